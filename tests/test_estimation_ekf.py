"""The lane-coordinate EKF: against filterpy's linear Kalman filter, delay compensation, bad input, observability."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.lane_ekf.ekf import EstimatorConfig, LaneStateEstimator
from plm_highway.lane_ekf.lane_model import (
    H_CAMERA,
    N_STATES,
    imu_model,
    lane_dynamics,
    lane_dynamics_jacobian,
    observability_rank,
    single_track_rows,
)
from plm_highway.lane_ekf.scenarios import SCENARIOS, simulate_truth
from plm_highway.vehicle.single_track import SEED_PAPER_VEHICLE

STEP_S = 0.01
SPEED = 16.7


def test_the_jacobian_is_the_derivative_of_the_dynamics():
    rows = single_track_rows(SPEED, SEED_PAPER_VEHICLE)
    x = np.array([0.4, 0.05, 0.6, 0.3, 0.1, 0.008])
    numeric = np.empty((N_STATES, N_STATES))
    for j in range(N_STATES):
        step = np.zeros(N_STATES)
        step[j] = 1e-6
        numeric[:, j] = (lane_dynamics(x + step, 0.02, SPEED, rows) - lane_dynamics(x - step, 0.02, SPEED, rows)) / 2e-6
    np.testing.assert_allclose(lane_dynamics_jacobian(x, SPEED, rows), numeric, atol=1e-6)


def test_the_lateral_acceleration_row_is_v_dot_plus_u_r():
    # Eq. (24): a_y = v' + u r; v' is the single-track row of Eq. (23).
    rows = single_track_rows(SPEED, SEED_PAPER_VEHICLE)
    x = np.array([0.0, 0.0, 0.0, 0.3, 0.1, 0.0])
    h_imu, steer_gain = imu_model(SPEED, rows)
    v_dot = lane_dynamics(x, 0.02, SPEED, rows)[3]
    assert h_imu[0] @ x + steer_gain[0] * 0.02 == pytest.approx(v_dot + SPEED * x[4])


def test_in_the_linear_regime_the_ekf_is_filterpys_kalman_filter():
    """With tiny signals the model's products of states vanish: the EKF must equal the linear KF."""
    config = EstimatorConfig()
    rows = single_track_rows(SPEED, config.vehicle)
    jacobian = lane_dynamics_jacobian(np.zeros(N_STATES), SPEED, rows)
    steer_column = (lane_dynamics(np.zeros(N_STATES), 1.0, SPEED, rows) - lane_dynamics(np.zeros(N_STATES), 0.0, SPEED, rows))
    h_imu, steer_gain = imu_model(SPEED, rows)

    reference = KalmanFilter(dim_x=N_STATES, dim_z=2, dim_u=1)
    reference.x = np.zeros((N_STATES, 1))
    reference.P = np.diag(np.square(config.initial_std))
    reference.F = np.eye(N_STATES) + STEP_S * jacobian
    reference.B = STEP_S * steer_column.reshape(-1, 1)
    reference.Q = np.diag(np.square(config.process_std)) * STEP_S
    estimator = LaneStateEstimator(config, compensate_delay=True)

    rng = np.random.default_rng(7)
    scale = 1e-5
    for k in range(300):
        steer = scale * math.sin(0.05 * k)
        z_imu = scale * rng.standard_normal(2)
        estimator.step(k * STEP_S, steer, SPEED, z_imu)
        if k > 0:
            reference.predict(u=np.array([[steer]]))
        reference.update((z_imu - steer_gain * steer).reshape(-1, 1), R=config.imu_covariance, H=h_imu)
        if k % 10 == 5:
            z_camera = scale * rng.standard_normal(3)
            estimator.add_camera(z_camera, k * STEP_S)
            reference.update(z_camera.reshape(-1, 1), R=config.camera_covariance, H=H_CAMERA)
    np.testing.assert_allclose(estimator.state, reference.x.ravel(), rtol=2e-3, atol=1e-3 * scale)
    np.testing.assert_allclose(estimator.covariance, reference.P, rtol=2e-3, atol=1e-12)


def _truth_run():
    truth = simulate_truth(SCENARIOS[2], np.random.default_rng(3), 0.0, STEP_S)
    imu = np.column_stack([truth.ay_mps2, truth.r_radps])
    camera = np.column_stack([truth.d_m, truth.dpsi_rad, truth.kappa_1pm])  # exact measurements
    return truth, imu, camera


def _run(truth, imu, camera, delay_steps: int, every: int, compensate: bool, latest: int | None = None,
         last_capture: float = math.inf):
    """States at every step; camera frames every ``every`` steps arrive ``delay_steps`` later."""
    estimator = LaneStateEstimator(EstimatorConfig(), compensate_delay=compensate)
    n = len(truth.time_s) if latest is None else latest
    states = np.empty((n, N_STATES))
    for k in range(n):
        estimator.step(truth.time_s[k], truth.steer_rad[k], truth.speed_mps, imu[k])
        capture = k - delay_steps
        if 0 <= capture <= last_capture and capture % every == 0:
            estimator.add_camera(camera[capture], truth.time_s[capture])
        states[k] = estimator.state
    return states


