"""Cells and the one way to drive them: serial, batched in this process, or spread over workers.

A :class:`~plm_highway.rollout.closed_loop.RunCell` is one closed-loop run described completely (track,
latency, seed, env config, camera, injection, image noise, step limit, and the policy by name or as an
object). :func:`run_cells` drives a list of them and returns one
:class:`~plm_highway.rollout.closed_loop.RunLog` per cell, in order; the arguments choose how:

- ``serial=True``: one env at a time (:func:`~plm_highway.rollout.closed_loop.drive`), in this process;
- by default, batched in this process (:func:`~plm_highway.rollout.closed_loop.drive_batched`): ``batch_size`` envs stepped
  together, one forward pass per model and policy step, over ``threads`` Python threads;
- with a ``backend`` (:mod:`plm_highway.rollout.backends`: a local process pool or a Ray cluster), in chunks
  of at most ``batch_size`` cells, each chunk batched in a worker that loads the named policies once.

The named model policies run batch-invariantly, so the three give the same logs bit for bit, whatever the
batch size, threads or workers (``tests/test_batched.py``, ``tests/test_cell_runner.py``).

A :class:`Cell` is a run of a comparison under a set of :class:`~plm_highway.rollout.conditions.Conditions`:
a role (``reference``, ``baseline``, ``mitigated``, ...), the key of the policy that drives it, a latency
setting and a seed. :func:`runs_under` turns cells into run cells on one track under one set of conditions
(each seed's start, the env config, camera, injection, image noise and the scored step count), the one place
that says how conditions set a run up.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from tqdm import tqdm

from plm_highway.io.digests import json_digest
from plm_highway.latency import LatencyProfile
from plm_highway.models.device import resolve_device
from plm_highway.road.spec import TrackSpec
from plm_highway.rollout.backends import LocalPool
from plm_highway.rollout.closed_loop import Policy, RunCell, RunLog, drive_batched, drive_cell, make_env
from plm_highway.rollout.conditions import Conditions, scored_steps, start_perturbation
from plm_highway.rollout.policies import (
    MODEL_POLICIES,
    POLICY_NAMES,
    SHIPPED_PRESET,
    VisionPolicy,
    biased,
    checkpoint_pair_sha256,
    make_policy,
    policy_for_run,
    single_threaded_inference,
)

DEFAULT_BATCH_SIZE = 32
MAX_BATCH_SIZE = 4096
MAX_THREADS = 64
ROLES = ("reference", "baseline", "mitigated")


# ---------------------------------------------------------------------------------------------
# cells under conditions
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Cell:
    """One closed-loop run: who drives (``role`` and ``policy``), with which latency, under which seed."""

    role: str  # reference, baseline or mitigated
    policy: str  # a key of the policies given to runs_under ("bm", "plm", ...) or a policy name
    latency: str  # latency spec driven ("const:0" for the reference)
    seed: int
    label: str = ""  # progress-bar text
    setting: str = ""  # the setting this run belongs to, if not its latency (the legacy FIFO's constant BM baseline)
    latency_bias_s: float = 0.0  # PLM-Net told its latency + this (the sweep's wrong estimates)

    @property
    def key(self) -> tuple[str, str, int]:
        """(role, setting, seed): how a run is found among a track's runs."""
        return self.role, self.setting or self.latency, self.seed

    @property
    def name(self) -> str:
        return self.role


def drive_options(cell: Cell, conditions: Conditions, steps: int | None) -> dict:
    """The keyword arguments of :func:`~plm_highway.rollout.closed_loop.drive` (and fields of a ``RunCell``) that
    ``conditions`` set for ``cell``: one place, so every run under conditions is set up alike."""
    offset_m, heading_rad = start_perturbation(cell.seed, conditions)
    return {"camera": conditions.camera or None, "env_config": conditions.env_config(offset_m, heading_rad),
            "max_steps": steps, "injection": conditions.injection, "image_noise_std": conditions.image_noise_std,
            "latency_estimation": conditions.latency_estimation}


def runs_under(cells: Sequence[Cell], track_spec: TrackSpec, conditions: Conditions,
               policies: Mapping[str, Policy] | None = None, max_steps: int | None = None) -> list[RunCell]:
    """The run cells of ``cells`` on ``track_spec`` under ``conditions``, all for the same number of steps
    (:func:`~plm_highway.rollout.conditions.scored_steps`), so step k of every log is the same instant.

    A cell's policy is ``policies[cell.policy]`` where given (an object, told its cell's latency bias), else
    the policy named ``cell.policy`` (loaded by :func:`run_cells`, PLM-Net told the latency the conditions say).
    Each latency spec is parsed once (by its first run cell) and the runs of that spec share its profile (every env
    keeps a private copy).
    """
    steps = scored_steps(track_spec, conditions, max_steps)
    profiles: dict[str, LatencyProfile] = {}
    runs = []
    for cell in cells:
        policy = (policies or {}).get(cell.policy)
        if policy is None:
            if cell.policy not in POLICY_NAMES:
                raise ValueError(f"cell {cell.name!r}: policy {cell.policy!r} is neither given as an object nor one "
                                 f"of {list(POLICY_NAMES)}")
            policy = cell.policy
        else:
            policy = biased(policy, cell.latency_bias_s)
        run = RunCell(cell.name, policy, track_spec, profiles.get(cell.latency, cell.latency), cell.seed,
                      latency_bias_s=cell.latency_bias_s, latency_source=conditions.latency_source,
                      **drive_options(cell, conditions, steps))
        profiles.setdefault(cell.latency, run.latency)
        runs.append(run)
    return runs


