"""Synthetic data streams with a known perception latency: a car weaving on a lane, its fast sensors, a late camera.

For checking the latency estimator (:mod:`plm_highway.latency.estimate`) where the truth is known exactly, and
for the lessons. The car is the kit's kinematic bicycle (:mod:`plm_highway.vehicle.models`) at constant speed on a
lane of constant curvature (0: a straight); its front-wheel angle is a sum of sinusoids. At every tick of
``rate_hz`` the stream holds the fast sensors (yaw rate, speed, wheel angle, as the car has them now) and the
lane offset and heading as a camera would report them: those of ``latency_s`` earlier (a
:class:`~plm_highway.latency.profiles.LatencyProfile` or a constant), plus Gaussian noise, or NaN for a dropped
frame. Every random draw takes the caller's generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.latency.profiles import LatencyProfile, parse_profile
from plm_highway.vehicle.models import vehicle_model

FINE_STEP_S = 0.002  # the car is integrated this finely; a late sample is read from this track by interpolation


@dataclass(frozen=True)
class Weave:
    """The front-wheel angle: ``sum_i amplitude_i sin(2 pi f_i t + phase_i)`` [rad], on top of the lane's own."""

    amplitudes_rad: tuple[float, ...] = (0.01,)
    frequencies_hz: tuple[float, ...] = (0.5,)
    phases_rad: tuple[float, ...] = (0.0,)

    def __post_init__(self):
        if not len(self.amplitudes_rad) == len(self.frequencies_hz) == len(self.phases_rad):
            raise BadInput("Weave: amplitudes_rad, frequencies_hz and phases_rad must have one entry per sinusoid")
        for name in ("amplitudes_rad", "frequencies_hz", "phases_rad"):
            if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in getattr(self, name)):
                raise BadInput(f"Weave.{name}={getattr(self, name)!r}: must be finite numbers")

    def steer_rad(self, t_s: np.ndarray) -> np.ndarray:
        steer = np.zeros_like(t_s, dtype=float)
        for amplitude, frequency, phase in zip(self.amplitudes_rad, self.frequencies_hz, self.phases_rad):
            steer += amplitude * np.sin(2.0 * math.pi * frequency * t_s + phase)
        return steer


@dataclass(frozen=True)
class StreamSpec:
    """A synthetic drive: how long, how often, how fast, on which lane, steering how, and how late the camera is."""

    duration_s: float = 10.0
    rate_hz: float = 20.0
    speed_mps: float = 16.7
    curvature_1pm: float = 0.0
    weave: Weave = Weave()
    latency: str | float = 0.25  # a latency spec (plm_highway.latency.parse_profile) or seconds
    offset_noise_m: float = 0.02
    heading_noise_rad: float = 0.003
    drop_fraction: float = 0.0  # each camera sample is missing with this probability

    def __post_init__(self):
        checks = (("duration_s", 0.5, 3600.0), ("rate_hz", 1.0, 1000.0), ("speed_mps", 1.0, 70.0),
                  ("curvature_1pm", -0.1, 0.1), ("offset_noise_m", 0.0, 10.0), ("heading_noise_rad", 0.0, 1.0),
                  ("drop_fraction", 0.0, 0.99))
        for name, low, high in checks:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
                raise BadInput(f"StreamSpec.{name}={value!r}: must be a number in [{low:g}, {high:g}]")
        parse_profile(self.latency)


def _lane_state(x_m, y_m, heading_rad, curvature_1pm: float) -> tuple[np.ndarray, np.ndarray]:
    """(offset left of the lane centre [m], heading minus the lane's [rad]) on a lane through the origin along +x,
    curving left with ``curvature_1pm`` (a circle centred at (0, 1/kappa)).

    Written in kappa, not the radius, so that a straight lane (kappa 0) and a nearly straight one (a radius beyond
    what a float holds) are the same formula: with s = |kappa| * (distance from the centre),
    offset = (1 - s) / kappa = (2y - kappa (x^2 + y^2)) / (1 + s), and the tangent is the angle of
    (kappa x, kappa y - 1) turned by 90 degrees, whatever kappa's sign."""
    x, y, k = np.asarray(x_m, float), np.asarray(y_m, float), float(curvature_1pm)
    s = np.hypot(k * x, k * y - 1.0)
    offset_m = (2.0 * y - k * (x * x + y * y)) / (1.0 + s)
    tangent_rad = np.arctan2(k * y - 1.0, k * x) + math.pi / 2
    return offset_m, np.remainder(np.asarray(heading_rad, float) - tangent_rad + math.pi, 2 * math.pi) - math.pi


def synthetic_stream(spec: StreamSpec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The stream of ``spec`` (module docstring): arrays ``time_s``, ``yaw_rate_radps``, ``speed_mps``,
    ``steer_rad``, ``lane_offset_m``, ``lane_heading_rad`` (NaN where dropped) and ``true_latency_s``."""
    model = vehicle_model("kinematic")
    params = model.default_params
    fine_t = np.arange(0.0, spec.duration_s + FINE_STEP_S / 2, FINE_STEP_S)
    # The wheel angle that holds a kinematic car on the lane's circle, plus the weave.
    lane_steer_rad = math.atan(params.wheelbase_m * spec.curvature_1pm)
    fine_steer = lane_steer_rad + spec.weave.steer_rad(fine_t)
    state = model.initial_state(0.0, 0.0, 0.0, float(fine_steer[0]), spec.speed_mps, params)
    poses = np.empty((len(fine_t), 3))
    yaw_rates = np.empty(len(fine_t))
    for k in range(len(fine_t)):
        poses[k] = state.x_m, state.y_m, state.heading_rad
        yaw_rates[k] = model.sensors(state, float(fine_steer[k]), spec.speed_mps, params).yaw_rate_radps
        if k + 1 < len(fine_t):
            state = model.step(state, float(fine_steer[k]), float(fine_steer[k + 1]), spec.speed_mps, spec.speed_mps,
                               FINE_STEP_S, params)
    offset_m, heading_rad = _lane_state(poses[:, 0], poses[:, 1], poses[:, 2], spec.curvature_1pm)

    profile: LatencyProfile = parse_profile(spec.latency)
    profile.reset(rng)
    ticks = np.arange(0.0, spec.duration_s + 1e-9, 1.0 / spec.rate_hz)
    latency_s = np.array([profile.latency_s(t) for t in ticks])
    captured = np.maximum(ticks - latency_s, 0.0)
    lane_offset = np.interp(captured, fine_t, offset_m) + spec.offset_noise_m * rng.standard_normal(len(ticks))
    lane_heading = np.interp(captured, fine_t, heading_rad) + spec.heading_noise_rad * rng.standard_normal(len(ticks))
    dropped = rng.random(len(ticks)) < spec.drop_fraction
    lane_offset[dropped] = np.nan
    lane_heading[dropped] = np.nan
    # The fast sensors describe the car at their tick (the fine track is integrated with the wheel angle at each
    # fine step's start, so the yaw rate sampled at a tick holds over the fine step after it: a shift of
    # FINE_STEP_S / 2, negligible against the frame periods the estimator is asked to resolve).
    return {"time_s": ticks, "yaw_rate_radps": np.interp(ticks, fine_t, yaw_rates),
            "speed_mps": np.full(len(ticks), spec.speed_mps), "steer_rad": np.interp(ticks, fine_t, fine_steer),
            "lane_offset_m": lane_offset, "lane_heading_rad": lane_heading, "true_latency_s": latency_s}
