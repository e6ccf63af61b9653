"""The car's motion since a past instant, dead reckoned from its own speed and yaw-rate samples.

A pure function and one small history of the samples the control loop read, one per policy call.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class MotionSample:
    time_s: float
    speed_mps: float
    yaw_rate_radps: float


def relative_pose(samples, since_s: float, now_s: float) -> tuple[float, float, float]:
    """The car's pose at ``now_s`` in its own frame at ``since_s``: ``(forward_m, left_m, yaw_rad)``.

    ``samples``: :class:`MotionSample` in time order. Between two samples the car moves at their mean speed and
    yaw rate; before the first and after the last at that sample's. Each piece is integrated exactly as an arc,
    so a steady turn gives the same pose however finely the loop sampled it.
    """
    if now_s <= since_s or not samples:
        return 0.0, 0.0, 0.0
    samples = list(samples)
    # pieces between consecutive samples at their mean speed and yaw rate (the motion between two reads is
    # smooth: the actuator and the car lag the command); before the first sample and after the last, its own
    pieces = [(-math.inf, samples[0].time_s, samples[0].speed_mps, samples[0].yaw_rate_radps)]
    pieces += [(a.time_s, b.time_s, (a.speed_mps + b.speed_mps) / 2, (a.yaw_rate_radps + b.yaw_rate_radps) / 2)
               for a, b in zip(samples, samples[1:])]
    pieces.append((samples[-1].time_s, math.inf, samples[-1].speed_mps, samples[-1].yaw_rate_radps))
    forward_m = left_m = yaw_rad = 0.0
    for start_s, end_s, speed_mps, yaw_rate_radps in pieces:
        start_s, end_s = max(start_s, since_s), min(end_s, now_s)
        if end_s <= start_s:
            continue
        dt_s = end_s - start_s
        turn_rad = yaw_rate_radps * dt_s
        distance_m = speed_mps * dt_s
        # the chord of the arc, along the piece's mean heading
        chord_m = distance_m * (math.sin(turn_rad / 2) / (turn_rad / 2) if abs(turn_rad) > 1e-9 else 1.0)
        mean_heading_rad = yaw_rad + turn_rad / 2
        forward_m += chord_m * math.cos(mean_heading_rad)
        left_m += chord_m * math.sin(mean_heading_rad)
        yaw_rad += turn_rad
    return forward_m, left_m, yaw_rad


class MotionHistory:
    """The newest samples covering at least ``horizon_s`` (older ones are dropped)."""

    def __init__(self, horizon_s: float = 2.0):
        if not (math.isfinite(horizon_s) and horizon_s > 0):
            raise ValueError(f"MotionHistory: horizon_s={horizon_s!r} must be a positive number of seconds")
        self.horizon_s = horizon_s
        self.samples: deque[MotionSample] = deque()

    def reset(self) -> None:
        self.samples.clear()

    def add(self, sample: MotionSample) -> None:
        if self.samples and sample.time_s <= self.samples[-1].time_s:
            raise ValueError(f"MotionHistory: sample at {sample.time_s} s is not after {self.samples[-1].time_s} s")
        self.samples.append(sample)
        # keep the newest sample at or before now - horizon, so a look back of horizon_s is still covered
        while len(self.samples) > 1 and self.samples[1].time_s <= sample.time_s - self.horizon_s:
            self.samples.popleft()

    def pose_since(self, since_s: float) -> tuple[float, float, float]:
        """:func:`relative_pose` from ``since_s`` to the newest sample's time."""
        if not self.samples:
            return 0.0, 0.0, 0.0
        return relative_pose(self.samples, since_s, self.samples[-1].time_s)
