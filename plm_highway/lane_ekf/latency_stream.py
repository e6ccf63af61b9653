"""The perception latency estimated from a lane-keeping env's stream, for PLM-Net, the EKF and the logs.

:class:`CameraLatencyObserver` turns what a car has at each policy step into the estimator's input
(:mod:`plm_highway.latency.estimate`): the fast sensors from ``info`` (``time_s``, ``yaw_rate_radps``,
``speed_mps``, ``steering_angle_rad``: the car's own clock, no delay) and the lane measured in the late
camera frame (:class:`~plm_highway.lane_ekf.lane_camera.LaneDetector`). Nothing else of ``info`` is
read: in particular neither ``observation_age_s``, ``latency_s`` nor ``observed_state`` (the truth the
estimate is judged against).

:class:`LatencyEstimateWrapper` wraps the latency wrapper and adds the estimate to every ``info``:

- ``latency_estimate_s``: the latency a consumer should use now (the newest estimable estimate, the step
  detector's, or the prior before any evidence; :attr:`~plm_highway.latency.estimate.LatencyEstimate.held_s`);
- ``latency_estimate_std_s``: the standard deviation of the window's estimate (inf while the cost is flat);
- ``latency_estimable``: whether the estimate is claimed now (its interval within a frame, and it has held still);
- ``latency_changing``: not claimed because the latency has just stepped or the newest samples disagree with the
  last claim (``latency_estimate_s`` may then be stale); neither flag: the driving carried too little information.

PLM-Net told the estimate reads ``latency_estimate_s`` (``latency_source="estimated"``); so does the EKF
policy, which re-stamps each camera measurement by it. The frame the observer measures is the one the
wrapper delivers (image noise that a run adds afterwards for the policy is not in it).

**A steering probe.** A lag is told only by the car's motion relative to the lane, and a car that keeps its lane
well hardly moves relative to it. ``LatencyEstimation(probe_rad=...)`` adds a small known excitation to every
steering command (:func:`probe_rad_at`: two sines, so that no lag in the estimator's range aliases another), which
the fast sensors and, later, the camera both see. It buys identifiability with lane offset: the report of
``plm-highway estimate latency`` measures both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import gymnasium
import numpy as np

from plm_highway.lane_ekf.lane_camera import LaneDetector, LaneDetectorConfig, LaneMeasurement
from plm_highway.latency.estimate import (
    FastSample,
    LaneSample,
    LatencyEstimate,
    LatencyEstimator,
    LatencyEstimatorConfig,
)

INFO_ESTIMATE = "latency_estimate_s"
INFO_STD = "latency_estimate_std_s"
INFO_ESTIMABLE = "latency_estimable"
INFO_CHANGING = "latency_changing"
ESTIMATE_KEYS = (INFO_ESTIMATE, INFO_STD, INFO_ESTIMABLE, INFO_CHANGING)
# With ``record``: what the estimator was given at the tick (after the stream's impairments), for writing a
# recording of the stream without capture timestamps.
STREAM_KEYS = ("stream_time_s", "stream_yaw_rate_radps", "stream_speed_mps", "stream_steer_rad",
               "stream_lane_offset_m", "stream_lane_heading_rad")
FAST_SENSOR_KEYS = ("time_s", "yaw_rate_radps", "speed_mps", "steering_angle_rad")


def fast_sample(info: dict) -> FastSample:
    """The car's own sensors in ``info`` (and nothing else of it)."""
    return FastSample(*(float(info[key]) for key in FAST_SENSOR_KEYS))


def lane_sample(measurement: LaneMeasurement | None) -> LaneSample | None:
    if measurement is None:
        return None
    return LaneSample(measurement.offset_m, measurement.heading_rad)


