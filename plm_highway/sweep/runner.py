"""Run a sweep grid into an output directory, resumably.

The directory (``OUT``) holds ``cells/KEY.json`` (one per finished run, written whole through
:mod:`plm_highway.io` as its chunk comes back) and the set of the last run that finished:
``grid.json`` (its grid), ``results.csv`` (the tidy table of the grid's cells,
:mod:`plm_highway.sweep.table`) and ``figures/``. The set is published in one step when the run
ends, so an interrupted run leaves the previous set whole (or none), never a new grid beside old
results. Run again with the same ``OUT``, a sweep skips the cells whose result is there and runs
the rest (also after a crash or Ctrl-C: what was written is whole); a grid with more seeds or
latencies reuses the cells it shares with the earlier one. ``overwrite=True`` starts afresh.

Cells are run in chunks of at most ``batch_size`` through
:func:`~plm_highway.rollout.cells.run_cells` (one batched forward pass per model and step),
chunks spread over the backend's workers (:mod:`plm_highway.rollout.backends`).
"""

from __future__ import annotations

import json
import math
import os
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from tqdm.auto import tqdm

from plm_highway.errors import BadInput
from plm_highway.io import (
    FIGURE,
    JSON_MARKER_KEY,
    JsonLimits,
    check_target,
    directory_kind,
    file_kind,
    json_text,
    load_json,
    write_csv_into,
    write_json,
    write_output,
)
from plm_highway.io.digests import DIGEST_KEY, content_digest, json_digest, set_aside
from plm_highway.models.device import resolve_device
from plm_highway.road.track import resolve_track
from plm_highway.rollout.backends import make_backend
from plm_highway.rollout.cells import RunCell, run_cells
from plm_highway.rollout.policies import checkpoint_pair, single_threaded_inference
from plm_highway.sweep.grid import SweepCell, SweepGrid
from plm_highway.sweep.table import SWEEP_TABLE, TABLE_COLUMNS, cell_result, save_figures, table_rows

SWEEP_CELL = file_kind("sweep-cell", "a sweep cell result JSON file")
SWEEP_GRID = file_kind("sweep-grid", "a sweep grid JSON file")
SWEEP_FIGURES = directory_kind("sweep-figures", "a sweep figures directory")
# The parts of OUT that one finished run replaces together; cells are added as they finish.
SWEEP_SET = ("grid.json", "results.csv", "figures")
SWEEP_DIR = directory_kind("sweep", "a plm-highway sweep directory", owned=(
    ("cells/*.json", SWEEP_CELL), ("grid.json", SWEEP_GRID), ("results.csv", SWEEP_TABLE),
    ("figures/*.png", FIGURE), ("figures/.plm-highway-output.json", SWEEP_FIGURES)))
DEFAULT_BATCH_SIZE = 16
CELL_LIMITS = JsonLimits(max_bytes=64 << 20, max_depth=8, max_nodes=20_000_000)


@dataclass(frozen=True)
class ChunkJob:
    """What a worker needs to run some cells (plain data: it travels to other processes and machines)."""

    cells: tuple[SweepCell, ...]
    grid: SweepGrid
    checkpoints: str | None
    batch_size: int
    device: str = "cpu"  # resolved on the worker: ``auto`` is the worker's GPU where it has one


def run_chunk(job: ChunkJob) -> list[dict]:
    """Run the job's cells together; one result dict per cell (:func:`~plm_highway.sweep.table.cell_result`)."""

    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

    tracks = {track: resolve_track(track) for track in dict.fromkeys(cell.track for cell in job.cells)}
    run_cells_list = []
    for cell in job.cells:
        condition = job.grid.conditions[cell.condition]
        run_cells_list.append(RunCell(f"{cell.policy} {cell.latency} seed {cell.seed}", cell.policy, tracks[cell.track],
                                      cell.latency, cell.seed, camera=dict(condition.get("camera", {})) or None,
                                      env_config=dict(condition.get("env_config", {})) or None,
                                      max_steps=job.grid.max_steps))
    with single_threaded_inference():
        logs = run_cells(run_cells_list, job.checkpoints, batch_size=job.batch_size, device=job.device)
    return [cell_result(log) for log in logs]


