"""Drive the reproduction's cells batched, in this process or on a local process pool.

:func:`drive_cells` is the batched, parallel counterpart of :func:`plm_highway.evaluation.run.run_cells`
(same cells, same conditions through :func:`~plm_highway.evaluation.run.drive_options`, logs in the
same order): the cells go through :func:`plm_highway.evaluation.batched.run_cells`, one batched
forward pass per model and policy step, and with ``workers`` >= 1 in chunks over a pool of that many
spawned processes (:func:`worker_pool`), each loading the checkpoints once. The named policies run batch-invariantly, so the logs are the one-env runs' bit for bit,
whatever the batch size or the number of workers (``tests/test_cell_runner.py`` checks it).
"""

from __future__ import annotations

import contextlib
import functools
import math
import multiprocessing
import os
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

from plm_highway.evaluation.batched import DEFAULT_BATCH_SIZE, RunCell, run_cells
from plm_highway.evaluation.closed_loop import RunLog
from plm_highway.evaluation.policies import VisionPolicy
from plm_highway.evaluation.run import Cell, Conditions, biased, drive_options, scored_steps
from plm_highway.road.track import TrackSpec

MAX_WORKERS = 256
NAMED_POLICIES = ("expert", "bm", "plm")  # what a pool worker can build by name (the EKF is seeded per run)


@dataclass(frozen=True)
class _Chunk:
    """What a pool worker needs (plain data: it is pickled to the worker)."""

    cells: tuple[RunCell, ...]
    checkpoints: str | None
    preset: str  # the shipped checkpoint pair the conditions are meant for (when checkpoints is None)
    batch_size: int


def drive_cells(cells: Sequence[Cell], track_spec: TrackSpec, conditions: Conditions, policies: Mapping | None = None,
                checkpoints=None, max_steps: int | None = None, progress=None, workers: int = 0,
                batch_size: int = DEFAULT_BATCH_SIZE, threads: int = 1, pool: ProcessPoolExecutor | None = None
                ) -> list[RunLog]:
    """Drive ``cells`` on ``track_spec`` under ``conditions``; their logs in order.

    ``workers`` 0 runs them batched in this process, with ``policies`` (as given to
    :func:`~plm_highway.evaluation.run.run_cells`: its model policies are batched; None: the named
    policies loaded from ``checkpoints``) and ``threads`` Python threads; ``workers`` >= 1 spreads
    chunks of at most ``batch_size`` cells over a pool of that many processes, which load the
    named policies (``bm``, ``plm``, told the latency ``conditions`` say) from ``checkpoints``.
    ``progress`` (a tqdm bar) advances as runs end. ``pool``: a :func:`worker_pool` to use (else one
    is started and stopped here).
    """
    if not 0 <= workers <= MAX_WORKERS:
        raise ValueError(f"workers {workers}: must lie in [0, {MAX_WORKERS}]")
    steps = scored_steps(track_spec, conditions, max_steps)
    checkpoints = None if checkpoints is None else str(checkpoints)
    if workers == 0:
        run_cells_list = [_run_cell(cell, track_spec, conditions, steps, policies) for cell in cells]
        if progress is not None:
            progress.set_postfix_str(f"{track_spec.name}: {len(cells)} runs batched", refresh=True)

        def tick(index: int, log: RunLog) -> None:
            if progress is not None:
                progress.update(1)

        return run_cells(run_cells_list, checkpoints, batch_size=batch_size, on_done=tick, threads=threads,
                         preset=conditions.checkpoint_preset)
    named = [_run_cell(cell, track_spec, conditions, steps, None) for cell in cells]
    n_chunks = chunk_count(len(named), workers, batch_size)
    chunks = [_Chunk(tuple(named[k::n_chunks]), checkpoints, conditions.checkpoint_preset, batch_size)
              for k in range(n_chunks)]
    logs: list[RunLog | None] = [None] * len(cells)
    if progress is not None:
        progress.set_postfix_str(f"{track_spec.name}: {len(cells)} runs on {workers} workers", refresh=True)
    with contextlib.ExitStack() as stack:
        if pool is None:
            pool = stack.enter_context(worker_pool(workers))
        futures = {pool.submit(_drive_chunk, chunk): index for index, chunk in enumerate(chunks)}
        try:
            for future in as_completed(futures):
                chunk_logs = future.result()
                logs[futures[future]::n_chunks] = chunk_logs
                if progress is not None:
                    progress.update(len(chunk_logs))
        finally:
            for future in futures:  # an error or an interrupt: drop what has not started
                future.cancel()
    return logs


def chunk_count(n_runs: int, workers: int, batch_size: int) -> int:
    """How many chunks ``n_runs`` runs are split into for ``workers`` processes: at least one per worker, at
    most ``batch_size`` runs each (the progress bar moves as chunks end), and a multiple of the workers where
    there are runs enough (3 chunks on 2 workers leave one worker idle for the last third)."""
    n_chunks = max(min(workers, n_runs), math.ceil(n_runs / batch_size))
    return min(n_runs, workers * math.ceil(n_chunks / workers))


def worker_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes (no torch state is forked) for :func:`drive_cells`; reuse it
    across calls (``with worker_pool(n) as pool``): each worker loads the checkpoints once and keeps them."""
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))


def _run_cell(cell: Cell, track_spec: TrackSpec, conditions: Conditions, steps: int | None,
              policies: Mapping | None) -> RunCell:
    """The batched runner's cell for a reproduction cell: the model policy object this process holds,
    else the policy's name (loaded, or for the expert made per run, by the runner)."""
    from plm_highway.expert import ExpertPolicy

    policy = policies.get(cell.policy) if policies is not None else None
    if policy is None or isinstance(policy, ExpertPolicy):
        if cell.policy not in NAMED_POLICIES:
            raise ValueError(f"cell {cell.name!r}: policy {cell.policy!r} is neither a model policy object nor one "
                             f"of {list(NAMED_POLICIES)}")
        policy = "expert" if isinstance(policy, ExpertPolicy) else cell.policy
    elif not isinstance(policy, VisionPolicy):
        raise ValueError(f"cell {cell.name!r}: policy {cell.policy!r} is neither a model policy object nor one of "
                         f"{list(NAMED_POLICIES)} but a {type(policy).__name__}, which runs stepped together would "
                         "share; drive these cells with plm_highway.evaluation.run.run_cells")
    else:
        policy = biased(policy, cell.latency_bias_s)
    return RunCell(cell.name, policy, track_spec, cell.latency, cell.seed, latency_bias_s=cell.latency_bias_s,
                   latency_source=conditions.latency_source, **drive_options(cell, conditions, steps))


def _drive_chunk(chunk: _Chunk) -> list[RunLog]:
    """A pool worker: the chunk's runs batched, with the policies this worker loaded once."""
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    from plm_highway.evaluation.policies import single_threaded_inference

    cells = [RunCell(**{**cell.__dict__, "policy": biased(
                 worker_policy(cell.policy, chunk.checkpoints, chunk.preset, cell.latency_source), cell.latency_bias_s)})
             if cell.policy in ("bm", "plm") else cell for cell in chunk.cells]
    with single_threaded_inference():
        return run_cells(cells, chunk.checkpoints, batch_size=chunk.batch_size, preset=chunk.preset)


@functools.lru_cache(maxsize=8)
def worker_policy(name: str, checkpoints: str | None, preset: str, latency_source: str) -> VisionPolicy:
    """The named policy, loaded once per process (pool workers keep it across chunks)."""
    from plm_highway.evaluation.policies import make_policy

    return make_policy(name, checkpoints, latency_source=latency_source, preset=preset)
