"""Run a lesson's exercises and graded checks outside a notebook, the way nbgrader's autograder does.

``exercise_namespace`` executes the import statements of a solution notebook and its solution cells
(optionally changed by a mutant); ``run_check`` executes the grade cell of one check, hidden tests
included. Used by the mutation battery and the delegation tests.
"""

from __future__ import annotations

import ast
from pathlib import Path

import nbformat

from plm_highway.grading.course import BEGIN_SOLUTION, check_calls

REPO = Path(__file__).resolve().parents[1]
SOLUTIONS = REPO / "solutions"


def solution_path(lesson: str) -> Path:
    """"01" -> solutions/01_....ipynb"""
    (path,) = sorted(SOLUTIONS.glob(f"{lesson}_*.ipynb"))
    return path


def _cells(lesson: str) -> list:
    return nbformat.read(solution_path(lesson), as_version=4).cells


def import_source(lesson: str) -> str:
    """Every top-level import statement of the lesson's code cells."""
    lines = []
    for cell in _cells(lesson):
        if cell.cell_type != "code":
            continue
        for node in ast.parse(cell.source).body:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                lines.append(ast.unparse(node))
    return "\n".join(lines)


def solution_sources(lesson: str) -> list[str]:
    return [cell.source for cell in _cells(lesson) if cell.cell_type == "code" and BEGIN_SOLUTION in cell.source]


def grade_cell_source(lesson: str, check: str) -> str:
    for cell in _cells(lesson):
        if cell.cell_type == "code" and any(name == check for _, name in check_calls(cell.source)):
            return cell.source
    raise KeyError(f"lesson {lesson}: no grade cell calls {check}")


def exercise_namespace(lesson: str, old: str | None = None, new: str = "", extra: dict | None = None) -> dict:
    """Imports, ``extra`` variables and the solution cells, with ``old`` replaced by ``new`` (exactly once
    across the solution cells) or, with ``old`` empty, ``new`` executed after them (a rewrite)."""
    namespace: dict = {"__name__": "__main__"}
    exec(import_source(lesson), namespace)
    namespace.update(extra or {})
    sources = solution_sources(lesson)
    if old:
        hits = sum(source.count(old) for source in sources)
        assert hits == 1, f"lesson {lesson}: mutant text found {hits} times, expected once:\n{old}"
        sources = [source.replace(old, new) for source in sources]
    for source in sources:
        exec(compile(source, f"<lesson {lesson} solution cell>", "exec"), namespace)
    if not old and new:
        exec(compile(new, f"<lesson {lesson} rewrite>", "exec"), namespace)
    return namespace


def run_check(lesson: str, check: str, namespace: dict) -> None:
    """Execute the check's grade cell (hidden tests included) in ``namespace``."""
    exec(compile(grade_cell_source(lesson, check), f"<lesson {lesson} grade cell {check}>", "exec"), namespace)