def run_sweep(grid: SweepGrid, out, workers: int | None = None, backend: str = "local", address: str | None = None,
              batch_size: int = DEFAULT_BATCH_SIZE, checkpoints=None, overwrite: bool = False,
              progress: bool = True, device: str = "cpu", prune: bool = False) -> dict:
    """Run every cell of ``grid`` not yet in ``out``; write the table and figures. Returns a summary dict.

    Cell results of other grids or inputs in ``out/cells`` are kept (a grid or input that comes back reuses them;
    they never enter this grid's table: cells are keyed by content) and counted, or removed with ``prune``.

    ``device`` (``cpu``, ``cuda``, ``auto``): where each worker runs the models; on a Ray cluster it is resolved
    by the worker, elsewhere here first (``cuda`` without CUDA is refused before any run)."""
    if not 1 <= batch_size <= 4096:
        raise BadInput(f"--batch-size {batch_size}: must lie in [1, 4096]")
    if backend != "ray":
        resolve_device(device)
    out = Path(out)
    if checkpoints is not None:
        checkpoint_pair(checkpoints)  # fails now, naming what is missing, rather than in a worker
    runner = make_backend(backend, workers, address)
    try:
        inputs = grid.inputs(checkpoints)  # contents, read once: a changed file gives its cells new keys
        _open_directory(out, grid, overwrite)
        cells = grid.cells()
        settings = {cell: grid.settings(cell, inputs) for cell in cells}
        keys = {cell: cell.key(settings[cell]) for cell in cells}
        results = {cell: r for cell in cells if (r := _read_cell(out, keys[cell], cell, settings[cell])) is not None}
        todo = [cell for cell in cells if cell not in results]
        n_workers = getattr(runner, "workers", 1)
        chunk_size = max(1, min(batch_size, math.ceil(len(todo) / max(1, n_workers))))
        jobs = [ChunkJob(tuple(todo[i:i + chunk_size]), grid, None if checkpoints is None else str(checkpoints),
                         batch_size, str(device)) for i in range(0, len(todo), chunk_size)]
        bar = _progress(len(cells), len(results), progress)
        try:
            for index, chunk_results in runner.map_unordered(run_chunk, jobs):
                for cell, result in zip(jobs[index].cells, chunk_results):
                    record = cell_record(cell, settings[cell], result)
                    write_json(out / "cells" / f"{keys[cell]}.json", record, SWEEP_CELL)
                    results[cell] = record  # as a resumed run reads it back (NaN as None): both give one table
                bar.update(len(jobs[index].cells))
        finally:
            bar.close()
    finally:
        runner.close()
    rows = table_rows(cells, results)
    figures = _publish_set(out, grid, rows)
    others = _other_cells(out, set(keys.values()))
    if prune:
        for path in others:
            path.unlink()
    return {"out": str(out), "cells": len(cells), "ran": len(todo), "resumed": len(cells) - len(todo),
            "table": str(out / "results.csv"), "figures": [str(path) for path in figures], "rows": rows,
            "other_cells": len(others), "pruned": len(others) if prune else 0}


def _other_cells(out: Path, keys: set[str]) -> list[Path]:
    """The cell results in ``out/cells`` that this grid's cells are not: written by the kit for another grid or
    other inputs (a file the kit did not write, or set aside as edited, is not one of them)."""
    others = []
    for path in sorted((out / "cells").glob("*.json")):
        if path.stem in keys or not path.is_file() or path.is_symlink():
            continue
        try:
            data = load_json(path, CELL_LIMITS, what="sweep cell result")
        except (OSError, BadInput):
            continue
        if isinstance(data, dict) and data.get(JSON_MARKER_KEY) == SWEEP_CELL.name:
            others.append(path)
    return others


def _open_directory(out: Path, grid: SweepGrid, overwrite: bool) -> None:
    """A new sweep directory, or an earlier one to resume (``overwrite``: replaced by a new one)."""
    if out.is_dir() and SWEEP_DIR.recognises(out) and not overwrite:
        return  # resumed: its grid, table and figures are replaced together when this run ends
    check_target(out, SWEEP_DIR, overwrite=overwrite)
    with write_output(out, SWEEP_DIR, overwrite=overwrite) as staged:
        (staged / "cells").mkdir()


def _publish_set(out: Path, grid: SweepGrid, rows: list[dict]) -> list[Path]:
    """This run's grid, table and figures, in place of the previous ones, in one step; the cells (and
    anything else in OUT) stay."""
    with write_output(out, SWEEP_DIR, update=SWEEP_SET) as staged:
        (staged / "grid.json").write_text(json_text(grid.as_dict(), SWEEP_GRID), encoding="utf-8")
        write_csv_into(staged / "results.csv", TABLE_COLUMNS, [[row[c] for c in TABLE_COLUMNS] for row in rows])
        (staged / "figures").mkdir()
        figures = save_figures(rows, grid, staged / "figures")
    return [out / "figures" / path.name for path in figures]


def cell_record(cell: SweepCell, settings: dict, result: dict) -> dict:
    """What a cell's file holds: the cell, what its run was made from, its result, and the digest of all that
    (:data:`~plm_highway.io.digests.DIGEST_KEY`), as strict JSON reads it back."""

    record = json.loads(json_text({"cell": asdict(cell), "inputs": settings, **result}))
    record[DIGEST_KEY] = content_digest(record)
    return record


def _read_cell(out: Path, key: str, cell: SweepCell, settings: dict) -> dict | None:
    """A finished cell's result, or None (then it runs). Files are written whole, so one that is there is
    complete; one whose content no longer matches the digest it was written with (edited by hand) is moved aside
    to ``KEY.json.edited`` (kept, never overwritten) and the cell runs again."""
    path = out / "cells" / f"{key}.json"
    if not path.is_file():
        return None
    try:
        data = load_json(path, CELL_LIMITS, what="sweep cell result")
    except (OSError, BadInput) as exc:
        raise BadInput(f"{path}: not a readable sweep cell result ({exc}); remove it to run the cell again") from None
    if not isinstance(data, dict) or data.get(JSON_MARKER_KEY) != SWEEP_CELL.name or data.get("cell") != asdict(cell):
        raise BadInput(f"{path}: not the result of cell {asdict(cell)}; remove it to run the cell again")
    record = {key_: value for key_, value in data.items() if key_ != JSON_MARKER_KEY}
    why = None
    if record.get(DIGEST_KEY) != content_digest(record):
        why = "its content does not match the digest it was written with (edited since)"
    elif json_digest(record.get("inputs")) != json_digest(json.loads(json_text(settings))):
        why = "it was made from other inputs"
    if why is None:
        return record
    set_aside(path, why)
    return None


def _progress(total: int, done: int, enabled: bool):
    return tqdm(total=total, initial=done, unit="run", desc="sweep", file=sys.stderr, disable=not enabled)
