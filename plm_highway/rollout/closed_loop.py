"""Closed-loop runs: a policy drives a track, optionally seeing late observations, and is logged.

A policy is anything that satisfies :class:`Policy`: ``policy(frame, info) -> normalised steering``
and ``reset()``; ``info`` carries the observed (possibly delayed) privileged state, the requested
``latency_s`` and the measured ``observation_age_s``. A policy that also counts the steps whose
latency lay beyond what it can compensate satisfies :class:`CountsClampedLatency`, and its count is
logged. Runs compared with each other use the same track, seed and so the same latency realisation.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import gymnasium
import numpy as np

from plm_highway.envs import ENV_ID, register_envs
from plm_highway.latency import LatencyProfile, LatencyWrapper
from plm_highway.road.spec import TrackSpec

LOG_COLUMNS = ("t_s", "steering", "latency_s", "observation_age_s", "x_m", "y_m", "heading_rad", "speed_mps",
               "lateral_offset_m", "heading_error_rad", "arc_length_m", "segment")
NOISE_STREAM = 7  # the image-noise generator is np.random.default_rng([seed, NOISE_STREAM]): apart from the env's


class Policy(Protocol):
    """What a closed-loop run drives with."""

    def reset(self) -> None: ...

    def __call__(self, frame: np.ndarray, info: dict) -> float: ...


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
    """One closed-loop run, :func:`drive`'s arguments as data. ``policy`` is a name of
    :data:`~plm_highway.rollout.policies.POLICY_NAMES` or a policy object.

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
    latency_source: str = "measured"  # what a named PLM-Net is told: "measured" age or "requested" latency
    camera: dict | None = None
    env_config: dict | None = None
    max_steps: int | None = None
    injection: str = "time"  # LatencyWrapper injection, as for drive()
    image_noise_std: float = 0.0  # Gaussian pixel noise [grey levels], seeded as drive() seeds it


def make_env(track: TrackSpec | str, latency: LatencyProfile | str, camera: dict | None = None,
             env_config: dict | None = None, injection: str = "time") -> LatencyWrapper:
    """The lane-keeping env on ``track`` behind a latency wrapper. ``latency``: a parsed profile (the wrapper
    keeps a private copy of it), or a spec, which the wrapper parses with the one parser."""
    register_envs()
    config = {"track": track, **({"camera": camera} if camera else {}), **(env_config or {})}
    return LatencyWrapper(gymnasium.make(ENV_ID, config=config), latency, injection=injection)


def add_image_noise(frame: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """``frame`` (uint8) plus Gaussian pixel noise of ``std`` grey levels, clipped to 0..255."""
    noisy = frame.astype(np.float32) + rng.normal(0.0, std, frame.shape).astype(np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(frame.dtype)


def drive(name: str, policy: Policy, track: TrackSpec | str = "test", latency: LatencyProfile | str = "const:0",
          seed: int = 0, camera: dict | None = None, env_config: dict | None = None, max_steps: int | None = None,
          injection: str = "time", image_noise_std: float = 0.0) -> RunLog:
    """Drive one run until the track ends, the car leaves the road or ``max_steps``; the env is closed after."""
    env = make_env(track, latency, camera, env_config, injection)
    noise_rng = np.random.default_rng([seed, NOISE_STREAM])
    try:
        obs, info = env.reset(seed=seed)
        policy.reset()
        rows: dict[str, list] = {column: [] for column in LOG_COLUMNS}
        terminated = False
        step = 0
        while max_steps is None or step < max_steps:
            frame = add_image_noise(obs, image_noise_std, noise_rng) if image_noise_std > 0 else obs
            steering = float(policy(frame, info))
            rows["steering"].append(steering)
            for column in LOG_COLUMNS[2:]:
                rows[column].append(info[column])
            rows["t_s"].append(info["time_s"])
            obs, _, terminated, truncated, info = env.step(np.array([steering], dtype=np.float32))
            step += 1
            if terminated or truncated:
                break
    finally:
        env.close()
    columns = {column: np.asarray(values) for column, values in rows.items()}
    extras = {"latency_clamped_steps": int(policy.clamped_count)} if isinstance(policy, CountsClampedLatency) else {}
    return RunLog(name, columns, bool(terminated), float(info["completed_fraction"]), extras)


def drive_cell(cell: RunCell, policy: Policy) -> RunLog:
    """:func:`drive` the run ``cell`` describes, with ``policy`` (the cell's policy made an object)."""
    return drive(cell.name, policy, cell.track, cell.latency, cell.seed, cell.camera, cell.env_config, cell.max_steps,
                 cell.injection, cell.image_noise_std)