def env_sensor_shift_s(env_config: dict) -> float:
    """When the motion of the kit env's fast-sensor sample happens, relative to its tick
    (:attr:`~plm_highway.latency.estimate.LatencyEstimatorConfig.fast_sensor_shift_s`).

    The env moves the car over each simulation step with the wheel angle at the step's start
    (:mod:`plm_highway.vehicle.kinematic`) and reports the yaw rate for the wheel angle at its end. Without a
    steering actuator both are the command of that step: the sample describes the step before its tick
    (-dt/2). With an actuator the angle at the step's end is the one the next step starts with (+dt/2).
    """
    step_s = 1.0 / float(env_config["simulation_frequency"])
    return 0.5 * step_s if float(env_config.get("steering_time_constant_s", 0.0)) > 0 else -0.5 * step_s


class CameraLatencyObserver:
    """Feeds the estimator from ``(frame, info)``: the lane measured in the frame, the fast sensors in ``info``.

    ``drop_rng`` and ``drop_fraction``: lose lane measurements at random; ``clock_rate``: the car's clock runs at
    that rate (:class:`LatencyEstimation`). :attr:`last_input` is what the estimator was given last.
    """

    def __init__(self, detector: LaneDetector, config: LatencyEstimatorConfig | None = None,
                 drop_fraction: float = 0.0, drop_rng: np.random.Generator | None = None, clock_rate: float = 1.0):
        self.detector = detector
        self.estimator = LatencyEstimator(LatencyEstimatorConfig() if config is None else config)
        self.drop_fraction, self.drop_rng, self.clock_rate = drop_fraction, drop_rng, clock_rate
        if drop_fraction > 0 and drop_rng is None:
            raise ValueError("CameraLatencyObserver: dropping lane measurements needs the caller's drop_rng")
        self.reset()

    def reset(self) -> None:
        self.estimator.reset()
        self._previous: LaneMeasurement | None = None
        self.frames_missed = 0
        self.last_input: tuple[FastSample, LaneSample | None] | None = None

    def observe(self, frame: np.ndarray, info: dict) -> LatencyEstimate:
        measurement = self.detector.measure(frame, self._previous)
        if measurement is None:
            self.frames_missed += 1
        else:
            self._previous = measurement
        lane = lane_sample(measurement)
        if self.drop_fraction > 0 and self.drop_rng.random() < self.drop_fraction:
            lane = None
        fast = fast_sample(info)
        if self.clock_rate != 1.0:
            fast = fast._replace(time_s=fast.time_s * self.clock_rate)
        self.last_input = (fast, lane)
        return self.estimator.update(fast, lane)


def estimate_info(estimate: LatencyEstimate) -> dict:
    """The ``info`` entries of one estimate (plain floats and a bool, for the logs)."""
    return {INFO_ESTIMATE: float(estimate.held_s), INFO_STD: float(estimate.std_s),
            INFO_ESTIMABLE: bool(estimate.estimable), INFO_CHANGING: estimate.state == "changing"}


@dataclass(frozen=True)
class LatencyEstimation:
    """How a run estimates its latency (plain data: it travels to pool workers with the run).

    ``drop_fraction`` and ``clock_rate`` impair the stream the estimator sees, for robustness measurements: each
    lane measurement is lost with that probability (seeded by the run's seed), and the car's clock runs at
    ``clock_rate`` times true time (1.01: a clock that drifts 1%).
    """

    estimator: LatencyEstimatorConfig = LatencyEstimatorConfig()
    # None: the sensor timing the env's own configuration implies (env_sensor_shift_s); a number overrides it.
    fast_sensor_shift_s: float | None = None
    drop_fraction: float = 0.0
    clock_rate: float = 1.0
    record: bool = False  # add what the estimator was given to info (STREAM_KEYS), for writing a recording
    # The steering probe (probe_rad_at), added to every command: its amplitude at the front wheels [rad] (0: none)
    # and its tones' periods [s]. 1.0 s and 0.6 s: the slower tone is at least the estimator's lag range (1 s), so a
    # lag one period off does not fit as well; the faster one makes the cost curve steep.
    probe_rad: float = 0.0
    probe_periods_s: tuple[float, ...] = (1.0, 0.6)

    def __post_init__(self):
        if not (isinstance(self.drop_fraction, (int, float)) and 0.0 <= self.drop_fraction < 1.0):
            raise ValueError(f"LatencyEstimation.drop_fraction={self.drop_fraction!r}: must be in [0, 1)")
        if not (isinstance(self.clock_rate, (int, float)) and 0.5 <= self.clock_rate <= 2.0):
            raise ValueError(f"LatencyEstimation.clock_rate={self.clock_rate!r}: must be in [0.5, 2]")
        if isinstance(self.probe_rad, bool) or not (isinstance(self.probe_rad, (int, float))
                                                     and 0.0 <= self.probe_rad <= 0.1):
            raise ValueError(f"LatencyEstimation.probe_rad={self.probe_rad!r}: must be in [0, 0.1] rad")
        if not (isinstance(self.probe_periods_s, tuple) and self.probe_periods_s
                and all(isinstance(p, (int, float)) and not isinstance(p, bool) and 0.2 <= p <= 10.0
                        for p in self.probe_periods_s)):
            raise ValueError(f"LatencyEstimation.probe_periods_s={self.probe_periods_s!r}: must be a non-empty tuple "
                             "of periods in [0.2, 10] s")


