"""Where chunks of runs are driven: in this process, a local process pool, or a Ray cluster.

Every backend has ``map_unordered(function, chunks)``, yielding ``(chunk index, function(chunk))`` as
chunks finish, and ``close()`` (also as a context manager). Workers only compute and return results; the
parent process writes every file (so a Ray cluster needs no shared filesystem and a result is written whole
once). :func:`plm_highway.rollout.cells.run_cells` spreads cells over a backend; sweeps map their own chunks.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

from plm_highway.errors import BadInput

BACKENDS = ("local", "ray")
MAX_WORKERS = 256


def default_workers() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def worker_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes (no torch state is forked) that end with the process that made them."""
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=end_with_parent)


PARENT_POLL_S = 1.0


def end_with_parent() -> None:
    """End this worker soon after the process that made it is gone (a daemon thread watches the parent's pid).

    A worker in the middle of a chunk otherwise outlives a parent ended by a signal it cannot catch (``kill``, an
    out-of-memory kill) and drives its runs to the end, for nobody, on cores others need. Polling the parent's pid
    (not the kernel's parent-death signal, which fires when the spawning *thread* ends) works whichever thread
    started the pool.
    """
    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(PARENT_POLL_S)
            if os.getppid() != parent:  # re-parented: the parent died
                os._exit(1)

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()


class _Backend:
    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class InProcess(_Backend):
    """Chunks one after another in this process (``--workers 0``; tests, benchmarks)."""

    def map_unordered(self, function: Callable, chunks: Sequence) -> Iterator[tuple[int, object]]:
        for index, chunk in enumerate(chunks):
            yield index, function(chunk)


class LocalPool(_Backend):
    """A pool of ``workers`` processes on this machine (spawned: no torch state is forked).

    The processes start at the first map and live until :meth:`close`, so what a worker loaded once (the
    checkpoints) serves every later map: hold one pool across calls. ``executor``: a pool of ``workers``
    processes already started (and warmed up) to map on instead; its owner shuts it down, not close.
    """

    def __init__(self, workers: int, executor: ProcessPoolExecutor | None = None):
        self.workers = workers
        self._executor = executor
        self._owned = executor is None

    @property
    def executor(self) -> ProcessPoolExecutor:
        if self._executor is None:
            self._executor = worker_pool(self.workers)
        return self._executor

    def map_unordered(self, function: Callable, chunks: Sequence) -> Iterator[tuple[int, object]]:
        futures = {self.executor.submit(function, chunk): index for index, chunk in enumerate(chunks)}
        try:
            while futures:
                done, _ = wait(futures, return_when=FIRST_COMPLETED)
                for future in done:
                    yield futures.pop(future), future.result()
        finally:
            for future in futures:  # an error or an interrupt: drop what has not started
                future.cancel()

    def close(self) -> None:
        if self._executor is not None and self._owned:
            self._executor.shutdown(cancel_futures=True)
        self._executor = None


class RayCluster(_Backend):
    """Chunks as Ray tasks (one CPU each) on a cluster at ``address``, or on a local Ray started here.

    ``address=None`` starts a private local Ray with ``workers`` CPUs and stops it on close;
    ``"auto"`` or ``"HOST:PORT"`` joins a running cluster (``ray start --head`` on one machine,
    ``ray start --address HOST:PORT`` on the others, plm-highway installed on every node).
    """

    def __init__(self, address: str | None, workers: int):
        try:
            # lazy: ray is optional (the cluster extra)
            import ray
        except ImportError:
            raise BadInput("--backend ray: Ray is not installed; pip install 'plm-highway[cluster]' "
                           "(or pip install ray)") from None
        self.ray = ray
        self.started_here = not ray.is_initialized()
        if self.started_here:
            options = {"include_dashboard": False, "log_to_driver": False}
            if address is None:
                options.update(num_cpus=workers, _node_ip_address="127.0.0.1")
            # Workers import plm_highway from where this process does (a source tree on PYTHONPATH).
            env_vars = {k: os.environ[k] for k in ("PYTHONPATH", "SDL_VIDEODRIVER") if k in os.environ}
            runtime_env = {"env_vars": env_vars} if env_vars else None
            # A private local Ray gets a second start: on a loaded machine its start-up can lose a race
            # (see _start_failed) that the next start may win, and a retry costs nothing when the first works.
            attempts = 2 if address is None else 1
            for attempt in range(attempts):
                try:
                    ray.init(address=address, runtime_env=runtime_env, **options)
                    break
                except Exception as exc:  # Ray raises bare Exception when its node does not come up
                    ray.shutdown()
                    if attempt + 1 < attempts:
                        continue
                    self._start_failed(exc)

    @staticmethod
    def _start_failed(exc: Exception) -> None:
        raise ConnectionError(
            f"--backend ray: Ray did not start or could not be reached ({exc}). On a heavily loaded machine "
            "a new local Ray can fail this way: its raylet gives up when its dashboard agent takes over "
            "~15 s to start; the logs are in /tmp/ray/session_latest/logs"
        ) from None

    def map_unordered(self, function: Callable, chunks: Sequence) -> Iterator[tuple[int, object]]:
        remote = self.ray.remote(num_cpus=1)(function)
        pending = {remote.remote(chunk): index for index, chunk in enumerate(chunks)}
        try:
            while pending:
                done, _ = self.ray.wait(list(pending), num_returns=1)
                yield pending.pop(done[0]), self.ray.get(done[0])
        finally:
            for ref in pending:
                self.ray.cancel(ref)

    def close(self) -> None:
        if self.started_here:
            self.ray.shutdown()


def make_backend(backend: str = "local", workers: int | None = None, address: str | None = None):
    """The backend by name; ``workers`` 0 runs in this process (local backend only)."""
    if backend not in BACKENDS:
        raise BadInput(f"--backend {backend!r}: expected one of {list(BACKENDS)}")
    workers = default_workers() if workers is None else workers
    if not 0 <= workers <= MAX_WORKERS:
        raise BadInput(f"--workers {workers}: must lie in [0, {MAX_WORKERS}]")
    if address is not None and backend != "ray":
        raise BadInput("--address: only with --backend ray")
    if backend == "ray":
        return RayCluster(address, max(1, workers))
    return InProcess() if workers == 0 else LocalPool(workers)
