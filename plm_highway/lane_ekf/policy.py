"""Model-based lane keeping under latency: the delay-compensated EKF and a controller on its state.

A policy for ``plm_highway/LaneKeeping-v0`` (usually inside a :class:`~plm_highway.latency.LatencyWrapper`)
with the kit's ``(frame, info) -> normalised steering`` interface. It sees the road only through the
delayed camera frame: the lane is measured from the frame (:class:`~plm_highway.lane_ekf.lane_camera.LaneDetector`)
and fused, re-stamped at the frame's capture time, into the EKF, which the car's own high-rate
sensors carry to the present.

``info`` keys read (nothing else; in particular no privileged lane offset, heading error or curvature):

- ``time_s`` [s] and ``observation_age_s`` [s]: the frame was captured at ``time_s - observation_age_s``
  (the latency wrapper's true age; without the wrapper the age is taken as 0);
- ``speed_mps``: the wheel-speed sensor (used as is);
- ``yaw_rate_radps`` and ``lateral_acceleration_mps2`` (the IMU) and ``front_wheel_angle_rad`` (the
  steering-angle sensor), each with seeded noise and bias added here. Where the env does not provide
  them: the yaw rate is the finite difference of ``heading_rad`` between calls, the lateral
  acceleration is ``speed * yaw rate`` (steady turning), and the front-wheel angle is ``steering``
  (the env's normalised applied steering) times ``max_steering_rad``.

``latency_bias_s`` is a misestimated latency: the frame is re-stamped at
``time_s - (observation_age_s + latency_bias_s)`` (kept within ``[oldest history, now]``).
``latency_source="estimated"`` re-stamps by the latency estimated from the stream instead of the true age:
``info["latency_estimate_s"]`` (:mod:`plm_highway.lane_ekf.latency_stream`; the run must estimate it).

Controller: a discrete LQR on the lane-coordinate error model (:mod:`plm_highway.lane_ekf.lateral_control`)
fed the EKF's ``[d, dpsi, v, r]``, with the curvature feedforward that leaves no steady offset, taken at the
EKF's curvature. Its plant is the car the estimator models (``vehicle``), the loop period, the steering
actuator's lag and the processing delay (``timing``) and the steering range (``max_steering_rad``): under a
set of conditions all of them are the conditions' own (:func:`plm_highway.rollout.policies.ekf_plant`);
the weights follow Bryson's rule with the tolerances of :class:`~plm_highway.lane_ekf.lateral_control.BrysonTolerances`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import gymnasium
import numpy as np

from plm_highway.camera.pinhole import PAPER_CAMERA, CameraConfig
from plm_highway.expert import ExpertPolicy
from plm_highway.lane_ekf.ekf import EstimatorConfig, LaneStateEstimator
from plm_highway.lane_ekf.lane_camera import LaneDetector, LaneDetectorConfig, LaneMeasurement
from plm_highway.lane_ekf.lane_model import DPSI, KAPPA, D, R, V
from plm_highway.lane_ekf.lateral_control import (
    BrysonTolerances,
    LoopTiming,
    LqrLaneController,
    single_track_equivalent,
)
from plm_highway.lane_ekf.sensors import ImuConfig, SteeringSensorConfig
from plm_highway.road.geometry import segment_starts_m
from plm_highway.vehicle.kinematic import HIGHWAY_ENV_VEHICLE
from plm_highway.vehicle.single_track import SingleTrackParams

INFO_YAW_RATE = "yaw_rate_radps"
INFO_LATERAL_ACCELERATION = "lateral_acceleration_mps2"
INFO_FRONT_WHEEL_ANGLE = "front_wheel_angle_rad"
# The frame's age by latency source (as plm_highway.rollout.policies.LATENCY_SOURCES tells PLM-Net).
CAPTURE_AGE_KEYS = {"measured": "observation_age_s", "requested": "latency_s", "estimated": "latency_estimate_s"}

# highway-env's kinematic bicycle (5 m wheelbase, reference point in the middle) as a single-track car
# with tires so stiff that they do not slip: neutral steer, r = u delta / L, v = b r, as the kinematic
# model. The mass and inertia only scale the (very fast) tire transients.
KINEMATIC_ENV_VEHICLE = single_track_equivalent(HIGHWAY_ENV_VEHICLE)


# The lane measurement's error per camera, measured on the train track (never the test track) by
# measure_camera_noise() with the expert driving: the filter takes the full standard deviations. Heavy-tailed
# (robust std about 0.04 m, 0.008 rad, 0.0007 1/m: the misses are near curve entries and exits, where the fitted
# parabola sees the next segment) and correlated frame to frame.
MEASURED_CAMERA_STD = {
    # the kit's 200x66 frames: std 0.142 m, 0.0293 rad, 0.0039 1/m over 2487 frames
    CameraConfig(): (0.14, 0.029, 0.0039),
    # the paper camera (800x800 cropped to 160x160): std 0.157 m, 0.0311 rad, 0.0040 1/m over 2485 frames
    CameraConfig.from_dict(PAPER_CAMERA): (0.16, 0.031, 0.0040),
}


@dataclass(frozen=True)
class EkfPolicyConfig:
    vehicle: SingleTrackParams = KINEMATIC_ENV_VEHICLE  # the car the env simulates, as the estimator models it
    max_steering_rad: float = 0.2  # the env's max_steering_rad (action +-1)
    latency_bias_s: float = 0.0
    # What the frame is re-stamped by: "measured" (the true age, observation_age_s) or "estimated" (the latency
    # estimated from the stream, latency_estimate_s); "requested" (latency_s) is the original PLM-Net's.
    latency_source: str = "measured"
    compensate_delay: bool = True  # False: each frame is fused as if captured now (the uncompensated EKF)
    lane_width_m: float = 4.0  # the kit's tracks
    camera: CameraConfig = field(default_factory=CameraConfig)  # the env's camera
    # The lane measurement's error [d m, dpsi rad, kappa 1/m] as the filter takes it; None: the value measured for
    # this camera (MEASURED_CAMERA_STD).
    camera_std: tuple[float, float, float] | None = None
    process_std: tuple[float, ...] = (0.02, 0.01, 0.3, 0.3, 0.03, 0.004)
    imu: ImuConfig = ImuConfig()
    steering_sensor: SteeringSensorConfig = SteeringSensorConfig()
    history_s: float = 1.0
    # The loop and what lies between the command and the tyres (the conditions'): part of the plant the LQR is
    # designed for (plm_highway.lane_ekf.lateral_control), derived from the conditions, not tuned.
    timing: LoopTiming = LoopTiming()
    tolerances: BrysonTolerances = BrysonTolerances()

    def __post_init__(self):
        if self.camera_std is None:
            if self.camera not in MEASURED_CAMERA_STD:
                raise ValueError(f"EkfPolicyConfig: no lane-measurement noise measured for camera {self.camera}; "
                                 "measure it with measure_camera_noise(camera=...) and pass camera_std")
            object.__setattr__(self, "camera_std", MEASURED_CAMERA_STD[self.camera])
        if not (math.isfinite(self.latency_bias_s) and abs(self.latency_bias_s) <= 1.0):
            raise ValueError(f"EkfPolicyConfig.latency_bias_s={self.latency_bias_s!r} must be within +-1 s")
        if not (math.isfinite(self.max_steering_rad) and 0 < self.max_steering_rad <= 1.0):
            raise ValueError(f"EkfPolicyConfig.max_steering_rad={self.max_steering_rad!r} must be in (0, 1] rad")
        if self.latency_source not in CAPTURE_AGE_KEYS:
            raise ValueError(f"EkfPolicyConfig.latency_source={self.latency_source!r}: expected one of "
                             f"{sorted(CAPTURE_AGE_KEYS)}")

    @property
    def estimator(self) -> EstimatorConfig:
        return EstimatorConfig(vehicle=self.vehicle, process_std=self.process_std, camera_std=self.camera_std,
                               yaw_rate_std_radps=max(self.imu.yaw_rate_noise_std_radps, 1e-4) * 2,
                               lateral_acceleration_std_mps2=max(self.imu.lateral_acceleration_noise_std_mps2, 1e-3) * 2,
                               history_s=self.history_s)


class EkfLaneKeepingPolicy:
    """``(frame, info) -> steering in [-1, 1]`` from the delay-compensated EKF (see the module docstring)."""

    def __init__(self, config: EkfPolicyConfig = EkfPolicyConfig(), seed: int = 0):
        self.config = config
        self.seed = seed
        self.detector = LaneDetector(config.camera, LaneDetectorConfig(lane_width_m=config.lane_width_m))
        self.controller = LqrLaneController(config.vehicle, config.timing, config.max_steering_rad, config.tolerances)
        self.reset()

    def reset(self) -> None:
        """Start an episode: empty history, no lane yet, the sensor noise stream restarted from the seed."""
        self.estimator = LaneStateEstimator(self.config.estimator, compensate_delay=self.config.compensate_delay)
        self.rng = np.random.default_rng(self.seed)
        self.lane: LaneMeasurement | None = None
        self._last_capture_s = -math.inf
        self._last_heading: tuple[float, float] | None = None  # (time, heading) for the yaw-rate fallback
        self.camera_updates = 0
        self.frames_skipped = 0
        self.controller.reset()
        self._wheel_angle_rad = 0.0

    def __call__(self, frame: np.ndarray, info: dict) -> float:
        age_key = CAPTURE_AGE_KEYS[self.config.latency_source]
        if age_key not in info and self.config.latency_source == "estimated":
            raise ValueError("the EKF policy re-stamps by the estimated latency, but info has no 'latency_estimate_s': "
                             "drive it in a run that estimates its latency (latency_estimation)")
        now_s = float(info["time_s"])
        speed_mps = max(float(info["speed_mps"]), 1.0)
        steer_rad, imu = self._sensors(info, now_s, speed_mps)
        self.estimator.step(now_s, steer_rad, speed_mps, imu)
        self._fuse_frame(frame, now_s - float(info.get(age_key, 0.0)) - self.config.latency_bias_s)
        return self._control(self.estimator.state, speed_mps)

    def _sensors(self, info: dict, now_s: float, speed_mps: float) -> tuple[float, np.ndarray]:
        config = self.config
        if INFO_YAW_RATE in info:
            yaw_rate = float(info[INFO_YAW_RATE])
        else:
            heading = float(info["heading_rad"])
            yaw_rate = 0.0
            if self._last_heading is not None and now_s > self._last_heading[0]:
                yaw_rate = math.remainder(heading - self._last_heading[1], 2 * math.pi) / (now_s - self._last_heading[0])
            self._last_heading = (now_s, heading)
        lateral_acceleration = float(info.get(INFO_LATERAL_ACCELERATION, speed_mps * yaw_rate))
        wheel_angle = float(info.get(INFO_FRONT_WHEEL_ANGLE, float(info["steering"]) * config.max_steering_rad))
        self._wheel_angle_rad = config.steering_sensor.measure(wheel_angle, self.rng)
        return self._wheel_angle_rad, config.imu.measure(yaw_rate, lateral_acceleration, self.rng)

    def _fuse_frame(self, frame: np.ndarray, capture_s: float) -> None:
        oldest_s = self.estimator.history[0].time_s
        capture_s = min(max(capture_s, oldest_s), self.estimator.now_s)
        if capture_s <= self._last_capture_s + 1e-9:
            # The same frame again, or an older one (the latency grew): nothing newer to learn.
            self.frames_skipped += 1
            return
        measurement = self.detector.measure(frame, self.lane)
        if measurement is None:
            self.frames_skipped += 1
            return
        self.lane = measurement
        self._last_capture_s = capture_s
        self.estimator.add_camera(measurement.vector, capture_s)
        self.camera_updates += 1

    def _control(self, state: np.ndarray, speed_mps: float) -> float:
        lane_state = state[[D, DPSI, V, R]]
        steer_rad = self.controller.command(lane_state, speed_mps, float(state[KAPPA]), self._wheel_angle_rad)
        return float(np.clip(steer_rad / self.config.max_steering_rad, -1.0, 1.0))


def ekf_policy(compensate_delay: bool = True, latency_bias_s: float = 0.0, seed: int = 0,
               latency_source: str = "measured", **plant) -> EkfLaneKeepingPolicy:
    """The EKF lane-keeping policy as ``plm-highway evaluate --policy ekf`` drives it; ``latency_source``: what it
    re-stamps each frame by (:data:`CAPTURE_AGE_KEYS`); ``plant``: the :class:`EkfPolicyConfig` fields a set of
    conditions fixes (``camera``, ``max_steering_rad``, ``timing``, ``vehicle``), the ideal conditions' by default."""
    return EkfLaneKeepingPolicy(EkfPolicyConfig(latency_bias_s=latency_bias_s, compensate_delay=compensate_delay,
                                                latency_source=latency_source, **plant), seed=seed)


