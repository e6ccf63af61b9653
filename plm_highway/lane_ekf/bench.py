"""``bench estimation``: the camera lane measurement's error and cost, and the estimator's cost per step.

Measured in one run, side by side:

- the lane measurement from the image (render not included) against the truth at capture, on the
  calibration seeds of scenarios 1 and 4 (never the scored ones), and its time per frame;
- the filter's parts: one prediction, one IMU update, one camera update, and one re-estimation over
  the history a camera delay of ``delay_s`` needs (``delay_s / step_s`` steps);
- per 100 Hz step, for the three variants: camera only (the lane measurement, amortised over the
  frames it gets), EKF without compensation (step + the camera update when one arrives), EKF with
  compensation (step + the re-estimation when one arrives).
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass

import numpy as np

from plm_highway.camera.ground_map import ground_map
from plm_highway.camera.pinhole import PinholeCamera
from plm_highway.lane_ekf.ekf import EstimatorConfig, LaneStateEstimator, ekf_predict
from plm_highway.lane_ekf.lane_camera import LaneDetector
from plm_highway.lane_ekf.lane_model import H_CAMERA, imu_model, single_track_rows
from plm_highway.lane_ekf.table3 import CALIBRATION_SEEDS, SCENARIOS, SimulationConfig, run_scenario
from plm_highway.road.geometry import reference_pose_at


@dataclass(frozen=True)
class EstimationBench:
    camera_rmse: dict  # "d_m", "dpsi_deg", "kappa_1pm"
    camera_frames: int
    lane_measurement_ms: float  # per frame, from image to [d, dpsi, kappa]
    predict_us: float
    imu_update_us: float
    camera_update_us: float
    reestimation_us: float  # one re-run over the delay's history
    reestimation_steps: int
    camera_rate_hz: float
    per_step_us: dict  # variant -> amortised cost per 100 Hz step
    repeats: int


def bench_estimation(delay_s: float = 0.3, repeats: int = 5, calls: int = 2000,
                     config: SimulationConfig | None = None) -> EstimationBench:
    config = SimulationConfig() if config is None else config
    if not 0 < delay_s <= config.estimator.history_s:
        raise ValueError(f"delay_s={delay_s!r} must be in (0, history_s={config.estimator.history_s}] s")
    if repeats < 1 or calls < 10:
        raise ValueError("repeats must be >= 1 and calls >= 10")
    errors, rates = [], []
    for scenario in (SCENARIOS[0], SCENARIOS[3]):
        run = run_scenario(scenario, CALIBRATION_SEEDS[0], config)
        errors.append(run.camera_errors)
        rates.append(len(run.camera_errors) / run.truth.time_s[-1])
    errors = np.concatenate(errors)
    camera_rmse = {"d_m": float(np.sqrt(np.mean(errors[:, 0] ** 2))),
                   "dpsi_deg": float(np.degrees(np.sqrt(np.mean(errors[:, 1] ** 2)))),
                   "kappa_1pm": float(np.sqrt(np.mean(errors[:, 2] ** 2)))}
    lane_ms = statistics.median(_time_lane_measurement(config) for _ in range(repeats))

    estimator_config = config.estimator
    step_s = config.sensor_step_s
    x = np.array([0.2, 0.01, 0.1, 0.05, 0.02, 0.005])
    p = np.eye(6) * 0.01
    speed = 16.7
    h_imu, _ = imu_model(speed, single_track_rows(speed, estimator_config.vehicle))
    from filterpy.kalman import update as kalman_update  # lazy: filterpy only as this bench's reference

    z_imu, z_cam = h_imu @ x, H_CAMERA @ x
    predict_us = _median_us(lambda: ekf_predict(x, p, 0.01, speed, step_s, estimator_config), calls, repeats)
    imu_us = _median_us(lambda: kalman_update(x, p, z_imu, estimator_config.imu_covariance, h_imu), calls, repeats)
    cam_us = _median_us(lambda: kalman_update(x, p, z_cam, estimator_config.camera_covariance, H_CAMERA), calls, repeats)
    reest_steps = int(round(delay_s / step_s)) + 1
    reest_us = _median_us(lambda: _reestimate_once(estimator_config, step_s, reest_steps, speed),
                          max(calls // 50, 10), repeats) - _median_us(
        lambda: _build_history(estimator_config, step_s, reest_steps, speed), max(calls // 50, 10), repeats)
    camera_rate = float(np.mean(rates))
    frames_per_step = camera_rate * step_s
    step_us = predict_us + imu_us
    per_step = {
        "camera": lane_ms * 1000 * frames_per_step,
        "ekf": step_us + frames_per_step * (cam_us + lane_ms * 1000),
        "ekf_dc": step_us + frames_per_step * (reest_us + lane_ms * 1000),
    }
    return EstimationBench(camera_rmse, len(errors), lane_ms, predict_us, imu_us, cam_us, reest_us, reest_steps,
                           camera_rate, per_step, repeats)


def _time_lane_measurement(config: SimulationConfig) -> float:
    scenario = SCENARIOS[1]
    camera = PinholeCamera(ground_map(scenario.track(), config.map_px_per_m), config.camera)
    detector = LaneDetector(config.camera, config.detector)

    frames = [camera.render(*reference_pose_at(scenario.track(), s)) for s in np.linspace(5, 60, 20)]
    start = time.perf_counter()
    for frame in frames:
        detector.measure(frame)
    return (time.perf_counter() - start) / len(frames) * 1000


def _build_history(config: EstimatorConfig, step_s: float, steps: int, speed: float) -> LaneStateEstimator:
    estimator = LaneStateEstimator(config, compensate_delay=True)
    for k in range(steps):
        estimator.step(k * step_s, 0.01, speed, np.array([0.5, 0.03]))
    return estimator


def _reestimate_once(config: EstimatorConfig, step_s: float, steps: int, speed: float) -> None:
    estimator = _build_history(config, step_s, steps, speed)
    estimator.add_camera(np.array([0.1, 0.01, 0.001]), 0.0)  # the oldest step: re-run all of them


def _median_us(function, calls: int, repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            function()
        samples.append((time.perf_counter() - start) / calls * 1e6)
    return statistics.median(samples)


def bench_lines(result: EstimationBench) -> list[str]:
    rmse = result.camera_rmse
    step = result.per_step_us
    return [
        f"camera lane measurement vs truth at capture ({result.camera_frames} frames, calibration seeds): "
        f"RMSE d {rmse['d_m']:.3f} m, dpsi {rmse['dpsi_deg']:.3f} deg, kappa {rmse['kappa_1pm']:.5f} 1/m",
        f"lane measurement from the image: {result.lane_measurement_ms:.2f} ms/frame "
        f"({result.camera_rate_hz:.1f} frames/s reach the estimator)",
        f"predict {result.predict_us:.1f} us | IMU update {result.imu_update_us:.1f} us | camera update "
        f"{result.camera_update_us:.1f} us | re-estimation over {result.reestimation_steps} steps "
        f"{result.reestimation_us:.0f} us ({result.reestimation_us / (result.predict_us + result.imu_update_us):.1f}x one step)",
        "per 100 Hz step, amortised: " + " | ".join(f"{name} {value:.0f} us" for name, value in step.items())
        + f" | ratio ekf_dc / ekf {step['ekf_dc'] / step['ekf']:.2f}",
        f"(median of {result.repeats} repeats; timings are from a shared, loaded machine)",
    ]


def bench_dict(result: EstimationBench) -> dict:
    return asdict(result)
