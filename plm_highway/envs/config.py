"""Checks of the env's configuration and reset options, before anything is built.

Every setting has a documented range; a value outside it (NaN and infinities included) is refused
with a :class:`~plm_highway.errors.BadInput` naming the key, the value and the range. The ranges:

===============================  ===============================================================
``start_lane``                   None (the middle lane) or an integer lane index of the track
``speed_mps``                    (0, 70] m/s, or a schedule (see :mod:`plm_highway.envs.speed`)
``sharp_turn_braking``           None, or a dict of ``SharpTurnBraking`` fields (:mod:`plm_highway.envs.speed`)
``max_steering_rad``             (0, 1] rad at the front wheels
``steering_time_constant_s``     [0, 5] s
``processing_delay_steps``       integer 0..10 policy steps
``simulation_frequency``         integer 1..1000 Hz, a multiple of ``policy_frequency``
``policy_frequency``             integer 1..1000 Hz
``map_px_per_m``                 [1, 40] px/m (and the map's pixel bound, ``camera/ground_map.py``)
``duration_s``                   None (until the end of an open track) or (0, 1,000,000] s
``curvature_preview_s``          [0, 10] s
``start_arc_length_m``           [0, track length] m
``start_offset_m``               keeps the car's centre on the road: [-w - o, w - o] m, with w half
                                 the road's width and o the start lane's offset
``start_heading_error_rad``      [-pi/2, pi/2]
``screen_width``, ``_height``    integers 16..4096 px; ``scaling`` (0, 100] px/m
``camera``                       see :class:`~plm_highway.camera.pinhole.CameraConfig`
``vehicle_model``/``_params``    see :mod:`plm_highway.vehicle.models`
===============================  ===============================================================

Unknown keys are refused too: a misspelt setting must not silently fall back to its default. So
are other values of highway-env's settings that this env does not use (``observation``,
``action``, ``manual_control`` and the viewer's: :data:`FIXED_SETTINGS`), a config that is not a
dict, and integers too large for a float (refused by range, not by an OverflowError).
"""

from __future__ import annotations

import math

from plm_highway.errors import BadInput

MAX_FREQUENCY_HZ = 1000
MAX_STEERING_TIME_CONSTANT_S = 5.0
MAX_PROCESSING_DELAY_STEPS = 10


def as_float(value) -> float:
    """A number as a float; NaN for anything else, and for an integer too large for a float (10**400)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return math.nan
    try:
        return float(value)
    except OverflowError:
        return math.nan


def shown(value, limit: int = 40) -> str:
    """``repr(value)``, cut: a 400-digit integer is named, not printed whole."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def number_in(config: dict, key: str, low: float, high: float, open_low: bool = False, where: str = "config") -> float:
    """``config[key]`` as a float in [low, high] ((low, high] with ``open_low``), or a clear error."""
    value = config[key]
    number = as_float(value)
    if not ((low < number if open_low else low <= number) and number <= high):  # False for NaN
        bracket = "(" if open_low else "["
        raise BadInput(f"{where}[{key!r}] = {shown(value)}: must be a number in {bracket}{low:g}, {high:g}]")
    return number


def integer_in(config: dict, key: str, low: int, high: int, where: str = "config") -> int:
    value = config[key]
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise BadInput(f"{where}[{key!r}] = {shown(value)}: must be an integer from {low} to {high}")
    return value


# highway-env settings this env does not use (it draws its own camera frames and top-down view, drives
# one car, and fixes its observation and action): any value but highway-env's default would be ignored
# silently, so it is refused instead.
FIXED_SETTINGS = ("observation", "action", "manual_control", "real_time_rendering", "render_agent",
                  "show_trajectories", "centering_position", "other_vehicles_type",
                  "neighbour_vehicles_connected_lanes")


def check_fixed_settings(config: dict, defaults: dict) -> None:
    for key in FIXED_SETTINGS:
        if key in defaults and config.get(key) != defaults[key]:
            raise BadInput(f"config[{key!r}] = {shown(config.get(key), 80)}: this env does not use it "
                           f"(it is fixed to {defaults[key]!r}); leave it out")
    if not isinstance(config.get("offscreen_rendering"), (bool, type(None))):
        raise BadInput(f"config['offscreen_rendering'] = {shown(config.get('offscreen_rendering'))}: must be true "
                       "or false")


def check_unknown_keys(config: dict, defaults: dict) -> None:
    unknown = sorted(set(config) - set(defaults))
    if unknown:
        raise BadInput(f"config: unknown keys {unknown}; allowed {sorted(defaults)}")


def check_env_config(config: dict) -> None:
    """Every scalar setting that does not need the track (those are checked by :func:`check_start`)."""
    number_in(config, "max_steering_rad", 0.0, 1.0, open_low=True)
    number_in(config, "steering_time_constant_s", 0.0, MAX_STEERING_TIME_CONSTANT_S)
    integer_in(config, "processing_delay_steps", 0, MAX_PROCESSING_DELAY_STEPS)
    policy_hz = integer_in(config, "policy_frequency", 1, MAX_FREQUENCY_HZ)
    sim_hz = integer_in(config, "simulation_frequency", 1, MAX_FREQUENCY_HZ)
    if sim_hz % policy_hz:
        raise BadInput(
            f"config['simulation_frequency'] = {sim_hz}: must be a positive integer multiple of "
            f"policy_frequency={policy_hz}"
        )
    number_in(config, "map_px_per_m", 1.0, 40.0)
    if config["duration_s"] is not None:
        number_in(config, "duration_s", 0.0, 1e6, open_low=True)
    number_in(config, "curvature_preview_s", 0.0, 10.0)
    integer_in(config, "screen_width", 16, 4096)
    integer_in(config, "screen_height", 16, 4096)
    number_in(config, "scaling", 0.0, 100.0, open_low=True)


def check_start(start: dict, track, lane_offsets_m: tuple[float, ...], start_lane, overridden=()) -> int:
    """The start pose settings against the track; returns the start lane. Keys in ``overridden`` came
    from ``reset(options=...)`` and are named so in errors."""
    if start_lane is None:
        lane = track.lanes // 2
    elif isinstance(start_lane, bool) or not isinstance(start_lane, int) or not 0 <= start_lane < track.lanes:
        raise BadInput(f"config['start_lane'] = {shown(start_lane)}: must be None or a lane index from 0 to "
                         f"{track.lanes - 1} (track {track.name!r} has {track.lanes} lanes)")
    else:
        lane = start_lane
    def where(key: str) -> str:
        return "reset options" if key in overridden else "config"

    number_in(start, "start_arc_length_m", 0.0, track.length_m, where=where("start_arc_length_m"))
    half_width_m, lane_offset_m = track.road_half_width_m, lane_offsets_m[lane]
    number_in(start, "start_offset_m", -half_width_m - lane_offset_m, half_width_m - lane_offset_m,
              where=where("start_offset_m"))
    number_in(start, "start_heading_error_rad", -math.pi / 2, math.pi / 2, where=where("start_heading_error_rad"))
    return lane