def measure_camera_noise(track="train", seed: int = 0, max_steps: int | None = None,
                         camera: CameraConfig | None = None, steady_only: bool = False) -> dict:
    """The policy's lane measurement against the env's privileged state, with the expert driving ``track``.

    Every frame is measured as it is rendered (no latency: the error of the measurement itself), tracked
    frame to frame as the policy does. ``steady_only``: only frames whose view holds no change of curvature
    (the car more than :data:`STEADY_MARGIN_M` past the last segment start and the next one beyond the
    detector's reach plus that margin), the road the Table 3 scenarios drive on.

    Returns ``{"frames", "missed", "frame_period_s", "bias", "std", "robust_std", "lag1_correlation",
    "correlation_time_s"}``, per component ``[d m, dpsi rad, kappa 1/m]`` (robust std: 1.4826 x median
    absolute deviation; the correlation from consecutive measured frames, its time ``-period / ln(rho)``).
    """
    env = gymnasium.make("plm_highway/LaneKeeping-v0",
                         config={"track": track, **({"camera": asdict(camera)} if camera is not None else {})})
    try:
        frame, info = env.reset(seed=seed)
        base = env.unwrapped
        detector_config = LaneDetectorConfig(lane_width_m=base.track.lane_width_m)
        detector = LaneDetector(base.camera_config, detector_config)
        changes_m = segment_starts_m(base.track)[1:-1]
        reach_m = detector_config.max_forward_m + STEADY_MARGIN_M
        frame_period_s = 1.0 / base.config["policy_frequency"]
        expert = ExpertPolicy()
        expert.reset()
        previous, errors, kept, missed, steps = None, [], [], 0, 0
        while max_steps is None or steps < max_steps:
            measurement = detector.measure(frame, previous)
            if measurement is None:
                missed += 1
            else:
                previous = measurement
                truth = (info["lateral_offset_m"], info["heading_error_rad"], info["curvature_1pm"])
                errors.append(measurement.vector - np.asarray(truth))
                ahead_m = changes_m - info["arc_length_m"]
                kept.append(not steady_only or not np.any((ahead_m > -STEADY_MARGIN_M) & (ahead_m < reach_m)))
            frame, _, terminated, truncated, info = env.step(np.array([expert(frame, info)], dtype=np.float32))
            steps += 1
            if terminated or truncated:
                break
    finally:
        env.close()
    errors, kept = np.array(errors).reshape(-1, 3), np.array(kept, bool)
    if not kept.any():
        raise ValueError(f"measure_camera_noise: no lane measured on track {track!r}"
                         f"{' away from curvature changes' if steady_only else ''}")
    return {"frames": int(kept.sum()), "missed": missed, "frame_period_s": frame_period_s,
            **error_statistics(errors, kept, frame_period_s)}