def test_delay_compensation_recovers_the_undelayed_filter_with_exact_measurements():
    truth, imu, camera = _truth_run()
    every, delay = 40, 30
    undelayed = _run(truth, imu, camera, 0, every, compensate=True)
    compensated = _run(truth, imu, camera, delay, every, compensate=True)
    uncompensated = _run(truth, imu, camera, delay, every, compensate=False)
    # From an arrival until the next capture both filters hold the same measurements: the compensated
    # one must then be exactly where the undelayed one is.
    steps = np.arange(len(truth.time_s))
    same_information = (steps % every >= delay) & (steps >= every)
    np.testing.assert_allclose(compensated[same_information], undelayed[same_information], rtol=1e-9, atol=1e-12)
    # ...and it tracks the truth, while applying late measurements as current lags behind it.
    d_error = lambda states: np.sqrt(np.mean((states[300:, 0] - truth.d_m[300:]) ** 2))  # noqa: E731
    assert d_error(compensated) < 0.05
    assert d_error(uncompensated) > 4 * d_error(compensated)


@settings(max_examples=12, deadline=None)
@given(delay_steps=st.integers(0, 30), every=st.integers(1, 40), latest=st.integers(60, 150))
def test_re_estimation_equals_the_undelayed_filter_for_any_delay(delay_steps, every, latest):
    truth, imu, camera = _TRUTH
    k = latest - 1
    # Captures that have not arrived by step k are left out of the undelayed run too.
    last_capture = ((k - delay_steps) // every) * every
    undelayed = _run(truth, imu, camera, 0, every, compensate=True, latest=latest, last_capture=last_capture)
    delayed = _run(truth, imu, camera, delay_steps, every, compensate=True, latest=latest)
    np.testing.assert_allclose(delayed[k], undelayed[k], rtol=1e-9, atol=1e-12)


_TRUTH = _truth_run()


def test_history_is_bounded_by_history_s():
    estimator = LaneStateEstimator(EstimatorConfig(history_s=0.3))
    for k in range(500):
        estimator.step(k * STEP_S, 0.0, SPEED, np.zeros(2))
    span_s = estimator.history[-1].time_s - estimator.history[0].time_s
    assert 0.3 - 1e-9 <= span_s <= 0.3 + STEP_S + 1e-9
    with pytest.raises(ValueError, match="history"):
        estimator.add_camera(np.zeros(3), estimator.now_s - 0.35)
    estimator.add_camera(np.zeros(3), estimator.now_s - 0.3)  # exactly the longest delay: served
    assert estimator.history[0].cameras  # filed under the oldest step kept


@pytest.mark.parametrize("call, match", [
    (lambda e: e.step(1.0, math.nan, SPEED, np.zeros(2)), "steer_rad"),
    (lambda e: e.step(1.0, 0.0, SPEED, np.array([0.0, math.nan])), "NaN"),
    (lambda e: e.step(0.5, 0.0, SPEED, np.zeros(2)), "not after"),
    (lambda e: e.step(0.9, 0.0, SPEED, np.zeros(2)), "not after"),
    (lambda e: e.step(1.0, 0.0, 0.0, np.zeros(2)), "speed"),
    (lambda e: e.step(1.0, 0.0, SPEED, np.zeros(3)), "imu"),
    (lambda e: e.add_camera(np.array([0.0, math.inf, 0.0]), 0.8), "NaN or infinity"),
    (lambda e: e.add_camera(np.zeros(3), 0.95), "negative delay"),
    (lambda e: e.add_camera(np.zeros(2), 0.8), "shape"),
    (lambda e: e.add_camera(np.zeros(3), -5.0), "history"),
])
def test_bad_input_is_refused(call, match):
    estimator = LaneStateEstimator(EstimatorConfig())
    for k in range(91):
        estimator.step(k * STEP_S, 0.0, SPEED, np.zeros(2))
    with pytest.raises(ValueError, match=match):
        call(estimator)


def test_out_of_order_camera_measurements_are_refused():
    estimator = LaneStateEstimator(EstimatorConfig())
    for k in range(50):
        estimator.step(k * STEP_S, 0.0, SPEED, np.zeros(2))
    estimator.add_camera(np.zeros(3), 0.3)
    with pytest.raises(ValueError, match="capture order"):
        estimator.add_camera(np.zeros(3), 0.2)


@pytest.mark.parametrize("kwargs", [{"process_std": (0.1,) * 5}, {"camera_std": (0.0, 0.1, 0.1)},
                                    {"history_s": -1.0}, {"yaw_rate_std_radps": math.nan},
                                    {"initial_std": (-1.0,) * 6}, {"max_euler_step_s": 0.0}])
def test_bad_configuration_is_refused(kwargs):
    with pytest.raises(ValueError, match="EstimatorConfig"):
        EstimatorConfig(**kwargs)


def test_observability_rank_eq_27():
    x = np.array([0.3, 0.02, 0.4, 0.2, 0.05, 0.005])
    assert observability_rank(x, SPEED, SEED_PAPER_VEHICLE, STEP_S) == N_STATES
    # Without the camera nothing ties the state to the lane: d (at least) is unobservable.
    assert observability_rank(x, SPEED, SEED_PAPER_VEHICLE, STEP_S, with_camera=False) < N_STATES
    assert observability_rank(x, 8.3, SEED_PAPER_VEHICLE, STEP_S, with_imu=False) == N_STATES
