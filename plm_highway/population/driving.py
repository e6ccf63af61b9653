"""Drive one pair under one simulator seed: every run the plan asks of it, judged against its own reference.

A :class:`DriveTask` carries the pair's checkpoint files (bytes, so that it runs on any backend, a Ray node
without the parent's disk included) and returns one outcome row per run
(:func:`~plm_highway.evaluation.outcomes.run_outcomes` against the same pair's BM without latency under the same
seed) and the runs' traces, compressed, for later looks at why a car drifted.
"""

from __future__ import annotations

import atexit
import hashlib
import io
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plm_highway.evaluation.outcomes import run_outcomes
from plm_highway.evaluation.reproduce import conditions_named, plan_cells
from plm_highway.population.plan import PopulationPlan, pair_name
from plm_highway.road.track import resolve_track
from plm_highway.rollout.cells import Cell, run_cells, runs_under
from plm_highway.rollout.conditions import with_latency_source
from plm_highway.rollout.policies import single_threaded_inference

TRACE_COLUMNS = ("t_s", "steering", "latency_s", "observation_age_s", "x_m", "y_m", "lateral_offset_m",
                 "heading_error_rad", "arc_length_m")


@dataclass(frozen=True)
class DriveTask:
    plan: PopulationPlan
    pair: int
    seeds: tuple[int, ...]  # driven as one batched chunk (a pair's seeds split evenly over the workers)
    files: dict  # {"bm"|"tapm": {file name: bytes}}: the pair's checkpoints
    batch_size: int = 16
    device: str = "cpu"  # where the policies' forward passes run
    remedy: str = ""  # "": the pair's own PLM-Net and its BM; else only PLM-Net with the remedy's TAPM (and the
    # reference it is judged against)


@dataclass
class DriveResult:
    pair: int
    rows: dict[int, list[dict]]  # per seed
    traces: dict[int, bytes]  # per seed: np.savez_compressed of every run's TRACE_COLUMNS, keyed "RUN/COLUMN"
    remedy: str = ""
    cpu_s: float = 0.0  # the worker's CPU time for the chunk


def run_label(role: str, setting: str) -> str:
    """The key of a run within one pair and seed: ``reference``, ``baseline@const:0.25``, ..."""
    return role if role == "reference" else f"{role}@{setting}"


def plan_runs(plan: PopulationPlan, seed: int, track_name: str, conditions, remedy: str = "") -> list:
    """The cells of one pair under ``seed``: reproduce's reference, BM and PLM-Net per latency setting, and
    PLM-Net without latency; for a remedy, the reference and PLM-Net only."""
    cells = plan_cells(list(plan.latency_settings), [seed], track_name, conditions)
    if remedy:
        cells = [c for c in cells if c.role != "baseline"]
    if "const:0" in plan.settings:
        cells.append(Cell("mitigated", "plm", "const:0", seed, f"{track_name}: PLM-Net const:0, seed {seed}",
                          "const:0"))
    return cells


def drive_pair(task: DriveTask) -> DriveResult:
    """Drive every run of ``task.pair`` under each of ``task.seeds`` batched in this process; one row per run,
    each judged against the reference of its own seed."""
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

    cpu0 = time.process_time()
    plan = task.plan
    conditions = with_latency_source(conditions_named(plan.conditions), plan.latency_source or None)
    track_spec = resolve_track(plan.track)
    cells = [cell for seed in task.seeds for cell in plan_runs(plan, seed, track_spec.name, conditions, task.remedy)]
    checkpoints = materialised_checkpoints(task.pair, task.files)
    with single_threaded_inference():
        logs = run_cells(runs_under(cells, track_spec, conditions, None, plan.max_steps), checkpoints,
                         preset=conditions.checkpoint_preset, batch_size=task.batch_size, device=task.device)
    rows, traces = {}, {}
    for seed in task.seeds:
        mine = [(c, log) for c, log in zip(cells, logs) if c.seed == seed]
        by_label = {run_label(c.role, c.setting or c.latency): log for c, log in mine}
        reference = by_label["reference"]
        rows[seed] = []
        for cell, log in mine:
            setting = "const:0" if cell.role == "reference" else (cell.setting or cell.latency)
            outcomes = run_outcomes(log, reference, track_spec, conditions.max_steering_rad)
            rows[seed].append({"pair": task.pair, "seed": seed, "role": cell.role, "remedy": task.remedy,
                               "setting": setting, "latency_driven": cell.latency, **outcomes})
        traces[seed] = _compressed_traces(by_label)
    return DriveResult(task.pair, rows, traces, task.remedy, time.process_time() - cpu0)


def split_seeds(seeds, chunks: int) -> list[tuple[int, ...]]:
    """``seeds`` in at most ``chunks`` contiguous groups whose sizes differ by at most one."""
    seeds = list(seeds)
    chunks = max(1, min(chunks, len(seeds)))
    size, extra = divmod(len(seeds), chunks)
    out, start = [], 0
    for k in range(chunks):
        end = start + size + (k < extra)
        out.append(tuple(seeds[start:end]))
        start = end
    return out


def _compressed_traces(by_label: dict) -> bytes:
    arrays = {f"{label}/{column}": np.asarray(log.columns[column], dtype=np.float64)
              for label, log in by_label.items() for column in TRACE_COLUMNS}
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def read_traces(data: bytes) -> dict[str, dict[str, np.ndarray]]:
    """``{run label: {column: array}}`` of :attr:`DriveResult.traces`."""
    out: dict[str, dict[str, np.ndarray]] = {}
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        for key in archive.files:
            label, _, column = key.rpartition("/")
            out.setdefault(label, {})[column] = archive[key]
    return out


_MATERIALISED: dict[str, str] = {}  # checkpoint digest -> directory written by this process


def materialised_checkpoints(pair: int, files: dict) -> str:
    """A directory of this process holding the pair's ``bm/`` and ``tapm/`` files (written once per process,
    removed when it exits)."""
    items = [(model, name, files[model][name]) for model in sorted(files) for name in sorted(files[model])]
    digest = hashlib.sha256(b"".join(data for _, _, data in items)).hexdigest()
    if digest not in _MATERIALISED:
        directory = Path(tempfile.mkdtemp(prefix=f"plm-highway-{pair_name(pair)}-"))
        atexit.register(shutil.rmtree, directory, True)
        for model, name, data in items:
            (directory / model).mkdir(exist_ok=True)
            (directory / model / name).write_bytes(data)
        _MATERIALISED[digest] = str(directory)
    return _MATERIALISED[digest]
