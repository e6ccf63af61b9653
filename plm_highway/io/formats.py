"""Writing the project's file formats: strict JSON, CSV tables, matplotlib figures, the recorded command.

Top-level outputs go through :func:`plm_highway.io.outputs.write_output` (safe, atomic); the
``*_into`` functions write inside a directory that is already being staged.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import re
import shlex
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from plm_highway.errors import BadInput
from plm_highway.io.outputs import JSON_MARKER_KEY, PNG_SOFTWARE, OutputKind, file_kind, write_output, write_outputs

FIGURE = file_kind("figure", "a figure (PNG)")
# What `plm-highway bench ... --json` writes (the bench commands and the sim2real benchmarks alike).
BENCH_RESULT = file_kind("bench-result", "a benchmark result JSON file")


def json_safe(value):
    """``value`` with NaN and infinite floats replaced by None: strict JSON has neither."""
    if isinstance(value, Mapping):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    if hasattr(value, "item") and getattr(value, "ndim", None) == 0:  # numpy scalars
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def json_text(data: Mapping, kind: OutputKind | None = None, indent: int | None = 2) -> str:
    """Strict JSON of ``data`` (NaN/inf as null), tagged with the output kind when given."""
    payload = dict(data)
    if kind is not None:
        payload = {JSON_MARKER_KEY: kind.name, **payload}
    return json.dumps(json_safe(payload), indent=indent, allow_nan=False) + "\n"


def write_text(path: str | os.PathLike, text: str, kind: OutputKind, *, overwrite: bool = False) -> Path:
    with write_output(path, kind, overwrite=overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_json(path: str | os.PathLike, data: Mapping, kind: OutputKind, *, overwrite: bool = False) -> Path:
    return write_text(path, json_text(data, kind), kind, overwrite=overwrite)


def write_csv_into(path: Path, header: Sequence[str], rows: Iterable[Sequence]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows([format_cell(value) for value in row] for row in rows)


def write_csv(path: str | os.PathLike, header: Sequence[str], rows: Iterable[Sequence], kind: OutputKind, *,
              overwrite: bool = False) -> Path:
    with write_output(path, kind, overwrite=overwrite) as tmp:
        write_csv_into(tmp, header, rows)
    return Path(path)


def format_cell(value) -> str:
    """A CSV cell: floats to 6 significant digits, NaN/inf as an empty cell, the rest as text."""
    if hasattr(value, "item") and getattr(value, "ndim", None) == 0:
        value = value.item()
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else ""
    return str(value)


def unique_file_names(labels: Sequence[str], keys: Sequence[str] | None = None, suffix: str = "",
                      max_chars: int = 80) -> list[str]:
    """One file name per label, made safe (``[A-Za-z0-9.+-]``), and distinct whenever the ``keys`` (what
    each name stands for; default: the labels) differ: labels that look alike once made safe or cut
    (two tracks ``a/t.json`` and ``b/t.json`` shown as ``t``), or differ only in case (case-insensitive
    filesystems), get a short hash of their key."""
    keys = list(labels) if keys is None else list(keys)
    if len(keys) != len(labels) or len(set(keys)) != len(keys):
        raise ValueError(f"one distinct key per label is needed, got {keys}")
    safe = [re.sub(r"[^A-Za-z0-9.+-]+", "-", label).strip("-")[:max_chars] or "unnamed" for label in labels]
    folded = [name.lower() for name in safe]
    names = []
    for key, name, lowered in zip(keys, safe, folded):
        if folded.count(lowered) > 1:
            name = f"{name}-{hashlib.sha1(key.encode('utf-8')).hexdigest()[:8]}"
        names.append(name + suffix)
    return names


def save_figure_into(fig, path: Path, dpi: int = 120, **savefig_options) -> None:
    """Save a matplotlib figure as PNG, tagged so that plm-highway recognises it later.

    ``path`` lies in a freshly staged output: a file already there means two figures got one name,
    which is refused rather than letting the second silently replace the first."""
    if os.path.lexists(path):
        raise RuntimeError(f"internal error: two figures of one output are both named {Path(path).name!r}")
    fig.savefig(path, format="png", dpi=dpi, metadata={"Software": PNG_SOFTWARE}, **savefig_options)


def save_figure(fig, path: str | os.PathLike, *, overwrite: bool = False, dpi: int = 120) -> Path:
    if Path(path).suffix.lower() != ".png":
        raise BadInput(f"figure path {str(path)!r}: figures are written as PNG; give a name ending in .png")
    with write_output(path, FIGURE, overwrite=overwrite) as tmp:
        save_figure_into(fig, tmp, dpi=dpi)
    return Path(path)


def write_figure_and_numbers(fig, numbers: dict, out: str | os.PathLike, numbers_kind: OutputKind, *,
                             overwrite: bool = False, dpi: int = 120) -> tuple[Path, Path]:
    """A figure (``out``, PNG) and the numbers drawn in it (same name, ``.json``), published together; the
    figure is closed either way."""
    figure_path = Path(out)
    json_path = figure_path.with_suffix(".json")
    try:
        with write_outputs([(figure_path, FIGURE), (json_path, numbers_kind)], overwrite=overwrite) as staged:
            save_figure_into(fig, staged[0], dpi=dpi)
            staged[1].write_text(json_text(numbers, numbers_kind), encoding="utf-8")
    finally:
        pyplot().close(fig)
    return figure_path, json_path


def pyplot():
    """matplotlib.pyplot on a non-interactive backend unless one was chosen."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    # lazy: matplotlib only when a figure is drawn
    import matplotlib.pyplot as plt

    return plt


def command_line(argv: Sequence[str]) -> str:
    """The command line that produced an output (``plm-highway`` + its arguments), ready to paste into a shell.

    The router records it once per invocation (``args.command_line``); outputs store that string.
    """
    return shlex.join(["plm-highway", *argv])
