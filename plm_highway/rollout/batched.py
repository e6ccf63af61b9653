"""Batched closed loop: N runs stepped together, one forward pass of each model per step.

:func:`drive_batched` drives a list of :class:`~plm_highway.rollout.closed_loop.RunCell`, each with its policy
object, and returns one :class:`~plm_highway.rollout.closed_loop.RunLog` per cell, in order; callers go through
:func:`plm_highway.rollout.cells.run_cells`, which makes the policy objects and chooses this engine, the serial
loop or a pool of workers. Up to ``batch_size`` envs are live at once; at every policy step the frames of all
live envs that use one model (the Base Model, or PLM-Net with each env's own measured latency) go through that
model in one ``steer_batch`` call; the expert and other callables are called per env. An env that ends drops
out of the batch, the others go on.

Why the project's own envs in a list and not gymnasium's vector API: ``SyncVectorEnv`` steps the
same envs one after another in one process, like this loop, but every run here ends at its own
step (leaving the road, the end of the track), which its autoreset modes handle by resetting the
env (``NEXT_STEP``/``SAME_STEP``) or by leaving a finished env in the batch (``DISABLED``, with
``reset_mask``); it also stacks every info dict into arrays each step, which this module would
only have to undo. ``plm-highway bench sweep`` drives the same 16 runs both ways in one run: on a
loaded 2-core machine (load average 7-11) the own loop took 17.0 s and SyncVectorEnv 18.6 s (earlier, at load 17,
16.8 s and 18.0 s against 32.5 s one env at a time). The forward pass costs 10-20x the env step, so the
vector API's bookkeeping is small but never a gain. ``AsyncVectorEnv`` puts one env per
subprocess: on 2 cores a process pool (:mod:`plm_highway.rollout.backends`) already uses both.

Same results as one env at a time: env stepping, resets, latency realisations and image noise are
per env and seeded exactly as :func:`~plm_highway.rollout.closed_loop.drive` does, and the named model
policies run batch-invariantly (:mod:`plm_highway.models.batch_invariant`: a sample's output does not depend
on the rest of its batch), so every logged column equals the one-env run's bit for bit, whatever
``batch_size`` or ``threads`` (``tests/test_batched.py``). A caller's policy object built without
``batch_invariant`` runs PyTorch's own kernels: equal up to float rounding (~1e-6 in steering per
step, amplified by the closed loop to ~1e-4 over 100 steps), or bit-identical with
``run_cells(..., batch_invariant=True)``. Expert runs are always bit-identical.
"""

from __future__ import annotations

import copy
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from plm_highway.rollout.closed_loop import (
    LOG_COLUMNS,
    NOISE_STREAM,
    Policy,
    RunCell,
    RunLog,
    add_image_noise,
    log_estimate,
    make_env,
)
from plm_highway.rollout.policies import VisionPolicy


@dataclass
class _Run:
    """One live env of the batch and what has been logged of it."""

    cell: RunCell
    env: object
    policy: object
    obs: np.ndarray
    info: dict
    noise_rng: np.random.Generator
    rows: dict[str, list] = field(default_factory=lambda: {column: [] for column in LOG_COLUMNS})
    step: int = 0
    clamped_steps: int = 0
    done: bool = False
    terminated: bool = False

    def frame(self) -> np.ndarray:
        """The observation as the policy sees it (with the run's image noise, drawn as drive() draws it)."""
        std = self.cell.image_noise_std
        return add_image_noise(self.obs, std, self.noise_rng) if std > 0 else self.obs

    def record(self, steering: float) -> None:
        self.rows["steering"].append(steering)
        for column in LOG_COLUMNS[2:]:
            self.rows[column].append(self.info[column])
        self.rows["t_s"].append(self.info["time_s"])
        log_estimate(self.rows, self.info)

    def advance(self, steering: float) -> None:
        self.obs, _, self.terminated, truncated, self.info = self.env.step(np.array([steering], dtype=np.float32))
        self.step += 1
        limit = self.cell.max_steps
        self.done = bool(self.terminated or truncated or (limit is not None and self.step >= limit))

    def log(self) -> RunLog:
        columns = {column: np.asarray(values) for column, values in self.rows.items()}
        policy = self.policy
        if isinstance(policy, VisionPolicy):
            extras = {"latency_clamped_steps": self.clamped_steps}
        elif hasattr(policy, "clamped_count"):
            extras = {"latency_clamped_steps": int(policy.clamped_count)}
        else:
            extras = {}
        self.env.close()
        return RunLog(self.cell.name, columns, bool(self.terminated), float(self.info["completed_fraction"]), extras)


