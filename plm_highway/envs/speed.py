"""The ego car's speed: a constant, or a schedule of (time, speed) points linearly interpolated.

Config ``speed_mps`` is a number, or a list of ``[time_s, speed_mps]`` pairs with strictly increasing
times from 0; before the first and after the last point the speed is held. Bounds, checked when the
env resets: speeds in (0, MAX_SPEED_MPS], times finite in [0, MAX_SCHEDULE_TIME_S], at most
MAX_SCHEDULE_POINTS points.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

from plm_highway.errors import BadInput

MAX_SPEED_MPS = 70.0  # 252 km/h
MAX_SCHEDULE_POINTS = 10_000
MAX_SCHEDULE_TIME_S = 86_400.0


@dataclass(frozen=True)
class SpeedSchedule:
    times_s: tuple[float, ...]
    speeds_mps: tuple[float, ...]

    @property
    def constant(self) -> bool:
        return len(self.speeds_mps) == 1

    def speed_at(self, t_s: float) -> float:
        times, speeds = self.times_s, self.speeds_mps
        if len(speeds) == 1 or t_s <= times[0]:
            return speeds[0]
        if t_s >= times[-1]:
            return speeds[-1]
        i = bisect.bisect_right(times, t_s) - 1
        fraction = (t_s - times[i]) / (times[i + 1] - times[i])
        return speeds[i] + fraction * (speeds[i + 1] - speeds[i])


def parse_speed(value, where: str = "config['speed_mps']") -> SpeedSchedule:
    """A :class:`SpeedSchedule` from a number or a list of [time_s, speed_mps] pairs; clear errors otherwise."""
    if _is_number(value):
        return SpeedSchedule((0.0,), (_speed(value, where),))
    if not isinstance(value, (list, tuple)) or not value:
        raise BadInput(f"{where}: must be a speed in m/s or a non-empty list of [time_s, speed_mps] pairs, "
                         f"got {value!r}")
    if len(value) > MAX_SCHEDULE_POINTS:
        raise BadInput(f"{where}: {len(value)} schedule points exceed the limit of {MAX_SCHEDULE_POINTS}")
    times, speeds = [], []
    for index, point in enumerate(value):
        if not isinstance(point, (list, tuple)) or len(point) != 2 or not all(_is_number(v) for v in point):
            raise BadInput(f"{where}[{index}]: must be a [time_s, speed_mps] pair of numbers, got {point!r}")
        time_s = float(point[0])
        if not (math.isfinite(time_s) and 0.0 <= time_s <= MAX_SCHEDULE_TIME_S):
            raise BadInput(f"{where}[{index}]: time_s {point[0]!r} outside [0, {MAX_SCHEDULE_TIME_S:.0f}] s")
        if times and time_s <= times[-1]:
            raise BadInput(f"{where}[{index}]: time_s {time_s} must be later than the previous {times[-1]}")
        times.append(time_s)
        speeds.append(_speed(point[1], f"{where}[{index}]"))
    return SpeedSchedule(tuple(times), tuple(speeds))


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _speed(value, where: str) -> float:
    speed = float(value) if _is_number(value) else math.nan
    if not (math.isfinite(speed) and 0.0 < speed <= MAX_SPEED_MPS):
        raise BadInput(f"{where}: speed {value!r} m/s outside (0, {MAX_SPEED_MPS:.0f}] m/s")
    return speed
