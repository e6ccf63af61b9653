"""The mitigations by name: per-run objects a :class:`~plm_highway.rollout.policies.VisionPolicy` calls around its
frozen BM.

Each has ``reset()``, ``model_input(frame, info, age_s) -> frame`` (what the BM sees) and
``output(steering, info) -> steering`` (what is issued), and reads from ``info`` only :data:`CONTROL_TIME_KEYS`.
Both dead reckon the car's motion since the frame's capture from its speed and its yaw-rate sensor (white noise
and bias added here, seeded by the run) and build on nothing trained but the BM.

- ``warp`` (policy ``bm-warp``): the BM steers on the late frame re-projected to the car's present pose
  (:mod:`~plm_highway.mitigation.view`). A Smith predictor whose model is the camera's geometry and the car's own
  motion: the BM answers the view it would have now.
- ``smith`` (policy ``bm-smith``): the BM steers on the late frame, plus its own posed feedback gains
  (:mod:`~plm_highway.mitigation.posing`, measured once per model on the train track) times the change of lane
  offset and heading since the capture, predicted in lane coordinates from the lane the late frame shows (the lane
  EKF's camera measurement, :class:`~plm_highway.lane_ekf.lane_camera.LaneDetector`) and the motion. The linear
  Smith predictor around the BM.
"""

from __future__ import annotations

import math
import threading
from dataclasses import asdict

import numpy as np

from plm_highway.camera.pinhole import CameraConfig
from plm_highway.lane_ekf.lane_camera import LaneDetector, LaneDetectorConfig, LaneMeasurement
from plm_highway.lane_ekf.sensors import ImuConfig
from plm_highway.mitigation.odometry import MotionHistory, MotionSample
from plm_highway.mitigation.posing import gains_from_answers, posed_frames
from plm_highway.mitigation.view import present_view

# What a mitigation may read from the env's info at control time (the frame's age is passed in, read by the
# VisionPolicy from its latency source).
CONTROL_TIME_KEYS = frozenset({"time_s", "speed_mps", "yaw_rate_radps"})
MITIGATIONS = {
    "warp": "the BM on the late frame re-projected to the car's present pose (speed and yaw-rate odometry)",
    "smith": "the BM on the late frame plus its posed lane gains times the lane change predicted since the capture",
}
IMU_STREAM = 47  # the mitigation's sensor noise: its own stream of the run's seed
DEFAULT_IMU = ImuConfig()
CALIBRATION_TRACK = "train"  # the BM's gains are measured where it was trained, never on the test track
LANE_WIDTH_M = 4.0  # the kit's tracks


class _Odometry:
    """The motion since a past instant from the seeded, noisy yaw-rate sensor and the speed."""

    def __init__(self, seed: int, imu: ImuConfig = DEFAULT_IMU, history_s: float = 2.0):
        self.seed = seed
        self.imu = imu
        self.motion = MotionHistory(history_s)
        self.reset()

    def reset(self) -> None:
        self.motion.reset()
        self.rng = np.random.default_rng([self.seed, IMU_STREAM])

    def read(self, info) -> float:
        """Record this step's sensors; the time now [s]."""
        now_s = float(info["time_s"])
        yaw_rate_radps = float(self.imu.measure(float(info["yaw_rate_radps"]), 0.0, self.rng)[1])
        self.motion.add(MotionSample(now_s, float(info["speed_mps"]), yaw_rate_radps))
        return now_s


class ViewWarp:
    """``warp``: see the module docstring."""

    def __init__(self, camera: CameraConfig, seed: int = 0):
        self.camera = camera
        self.odometry = _Odometry(seed)

    def reset(self) -> None:
        self.odometry.reset()

    def model_input(self, frame: np.ndarray, info, age_s: float) -> np.ndarray:
        now_s = self.odometry.read(info)
        if not (math.isfinite(age_s) and age_s > 0):
            return frame
        return present_view(frame, self.camera, self.odometry.motion.pose_since(now_s - age_s))

    def output(self, steering: float, info) -> float:
        return steering


_GAINS_LOCK = threading.Lock()