def check_env(track_spec: TrackSpec, latency: str, conditions: Conditions) -> None:
    """Build (and close) the env a cell would use: the latency must fit the buffer, the rates the env."""
    make_env(track_spec, latency, conditions.camera, conditions.env_config(), conditions.injection).close()


def progress_bar(total: int, enabled: bool, desc: str = "reproduce") -> tqdm:
    return tqdm(total=total, desc=desc, unit="run", disable=not enabled, file=sys.stderr)


def advancing(progress: tqdm | None) -> Callable[[int, RunLog], None] | None:
    """An ``on_done`` for :func:`run_cells` that moves ``progress`` one run on (None: no bar)."""
    if progress is None:
        return None
    return lambda index, log: progress.update(1)


# ---------------------------------------------------------------------------------------------
# driving
# ---------------------------------------------------------------------------------------------


def run_cells(cells: Sequence[RunCell], checkpoints=None, *, preset: str = SHIPPED_PRESET, serial: bool = False,
              batch_size: int = DEFAULT_BATCH_SIZE, threads: int = 1, backend=None, batch_invariant: bool = False,
              on_done: Callable[[int, RunLog], None] | None = None, device="cpu") -> list[RunLog]:
    """Drive every cell; the logs in the order of ``cells`` (see the module docstring for the three ways).

    Named model policies load the checkpoint pair once per process (``checkpoints`` and ``preset`` as for
    :func:`~plm_highway.rollout.policies.make_policy`); the expert and the EKF are made per run.
    ``on_done(index, log)`` is called as each run ends (progress, or saving results as they come).
    ``batch_invariant`` (batched in this process): run a caller's model policy objects with batch-invariant
    kernels too (the named ones always are). ``device``: where the named model policies run (``cpu``, ``cuda``,
    ``auto`` or a torch.device; each step's batch of frames goes there for one forward pass).
    """
    if not 1 <= batch_size <= MAX_BATCH_SIZE:
        raise ValueError(f"batch_size {batch_size}: must lie in [1, {MAX_BATCH_SIZE}]")
    if not 1 <= threads <= MAX_THREADS:
        raise ValueError(f"threads {threads}: must lie in [1, {MAX_THREADS}]")
    if serial and (threads != 1 or backend is not None or batch_invariant):
        raise ValueError("serial runs take no threads, backend or batch_invariant (they step one env at a time)")
    if backend is not None and threads != 1:
        raise ValueError("runs on a backend take no threads (each worker steps its chunk as one batch)")
    for i, cell in enumerate(cells):
        if isinstance(cell.policy, str) and cell.policy not in POLICY_NAMES:
            raise ValueError(f"cell {i} ({cell.name!r}): policy {cell.policy!r} is not one of {list(POLICY_NAMES)}")
        if cell.max_steps is not None and cell.max_steps < 1:
            raise ValueError(f"cell {i} ({cell.name!r}): max_steps {cell.max_steps} must be at least 1")
    checkpoints = None if checkpoints is None else str(checkpoints)
    device = resolve_device(device)  # once, here (cuda without CUDA is refused before any run); workers get it as is
    if backend is not None:
        return _run_on(backend, cells, checkpoints, preset, batch_size, on_done, device)
    models = _load_models(cells, functools.partial(make_policy, checkpoint_dir=checkpoints, preset=preset,
                                                   device=device))
    if serial:
        logs = []
        for index, cell in enumerate(cells):
            logs.append(drive_cell(cell, _policy_for(cell, models)))
            if on_done is not None:
                on_done(index, logs[-1])
        return logs
    _check_no_shared_callables(cells)
    return drive_batched(cells, [_policy_for(cell, models) for cell in cells], batch_size, batch_invariant, on_done,
                         threads)


def _load_models(cells: Sequence[RunCell], load: Callable[[str], VisionPolicy]) -> dict[str, VisionPolicy]:
    """One policy per model name the cells use (loaded once, shared by the runs)."""
    return {name: load(name) for name in sorted({c.policy for c in cells if c.policy in MODEL_POLICIES})}


