"""How long each lesson takes to run from top to bottom (the 5-minute budget on 2 cores).

Runs every solution notebook in a fresh kernel with nbclient, in full mode (``PLM_FAST=0``) unless
told otherwise, and reports the wall-clock time per notebook and whether any cell raised.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import nbformat

BUDGET_S = 300.0


@dataclass(frozen=True)
class LessonTiming:
    notebook: str
    seconds: float
    errors: int

    def line(self) -> str:
        verdict = "within" if self.seconds <= BUDGET_S else "OVER"
        return (f"{self.notebook:<40} {self.seconds:7.1f} s  ({verdict} the {BUDGET_S:.0f} s budget)"
                + (f", {self.errors} cell(s) raised" if self.errors else ""))


def time_lesson(path: Path, fast: bool = False, timeout_s: int = 1800) -> LessonTiming:
    from nbclient import NotebookClient  # lazy: nbclient is a test extra, only for timing the lessons

    notebook = nbformat.read(path, as_version=4)
    old = os.environ.get("PLM_FAST")
    os.environ["PLM_FAST"] = "1" if fast else "0"
    try:
        started = time.perf_counter()
        NotebookClient(notebook, timeout=timeout_s, allow_errors=True, kernel_name="python3",
                       resources={"metadata": {"path": str(Path(path).parent)}}).execute()
        seconds = time.perf_counter() - started
    finally:
        if old is None:
            os.environ.pop("PLM_FAST", None)
        else:
            os.environ["PLM_FAST"] = old
    errors = sum(out.output_type == "error" for cell in notebook.cells if cell.cell_type == "code"
                 for out in cell.outputs)
    return LessonTiming(Path(path).name, seconds, errors)


def time_lessons(solutions_dir: Path, fast: bool = False, names: list[str] | None = None) -> list[LessonTiming]:
    paths = sorted(Path(solutions_dir).glob("*.ipynb"))
    if names:
        paths = [p for p in paths if p.name in names or p.stem in names]
    if not paths:
        raise ValueError(f"{solutions_dir}: no solution notebooks{' matching ' + str(names) if names else ''}")
    return [time_lesson(path, fast) for path in paths]
