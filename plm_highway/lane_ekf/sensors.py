"""Sensors as a car has them: IMU and steering-angle sensor with noise and bias, and a late camera.

Every random draw takes the caller's :class:`numpy.random.Generator`.

Camera processing delay (:func:`plm_highway.latency.profiles.parse_camera_delay`): any kit latency profile
(:func:`plm_highway.latency.parse_profile`: ``const:0.3``, ``steps:LO-HI:PERIOD``, ``sine:...``,
``ramp:...``, ``trace:...``, looked up at the frame's capture time) or ``frame:LO-HI``: a new delay
drawn uniformly from [LO, HI] s for every frame, like the paper's measured ~0.3 s per frame
(Sensors 2025, 25, 6251, Figure 6). Delays are bounded by :data:`plm_highway.latency.profiles.MAX_CAMERA_DELAY_S`.

The processing pipeline has one worker, as in the paper: a frame is captured when the worker is free
(at the next camera frame tick), and its lane measurement arrives ``delay`` later. So the camera
measurement rate is about ``1 / delay`` and measurements arrive in capture order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plm_highway.latency.profiles import parse_camera_delay


@dataclass(frozen=True)
class ImuConfig:
    """A low-cost MEMS IMU: white noise per sample and a constant bias."""

    yaw_rate_noise_std_radps: float = 0.003  # ~0.17 deg/s per 100 Hz sample
    yaw_rate_bias_radps: float = 0.002  # ~0.11 deg/s left after calibration at standstill
    lateral_acceleration_noise_std_mps2: float = 0.1
    lateral_acceleration_bias_mps2: float = 0.05

    def __post_init__(self):
        _check_finite(self, nonnegative=("yaw_rate_noise_std_radps", "lateral_acceleration_noise_std_mps2"))

    def measure(self, yaw_rate_radps: float, lateral_acceleration_mps2: float, rng: np.random.Generator) -> np.ndarray:
        """``[a_y, r]`` as the IMU reports them."""
        noise = rng.standard_normal(2)
        return np.array([
            lateral_acceleration_mps2 + self.lateral_acceleration_bias_mps2 + self.lateral_acceleration_noise_std_mps2 * noise[0],
            yaw_rate_radps + self.yaw_rate_bias_radps + self.yaw_rate_noise_std_radps * noise[1],
        ])


@dataclass(frozen=True)
class SteeringSensorConfig:
    """Steering-angle sensor, expressed at the front wheel (the column angle over the steering ratio)."""

    noise_std_rad: float = 0.0005  # ~0.4 deg at the steering wheel with a 15:1 ratio
    bias_rad: float = 0.0005
    quantisation_rad: float = 0.1 / 15 * math.pi / 180  # 0.1 deg steering-wheel resolution

    def __post_init__(self):
        _check_finite(self, nonnegative=("noise_std_rad", "quantisation_rad"))

    def measure(self, steer_rad: float, rng: np.random.Generator) -> float:
        value = steer_rad + self.bias_rad + self.noise_std_rad * rng.standard_normal()
        if self.quantisation_rad > 0:
            value = round(value / self.quantisation_rad) * self.quantisation_rad
        return float(value)


@dataclass(frozen=True)
class LaneMeasurementNoise:
    """Error added to the camera's lane measurement ``[d m, dpsi rad, kappa 1/m]``: a constant bias plus
    Gauss-Markov noise (first order, stationary std ``std``, correlation time ``correlation_time_s``), so that
    measurements close in time share their error as a lane detector's do from frame to frame."""

    bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    correlation_time_s: tuple[float, float, float] = (0.0, 0.0, 0.0)  # 0: independent from one frame to the next

    def __post_init__(self):
        for name in ("bias", "std", "correlation_time_s"):
            values = getattr(self, name)
            if len(values) != 3 or not all(math.isfinite(v) for v in values):
                raise ValueError(f"LaneMeasurementNoise.{name}: need 3 finite values, got {values!r}")
            if name != "bias" and min(values) < 0:
                raise ValueError(f"LaneMeasurementNoise.{name}: must be >= 0, got {values!r}")

    def sample(self, times_s, rng: np.random.Generator) -> np.ndarray:
        """The errors ``(n, 3)`` of measurements captured at ``times_s`` (non-decreasing), the first stationary."""
        times_s = np.asarray(times_s, float)
        if times_s.ndim != 1 or np.any(np.diff(times_s) < 0) or not np.all(np.isfinite(times_s)):
            raise ValueError("LaneMeasurementNoise.sample: times_s must be finite and non-decreasing")
        std = np.asarray(self.std)
        tau = np.asarray(self.correlation_time_s)
        draws = rng.standard_normal((len(times_s), 3))
        out = np.empty((len(times_s), 3))
        state = std * draws[0] if len(times_s) else None
        for k in range(len(times_s)):
            if k:
                gap_s = times_s[k] - times_s[k - 1]
                with np.errstate(divide="ignore"):
                    keep = np.where(tau > 0, np.exp(-gap_s / np.where(tau > 0, tau, 1.0)), 0.0)
                state = keep * state + np.sqrt(1.0 - keep ** 2) * std * draws[k]
            out[k] = state
        return out + np.asarray(self.bias)


@dataclass(frozen=True)
class CameraTiming:
    """When frames are captured and when their lane measurements arrive (all on the sensor clock)."""

    delay: str = "frame:0.25-0.35"
    frame_rate_hz: float = 25.0  # the camera's own frame rate; the worker takes the next frame when free

    def __post_init__(self):
        parse_camera_delay(self.delay)
        if not (math.isfinite(self.frame_rate_hz) and 0 < self.frame_rate_hz <= 1000):
            raise ValueError(f"CameraTiming.frame_rate_hz={self.frame_rate_hz!r} must be in (0, 1000]")

    def schedule(self, duration_s: float, sensor_step_s: float, rng: np.random.Generator) -> list[tuple[float, float]]:
        """``(capture_time_s, arrival_time_s)`` of every frame in ``[0, duration_s]``.

        Capture and arrival times are put on the sensor clock (multiples of ``sensor_step_s``): a frame is
        taken at a sensor tick, and the estimator sees a result at the first tick after it is ready.
        """
        profile = parse_camera_delay(self.delay)
        profile.reset(rng)
        frame_ticks = max(1, round(1.0 / (self.frame_rate_hz * sensor_step_s)))
        schedule: list[tuple[float, float]] = []
        tick = 0
        while tick * sensor_step_s <= duration_s + 1e-9:
            capture_s = tick * sensor_step_s
            delay_s = profile.latency_s(capture_s)
            if not (math.isfinite(delay_s) and delay_s >= 0):
                raise ValueError(f"camera delay {profile.spec!r}: {delay_s!r} s at t={capture_s} s")
            arrival_tick = tick + math.ceil(delay_s / sensor_step_s - 1e-9)
            schedule.append((capture_s, arrival_tick * sensor_step_s))
            # The worker is busy until the arrival; it takes the next camera frame after that.
            tick = max(tick + frame_ticks, math.ceil(arrival_tick / frame_ticks) * frame_ticks)
        return schedule


def _check_finite(config, nonnegative: tuple[str, ...]) -> None:
    for name in config.__dataclass_fields__:
        value = getattr(config, name)
        if not math.isfinite(value):
            raise ValueError(f"{type(config).__name__}.{name}={value!r} is not finite")
        if name in nonnegative and value < 0:
            raise ValueError(f"{type(config).__name__}.{name}={value!r} must be >= 0")