STEADY_MARGIN_M = 5.0  # the car's length and a step of travel either side of a curvature change


def error_statistics(errors: np.ndarray, kept: np.ndarray, period_s: float) -> dict:
    """Bias, std, robust std and frame-to-frame correlation of ``errors[kept]`` ((n, k), one row per frame).

    The lag-1 correlation pairs consecutive frames that are both kept; its time is ``-period_s / ln(rho)``
    (0 for rho <= 0: no memory from one frame to the next).
    """
    errors, kept = np.asarray(errors, float), np.asarray(kept, bool)
    chosen = errors[kept]
    median = np.median(chosen, axis=0)
    pairs = kept[1:] & kept[:-1]
    correlation = []
    for column in range(errors.shape[1]):
        first, second = errors[:-1, column][pairs], errors[1:, column][pairs]
        ok = len(first) > 2 and first.std() > 0 and second.std() > 0
        correlation.append(float(np.corrcoef(first, second)[0, 1]) if ok else 0.0)
    return {"bias": chosen.mean(axis=0).tolist(), "std": chosen.std(axis=0).tolist(),
            "robust_std": (1.4826 * np.median(np.abs(chosen - median), axis=0)).tolist(),
            "lag1_correlation": correlation,
            "correlation_time_s": [-period_s / math.log(rho) if 0 < rho < 1 else (math.inf if rho >= 1 else 0.0)
                                   for rho in correlation]}
