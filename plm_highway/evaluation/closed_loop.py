"""Closed-loop runs: a policy drives a track, optionally seeing late observations, and is logged.

A policy is any callable ``policy(frame, info) -> normalised steering`` with a ``reset()``;
``info`` carries the observed (possibly delayed) privileged state, the requested ``latency_s``
and the measured ``observation_age_s``. Runs compared with each other use the same track,
seed and so the same latency realisation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium
import numpy as np

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.latency import LatencyWrapper, parse_profile

LOG_COLUMNS = ("t_s", "steering", "latency_s", "observation_age_s", "x_m", "y_m", "heading_rad", "speed_mps",
               "lateral_offset_m", "heading_error_rad", "arc_length_m", "segment")


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


def make_env(track, latency, camera: dict | None = None, env_config: dict | None = None) -> LatencyWrapper:
    config = {"track": track, **({"camera": camera} if camera else {}), **(env_config or {})}
    return LatencyWrapper(gymnasium.make("plm_highway/LaneKeeping-v0", config=config), parse_profile(latency))


def drive(name: str, policy, track="test", latency="const:0", seed: int = 0, camera: dict | None = None,
          env_config: dict | None = None, max_steps: int | None = None) -> RunLog:
    env = make_env(track, latency, camera, env_config)
    obs, info = env.reset(seed=seed)
    policy.reset()
    rows: dict[str, list] = {column: [] for column in LOG_COLUMNS}
    terminated = False
    step = 0
    while max_steps is None or step < max_steps:
        steering = float(policy(obs, info))
        rows["steering"].append(steering)
        for column in LOG_COLUMNS[2:]:
            rows[column].append(info[column])
        rows["t_s"].append(info["time_s"])
        obs, _, terminated, truncated, info = env.step(np.array([steering], dtype=np.float32))
        step += 1
        if terminated or truncated:
            break
    columns = {column: np.asarray(values) for column, values in rows.items()}
    extras = {"latency_clamped_steps": int(policy.clamped_count)} if hasattr(policy, "clamped_count") else {}
    return RunLog(name, columns, bool(terminated), float(info["completed_fraction"]), extras)