def drive_batched(cells: Sequence[RunCell], policies: Sequence[Policy], batch_size: int, batch_invariant: bool = False,
                  on_done: Callable[[int, RunLog], None] | None = None, threads: int = 1) -> list[RunLog]:
    """Drive every cell with its policy (``policies[i]`` for ``cells[i]``), ``batch_size`` envs at a time; the logs
    in the order of ``cells``.

    ``on_done(index, log)`` is called as each run ends. ``threads`` > 1 splits the cells over that many Python
    threads, each stepping its own batch and sharing the models: the forward passes (which release the GIL) of
    one batch run while another batch's envs step, which uses a second core without a process or a second copy
    of the model. With batch-invariant models the logs do not depend on ``batch_size`` or ``threads``.
    """
    logs: list[RunLog | None] = [None] * len(cells)
    parts = [list(range(len(cells)))[k::threads] for k in range(min(threads, len(cells)))]
    if len(parts) <= 1:
        _drive_part(parts[0] if parts else [], cells, policies, batch_size, batch_invariant, logs, on_done)
        return logs
    lock = threading.Lock()

    def done(index: int, log: RunLog) -> None:
        with lock:
            on_done(index, log)

    with ThreadPoolExecutor(len(parts)) as pool:
        futures = [pool.submit(_drive_part, part, cells, policies, batch_size, batch_invariant, logs,
                               None if on_done is None else done) for part in parts]
        for future in futures:
            future.result()
    return logs


def _drive_part(indices: list[int], cells: Sequence[RunCell], policies: Sequence[Policy], batch_size: int,
                batch_invariant: bool, logs: list, on_done) -> None:
    """The cells ``indices``, ``batch_size`` envs at a time, refilling the batch as runs end."""
    pending = list(indices)
    live: dict[int, _Run] = {}
    try:
        while pending or live:
            while pending and len(live) < batch_size:
                index = pending.pop(0)
                live[index] = _start(cells[index], policies[index])
            _steer_and_step(list(live.values()), batch_invariant)
            for index in [i for i, run in live.items() if run.done]:
                logs[index] = live.pop(index).log()
                if on_done is not None:
                    on_done(index, logs[index])
    finally:
        for run in live.values():  # an error: close what is still open
            run.env.close()


def _start(cell: RunCell, policy: Policy) -> _Run:
    env = make_env(cell.track, cell.latency, cell.camera, cell.env_config, cell.injection, cell.latency_estimation)
    obs, info = env.reset(seed=cell.seed)
    policy.reset()
    return _Run(cell, env, policy, obs, info, np.random.default_rng([cell.seed, NOISE_STREAM]))


def _steer_and_step(runs: list[_Run], batch_invariant: bool) -> None:
    """One policy step of every live run: batched model calls, then each env steps."""
    steering: dict[int, float] = {}
    by_model: dict[int, list[_Run]] = {}
    for run in runs:
        if isinstance(run.policy, VisionPolicy):
            by_model.setdefault(id(run.policy.model_policy), []).append(run)
        else:
            steering[id(run)] = float(run.policy(run.frame(), run.info))
    for group in by_model.values():
        model = group[0].policy.model_policy
        # The same latency (and float32 rounding) as VisionPolicy.__call__ gives the model per frame.
        latencies_s = np.asarray([max(0.0, run.info[run.policy.info_key] + run.policy.latency_bias_s)
                                  for run in group], dtype=np.float32)
        frames = np.stack([run.policy.model_input(run.frame(), run.info) for run in group])
        speeds_mps = np.asarray([run.info["speed_mps"] for run in group])
        if batch_invariant and not model.batch_invariant:  # a caller's policy object, left as it was
            model = copy.copy(model)
            model.batch_invariant = True
        actions = model.steer_batch(frames, speeds_mps, latencies_s)
        above_grid = latencies_s > np.float32(model.max_latency_s)
        for run, action, clamped in zip(group, actions, above_grid):
            steering[id(run)] = run.policy.output(float(action), run.info)
            run.clamped_steps += int(clamped)
    for run in runs:
        run.record(steering[id(run)])
        run.advance(steering[id(run)])
