"""Closed-loop runs and the one loop that drives them: a policy drives a track, optionally seeing late
observations, and is logged.

A policy is anything that satisfies :class:`Policy`: ``policy(frame, info) -> normalised steering``
and ``reset()``; ``info`` carries the observed (possibly delayed) privileged state, the requested
``latency_s`` and the measured ``observation_age_s``. A policy that also counts the steps whose
latency lay beyond what it can compensate satisfies :class:`CountsClampedLatency`, and its count is
logged. Runs compared with each other use the same track, seed and so the same latency realisation.

One loop drives every run: :func:`drive_batched` steps N runs together, one forward pass of each model per step;
:func:`drive` is that loop with one run. Callers with many runs go through
:func:`plm_highway.rollout.cells.run_cells`, which makes the policy objects and chooses how many runs share a batch,
threads or a pool of workers. At every policy step the frames of all live runs whose policy
:class:`SteersInBatches` on one model (the Base Model, or PLM-Net told each run's own latency) go through that model
in one ``steer_batch`` call; the expert and other callables are called per run. A run that ends drops out of the
batch, the others go on.

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

Same results in a batch as alone: env stepping, resets, latency realisations and image noise are per run and
seeded by the run's seed, and the named model policies run batch-invariantly
(:mod:`plm_highway.models.batch_invariant`: a sample's output does not depend on the rest of its batch), so every
logged column of a run equals its one-run result bit for bit, whatever ``batch_size`` or ``threads``
(``tests/test_batched.py``). A caller's policy object built without ``batch_invariant`` runs PyTorch's own
kernels: equal up to float rounding, or bit-identical with ``run_cells(..., batch_invariant=True)``.

A run given a ``latency_estimation`` (:class:`~plm_highway.lane_ekf.latency_stream.LatencyEstimation`)
estimates its latency from the stream (no capture timestamps) and logs :data:`ESTIMATE_COLUMNS` beside the
true ``observation_age_s``; PLM-Net told ``latency_source="estimated"`` reads that estimate.
"""

from __future__ import annotations

import copy
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import gymnasium
import numpy as np

from plm_highway.envs import ENV_ID, register_envs
from plm_highway.lane_ekf.latency_stream import ESTIMATE_KEYS, STREAM_KEYS, LatencyEstimateWrapper
from plm_highway.latency import LatencyProfile, LatencyWrapper, parse_profile
from plm_highway.road.spec import TrackSpec

LOG_COLUMNS = ("t_s", "steering", "latency_s", "observation_age_s", "x_m", "y_m", "heading_rad", "speed_mps",
               "lateral_offset_m", "heading_error_rad", "arc_length_m", "segment")
# Logged when the run estimates its latency (plm_highway.lane_ekf.latency_stream adds them to info), and with its
# ``record`` option what the estimator was given (for writing the stream as a recording).
ESTIMATE_COLUMNS = ESTIMATE_KEYS
STREAM_COLUMNS = STREAM_KEYS
NOISE_STREAM = 7  # the image-noise generator is np.random.default_rng([seed, NOISE_STREAM]): apart from the env's


class Policy(Protocol):
    """What a closed-loop run drives with."""

    def reset(self) -> None: ...

    def __call__(self, frame: np.ndarray, info: dict) -> float: ...


@runtime_checkable
class SteersInBatches(Protocol):
    """A policy whose model steers many runs in one forward pass
    (:class:`~plm_highway.rollout.policies.VisionPolicy`): runs whose policies share one ``model_policy`` are
    stepped together, each told its own latency."""

    model_policy: object

    def reset(self) -> None: ...

    def latency_s(self, info: dict) -> float: ...

    def model_input(self, frame: np.ndarray, info: dict) -> np.ndarray: ...

    def output(self, steering: float, info: dict) -> float: ...


@runtime_checkable
class CountsClampedLatency(Protocol):
    """A policy that counts the steps whose latency was beyond its compensation range (PLM-Net's grid)."""

    @property
    def clamped_count(self) -> int: ...


@dataclass
class RunLog:
    """Per-step log of one run: the state at each policy step and the steering chosen there."""

    name: str
    columns: dict[str, np.ndarray]
    left_road: bool
    completed_fraction: float
    extras: dict = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return len(self.columns["t_s"])

    def summary(self) -> dict:
        offset_m = self.columns["lateral_offset_m"]
        return {
            "left_road": bool(self.left_road),
            "completed_fraction": float(self.completed_fraction),
            "lateral_offset_rms_m": float(np.sqrt(np.mean(offset_m ** 2))),
            "lateral_offset_max_m": float(np.max(np.abs(offset_m))),
            "steps": self.steps,
            **self.extras,
        }


