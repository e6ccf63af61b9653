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

from plm_highway.envs.config import as_float, shown
from plm_highway.errors import BadInput
from plm_highway.vehicle.paper_units import paper_unit_to_front_wheel_rad

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
                         f"got {shown(value)}")
    if len(value) > MAX_SCHEDULE_POINTS:
        raise BadInput(f"{where}: {len(value)} schedule points exceed the limit of {MAX_SCHEDULE_POINTS}")
    times, speeds = [], []
    for index, point in enumerate(value):
        if not isinstance(point, (list, tuple)) or len(point) != 2 or not all(_is_number(v) for v in point):
            raise BadInput(f"{where}[{index}]: must be a [time_s, speed_mps] pair of numbers, got {shown(point)}")
        time_s = as_float(point[0])
        if not (math.isfinite(time_s) and 0.0 <= time_s <= MAX_SCHEDULE_TIME_S):
            raise BadInput(f"{where}[{index}]: time_s {shown(point[0])} outside [0, {MAX_SCHEDULE_TIME_S:.0f}] s")
        if times and time_s <= times[-1]:
            raise BadInput(f"{where}[{index}]: time_s {time_s} must be later than the previous {times[-1]}")
        times.append(time_s)
        speeds.append(_speed(point[1], f"{where}[{index}]"))
    return SpeedSchedule(tuple(times), tuple(speeds))


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _speed(value, where: str) -> float:
    speed = as_float(value)
    if not (math.isfinite(speed) and 0.0 < speed <= MAX_SPEED_MPS):
        raise BadInput(f"{where}: speed {shown(value)} m/s outside (0, {MAX_SPEED_MPS:.0f}] m/s")
    return speed


# ---------------------------------------------------------------------------------------------
# the original run scripts' speed logic
# ---------------------------------------------------------------------------------------------

ORIGINAL_SHARP_TURN_RAD = paper_unit_to_front_wheel_rad(0.25)  # the original's sharp_turn_min, 0.25 in the paper's unit


@dataclass(frozen=True)
class SharpTurnBraking:
    """The speed logic of the original PLM-Net run scripts (AwsKhalil/oscar, ``run_neural`` with its
    ``run_neural`` configuration; read for the behaviour only): full throttle, except that whenever the
    commanded steering exceeds ``sharp_turn_rad`` or the speed exceeds ``max_speed_mps`` (and the car is not
    below ``min_speed_mps``) it brakes, and keeps braking for ``brake_hold_s`` whatever it steers meanwhile.

    The thresholds and the hold are the original's configuration (max_vel 22, sharp_turn_min 0.25, brake
    1.7 s at brake value 0.5, velocity_0 5). How hard its Gazebo car accelerated at throttle 1.0 and slowed
    at brake 0.5 is not recorded anywhere we have: ``throttle_accel_mps2`` and ``brake_decel_mps2`` are
    assumptions (a mid-size saloon's full-throttle acceleration near 60 km/h; half of a firm 8 m/s^2 stop).
    """

    max_speed_mps: float = 22.0
    min_speed_mps: float = 5.0
    sharp_turn_rad: float = ORIGINAL_SHARP_TURN_RAD
    brake_hold_s: float = 1.7
    throttle_accel_mps2: float = 3.0
    brake_decel_mps2: float = 4.0

    def decide(self, braking_until_s: float, time_s: float, speed_mps: float, command_rad: float) -> float:
        """The time until which the car brakes, after the loop iteration at ``time_s`` saw ``command_rad``."""
        if time_s < braking_until_s:  # a brake already applied runs its course
            return braking_until_s
        if speed_mps >= self.min_speed_mps and (abs(command_rad) > self.sharp_turn_rad
                                                or speed_mps > self.max_speed_mps):
            return time_s + self.brake_hold_s
        return braking_until_s

    def speed_after(self, speed_mps: float, braking: bool, dt_s: float) -> float:
        """The speed ``dt_s`` later, braking or at full throttle (never below 0)."""
        if braking:
            return max(0.0, speed_mps - self.brake_decel_mps2 * dt_s)
        return speed_mps + self.throttle_accel_mps2 * dt_s


SHARP_TURN_BRAKING_BOUNDS = {  # field: (low, high), low open
    "max_speed_mps": (0.0, MAX_SPEED_MPS), "min_speed_mps": (0.0, MAX_SPEED_MPS), "sharp_turn_rad": (0.0, 1.0),
    "brake_hold_s": (0.0, 60.0), "throttle_accel_mps2": (0.0, 20.0), "brake_decel_mps2": (0.0, 20.0),
}


def parse_sharp_turn_braking(value, where: str = "config['sharp_turn_braking']") -> SharpTurnBraking | None:
    """None (the speed follows ``speed_mps``) or a dict of :class:`SharpTurnBraking` fields ({}: the original's)."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise BadInput(f"{where}: must be None or a dict of {sorted(SHARP_TURN_BRAKING_BOUNDS)}, got {value!r}")
    unknown = sorted(set(value) - set(SHARP_TURN_BRAKING_BOUNDS))
    if unknown:
        raise BadInput(f"{where}: unknown keys {unknown}; allowed {sorted(SHARP_TURN_BRAKING_BOUNDS)}")
    fields = {}
    for key, raw in value.items():
        low, high = SHARP_TURN_BRAKING_BOUNDS[key]
        number = as_float(raw)
        if not (low < number <= high):
            raise BadInput(f"{where}[{key!r}] = {shown(raw)}: must be a number in ({low:g}, {high:g}]")
        fields[key] = number
    logic = SharpTurnBraking(**fields)
    if logic.min_speed_mps >= logic.max_speed_mps:
        raise BadInput(f"{where}: min_speed_mps {logic.min_speed_mps:g} must be below max_speed_mps "
                       f"{logic.max_speed_mps:g}")
    return logic