def lane_change(lane: LaneMeasurement | None, pose: tuple[float, float, float]) -> tuple[float, float]:
    """(change of lane offset [m], change of heading error [rad]) of a car that moved by ``pose`` (forward, left,
    yaw in its frame at the start) from where it saw ``lane``: the lane's tangent at the start turned by the
    car's heading error, bent by the lane's curvature (second order in the distance). Without a lane, a straight
    lane along the car."""
    forward_m, left_m, yaw_rad = pose
    heading_rad, curvature_1pm = (lane.heading_rad, lane.curvature_1pm) if lane is not None else (0.0, 0.0)
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    along_m, across_m = c * forward_m - s * left_m, s * forward_m + c * left_m
    return across_m - 0.5 * curvature_1pm * along_m ** 2, yaw_rad - curvature_1pm * along_m


def bm_gains(model_policy, camera: CameraConfig, env_config: dict) -> dict:
    """The BM's posed feedback gains with ``camera``, measured once per model object and camera (kept on the model
    object, which the runs of a process share)."""
    with _GAINS_LOCK:  # batched runs on threads share the model
        measured = model_policy.__dict__.setdefault("posed_gains_by_camera", {})
        if camera not in measured:
            answers: dict[str, list[float]] = {}
            for sweep, frame, info in posed_frames(env_config, CALIBRATION_TRACK, asdict(camera)):
                answers.setdefault(sweep, []).append(float(model_policy(frame, info["speed_mps"], 0.0)))
            measured[camera] = gains_from_answers(answers)
        return measured[camera]


class SmithCorrection:
    """``smith``: see the module docstring. ``gains``: the BM's ``offset_gain_per_m`` and ``heading_gain_per_rad``."""

    def __init__(self, camera: CameraConfig, gains: dict, seed: int = 0):
        self.camera = camera
        self.gains = gains
        self.detector = LaneDetector(camera, LaneDetectorConfig(lane_width_m=LANE_WIDTH_M))
        self.odometry = _Odometry(seed)
        self.reset()

    def reset(self) -> None:
        self.odometry.reset()
        self.lane: LaneMeasurement | None = None
        self._capture_s = -math.inf
        self._correction = 0.0

    def model_input(self, frame: np.ndarray, info, age_s: float) -> np.ndarray:
        now_s = self.odometry.read(info)
        age_s = age_s if math.isfinite(age_s) and age_s > 0 else 0.0
        capture_s = now_s - age_s
        if capture_s > self._capture_s + 1e-9:  # a newer frame: measure its lane (else keep the last one's)
            self.lane = self.detector.measure(frame, self.lane) or self.lane
            self._capture_s = capture_s
        offset_change_m, heading_change_rad = lane_change(self.lane, self.odometry.motion.pose_since(capture_s))
        self._correction = (self.gains["offset_gain_per_m"] * offset_change_m
                            + self.gains["heading_gain_per_rad"] * heading_change_rad)
        return frame

    def output(self, steering: float, info) -> float:
        return float(np.clip(steering + self._correction, -1.0, 1.0))


def make_mitigation(name: str, camera: dict | CameraConfig | None = None, seed: int = 0, model_policy=None,
                    env_config: dict | None = None):
    """The per-run object of mitigation ``name`` (:data:`MITIGATIONS`) for a run whose camera is ``camera`` (a dict
    as conditions hold it, or a :class:`CameraConfig`) and whose seed is ``seed``; ``smith`` also needs the
    ``model_policy`` it corrects and the run's ``env_config`` (to pose the car as it drives)."""
    if name not in MITIGATIONS:
        raise ValueError(f"mitigation {name!r}: expected one of {list(MITIGATIONS)}")
    camera = camera if isinstance(camera, CameraConfig) else CameraConfig.from_dict(camera or {})
    if name == "warp":
        return ViewWarp(camera, seed)
    if model_policy is None:
        raise ValueError("mitigation 'smith' needs the model policy whose gains it applies")
    return SmithCorrection(camera, bm_gains(model_policy, camera, env_config or {}), seed)