def _policy_for(cell: RunCell, models: Mapping[str, VisionPolicy]) -> Policy:
    """The cell's policy object: a named model shared with the other runs (told this cell's latency), a named
    expert or EKF of its own, or the object the cell holds."""
    if not isinstance(cell.policy, str):
        return cell.policy
    shared = models[cell.policy].model_policy if cell.policy in MODEL_POLICIES else None
    return policy_for_run(cell.policy, shared, latency_bias_s=cell.latency_bias_s, latency_source=cell.latency_source,
                          seed=cell.seed, camera=cell.camera, env_config=cell.env_config)


def _check_no_shared_callables(cells: Sequence[RunCell]) -> None:
    seen: dict[int, int] = {}
    for i, cell in enumerate(cells):
        if isinstance(cell.policy, (str, VisionPolicy)):
            continue
        if id(cell.policy) in seen:
            raise ValueError(f"cells {seen[id(cell.policy)]} and {i}: one policy object in two cells; runs "
                             "stepped together would share its state. Give each cell its own object")
        seen[id(cell.policy)] = i


# ---------------------------------------------------------------------------------------------
# on workers
# ---------------------------------------------------------------------------------------------


@contextlib.contextmanager
def local_workers(workers: int):
    """A local pool of ``workers`` processes to give :func:`run_cells` as its backend, shut down after the block;
    None for 0 (the runs batched in this process). Hold one across calls: its workers load the models once."""
    if not workers:
        yield None
        return
    with LocalPool(workers) as pool:
        yield pool


@dataclass(frozen=True)
class _Chunk:
    """What a worker needs (plain data: it is pickled to the worker)."""

    cells: tuple[RunCell, ...]
    checkpoints: str | None
    preset: str  # the shipped checkpoint pair (when checkpoints is None)
    batch_size: int
    device: object = "cpu"  # where the worker's model policies run: the caller's resolved torch.device


def chunk_count(n_runs: int, workers: int, batch_size: int) -> int:
    """How many chunks ``n_runs`` runs are split into for ``workers`` processes: at least one per worker, at
    most ``batch_size`` runs each (progress moves as chunks end), and a multiple of the workers where
    there are runs enough (3 chunks on 2 workers leave one worker idle for the last third)."""
    n_chunks = max(min(workers, n_runs), math.ceil(n_runs / batch_size))
    return min(n_runs, workers * math.ceil(n_chunks / workers))


def _run_on(backend, cells: Sequence[RunCell], checkpoints: str | None, preset: str, batch_size: int,
            on_done, device) -> list[RunLog]:
    """The cells in chunks over ``backend``'s workers, each chunk batched there; logs in order."""
    for i, cell in enumerate(cells):
        if not isinstance(cell.policy, str):
            raise ValueError(f"cell {i} ({cell.name!r}): runs on workers take their policy by name (one of "
                             f"{list(POLICY_NAMES)}), not a {type(cell.policy).__name__} object of this process")
    if not cells:
        return []
    n_chunks = chunk_count(len(cells), getattr(backend, "workers", 1), batch_size)
    chunks = [_Chunk(tuple(cells[k::n_chunks]), checkpoints, preset, batch_size, device) for k in range(n_chunks)]
    logs: list[RunLog | None] = [None] * len(cells)
    for k, chunk_logs in backend.map_unordered(_drive_chunk, chunks):
        for j, log in enumerate(chunk_logs):
            index = k + j * n_chunks
            logs[index] = log
            if on_done is not None:
                on_done(index, log)
    return logs


def _drive_chunk(chunk: _Chunk) -> list[RunLog]:
    """A worker: the chunk's runs batched, with the model policies this process loaded once."""
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    models = _load_models(chunk.cells,
                          lambda name: worker_policy(name, chunk.checkpoints, chunk.preset, chunk.device,
                                                      _pair_contents(chunk.checkpoints, chunk.preset)))
    with single_threaded_inference():
        return drive_batched(chunk.cells, [_policy_for(cell, models) for cell in chunk.cells], chunk.batch_size)


@functools.lru_cache(maxsize=8)
def worker_policy(name: str, checkpoints: str | None, preset: str, device="cpu",
                  contents: str | None = None) -> VisionPolicy:
    """The named model policy, loaded once per process (pool workers keep it across chunks; call it with
    positional arguments, as the workers do, to find what they loaded). ``contents``: the digest of the pair's
    files (:func:`_pair_contents`), so a pair retrained into the same directory while a worker lives (a Ray
    cluster's) is loaded anew rather than served from this cache."""
    return make_policy(name, checkpoints, preset=preset, device=device)


def _pair_contents(checkpoints: str | None, preset: str) -> str:
    return json_digest(checkpoint_pair_sha256(checkpoints, preset))


__all__ = ["DEFAULT_BATCH_SIZE", "ROLES", "Cell", "RunCell", "advancing", "check_env", "chunk_count",
           "drive_options", "local_workers", "progress_bar", "run_cells", "runs_under"]