@dataclass(frozen=True)
class RunCell:
    """One closed-loop run described completely, :func:`drive`'s arguments as data: the typed description every
    driving command builds and the loop runs. ``policy`` is a name of
    :data:`~plm_highway.rollout.policies.POLICY_NAMES` or a policy object; ``latency`` is given as a spec or a
    profile and held as the parsed :class:`~plm_highway.latency.LatencyProfile` (parsed here, once per run; the
    env keeps a private copy of it, so runs may share one).

    A policy object is either a :class:`~plm_highway.rollout.policies.VisionPolicy` (batched runs sharing its
    model go through it together) or any ``policy(frame, info)`` callable with ``reset()``, called per env: a
    stateful one (a filter) must be a distinct object in every cell that runs batched.
    """

    name: str
    policy: object
    track: TrackSpec | str = "test"
    latency: LatencyProfile | str = "const:0"
    seed: int = 0
    latency_bias_s: float = 0.0  # PLM-Net told its latency + bias (named policies only)
    latency_source: str = "measured"  # what a named PLM-Net is told: "measured" age, "requested" or "estimated"
    camera: dict | None = None
    env_config: dict | None = None
    max_steps: int | None = None
    injection: str = "time"  # LatencyWrapper injection, as for drive()
    image_noise_std: float = 0.0  # Gaussian pixel noise [grey levels], seeded as drive() seeds it
    latency_estimation: object = None  # a LatencyEstimation: the run estimates its latency, as for drive()

    def __post_init__(self):
        object.__setattr__(self, "latency", parse_profile(self.latency))


def make_env(track: TrackSpec | str, latency: LatencyProfile | str, camera: dict | None = None,
             env_config: dict | None = None, injection: str = "time", latency_estimation=None) -> gymnasium.Env:
    """The lane-keeping env on ``track`` behind a latency wrapper. ``latency``: a parsed profile (the wrapper
    keeps a private copy of it), or a spec, which the wrapper parses with the one parser. With a
    ``latency_estimation``, a :class:`~plm_highway.lane_ekf.latency_stream.LatencyEstimateWrapper` outside it
    adds the latency estimated from the stream to ``info``."""
    register_envs()
    config = {"track": track, **({"camera": camera} if camera else {}), **(env_config or {})}
    env = LatencyWrapper(gymnasium.make(ENV_ID, config=config), latency, injection=injection)
    return env if latency_estimation is None else LatencyEstimateWrapper(env, latency_estimation)


def log_estimate(rows: dict[str, list], info: dict) -> None:
    """Append the latency estimate's columns of ``info`` to ``rows`` (a run that estimates its latency)."""
    for column in ESTIMATE_COLUMNS + STREAM_COLUMNS:
        if column in info:
            rows.setdefault(column, []).append(info[column])


def add_image_noise(frame: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """``frame`` (uint8) plus Gaussian pixel noise of ``std`` grey levels, clipped to 0..255."""
    noisy = frame.astype(np.float32) + rng.normal(0.0, std, frame.shape).astype(np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(frame.dtype)


def drive(name: str, policy: Policy, track: TrackSpec | str = "test", latency: LatencyProfile | str = "const:0",
          seed: int = 0, camera: dict | None = None, env_config: dict | None = None, max_steps: int | None = None,
          injection: str = "time", image_noise_std: float = 0.0, latency_estimation=None) -> RunLog:
    """Drive one run until the track ends, the car leaves the road or ``max_steps``; the env is closed after.
    The loop of :func:`drive_batched` with this one run."""
    cell = RunCell(name, policy, track, latency, seed, camera=camera, env_config=env_config, max_steps=max_steps,
                   injection=injection, image_noise_std=image_noise_std, latency_estimation=latency_estimation)
    return drive_cell(cell, policy)


def drive_cell(cell: RunCell, policy: Policy) -> RunLog:
    """:func:`drive` the run ``cell`` describes, with ``policy`` (the cell's policy made an object)."""
    return drive_batched([cell], [policy], batch_size=1)[0]


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
    in_batches: bool = False  # its policy SteersInBatches (checked once: a protocol check costs as much as a step)

    def frame(self) -> np.ndarray:
        """The observation as the policy sees it (with the run's image noise)."""
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
        self.done = bool(self.terminated or truncated or self.at_step_limit())

    def at_step_limit(self) -> bool:
        return self.cell.max_steps is not None and self.step >= self.cell.max_steps

    def log(self) -> RunLog:
        columns = {column: np.asarray(values) for column, values in self.rows.items()}
        policy = self.policy
        if self.in_batches:
            extras = {"latency_clamped_steps": self.clamped_steps}  # counted per run: its model is shared
        elif isinstance(policy, CountsClampedLatency):
            extras = {"latency_clamped_steps": int(policy.clamped_count)}
        else:
            extras = {}
        self.env.close()
        return RunLog(self.cell.name, columns, bool(self.terminated), float(self.info["completed_fraction"]), extras)


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
            _steer_and_step([run for run in live.values() if not run.done], batch_invariant)
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
    run = _Run(cell, env, policy, obs, info, np.random.default_rng([cell.seed, NOISE_STREAM]),
               in_batches=isinstance(policy, SteersInBatches))
    run.done = run.at_step_limit()  # max_steps 0: logged without a step
    return run


def _steer_and_step(runs: list[_Run], batch_invariant: bool) -> None:
    """One policy step of every live run: batched model calls, then each env steps."""
    steering: dict[int, float] = {}
    by_model: dict[int, list[_Run]] = {}
    for run in runs:
        if run.in_batches:
            by_model.setdefault(id(run.policy.model_policy), []).append(run)
        else:
            steering[id(run)] = float(run.policy(run.frame(), run.info))
    for group in by_model.values():
        model = group[0].policy.model_policy
        # float32 as the model takes it: the same rounding whatever the batch
        latencies_s = np.asarray([run.policy.latency_s(run.info) for run in group], dtype=np.float32)
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