DROP_STREAM = 13  # lost lane measurements draw from np.random.default_rng([seed, DROP_STREAM])


def probe_rad_at(time_s: float, amplitude_rad: float, periods_s: tuple[float, ...]) -> float:
    """The steering probe at ``time_s`` [rad at the front wheels]: the mean-square-normalised sum of one sine per
    period (the k-th shifted by k rad, so the tones do not all start in phase); its RMS is ``amplitude_rad`` / sqrt 2."""
    if amplitude_rad == 0.0:
        return 0.0
    tones = sum(math.sin(2.0 * math.pi * time_s / period_s + k) for k, period_s in enumerate(periods_s))
    return amplitude_rad * tones / math.sqrt(len(periods_s))


class LatencyEstimateWrapper(gymnasium.Wrapper):
    """Adds the latency estimated from the stream to ``info`` (module docstring). Wrap a ``LatencyWrapper``."""

    def __init__(self, env: gymnasium.Env, estimation: LatencyEstimation = LatencyEstimation()):
        super().__init__(env)
        self.estimation = estimation
        self.observer: CameraLatencyObserver | None = None

    def _make_observer(self, seed: int | None) -> CameraLatencyObserver:
        base = self.env.unwrapped
        shift_s = self.estimation.fast_sensor_shift_s
        if shift_s is None:
            shift_s = env_sensor_shift_s(base.config)
        config = self.estimation.estimator
        if not math.isclose(config.fast_sensor_shift_s, shift_s):
            config = replace(config, fast_sensor_shift_s=shift_s)
        detector = LaneDetector(base.camera_config, LaneDetectorConfig(lane_width_m=base.track.lane_width_m))
        estimation = self.estimation
        drop_rng = np.random.default_rng([0 if seed is None else seed, DROP_STREAM])
        return CameraLatencyObserver(detector, config, estimation.drop_fraction, drop_rng, estimation.clock_rate)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        # Rates, camera and track are read at every reset: reset(options=...) may change them.
        self.observer = self._make_observer(seed)
        self._time_s = float(info["time_s"])
        return obs, self._with_estimate(obs, info)

    def step(self, action):
        if self.estimation.probe_rad > 0:
            probe_rad = probe_rad_at(self._time_s, self.estimation.probe_rad, self.estimation.probe_periods_s)
            action = np.asarray(action, dtype=np.float32) + np.float32(
                probe_rad / float(self.env.unwrapped.config["max_steering_rad"]))
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._time_s = float(info["time_s"])
        return obs, reward, terminated, truncated, self._with_estimate(obs, info)

    def _with_estimate(self, obs, info: dict) -> dict:
        info = {**info, **estimate_info(self.observer.observe(obs, info))}
        if self.estimation.record:
            fast, lane = self.observer.last_input
            info.update(zip(STREAM_KEYS, (*fast, math.nan if lane is None else lane.offset_m,
                                          math.nan if lane is None else lane.heading_rad)))
        return info
