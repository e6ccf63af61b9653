"""The LQR lane keeper: the Riccati solution against hand-derived cases, the plant it is designed on, and the
EKF lane keeper driving a stretch of the train track."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.lane_ekf.lane_model import lane_dynamics, single_track_rows
from plm_highway.lane_ekf.lateral_control import (
    BrysonTolerances,
    LoopTiming,
    LqrLaneController,
    continuous_error_model,
    dlqr,
    lane_plant,
    lqr_gains,
    single_track_equivalent,
)
from plm_highway.vehicle.kinematic import HIGHWAY_ENV_VEHICLE
from plm_highway.vehicle.single_track import SEED_PAPER_VEHICLE

KINEMATIC_CAR = single_track_equivalent(HIGHWAY_ENV_VEHICLE)


def test_dlqr_of_the_scalar_integrator_is_the_golden_ratio():
    # x+ = x + u, cost sum x^2 + u^2: the Riccati equation P = P - P^2 / (1 + P) + 1 gives P^2 - P - 1 = 0.
    golden = (1 + math.sqrt(5)) / 2
    k, p = dlqr(np.array([[1.0]]), np.array([1.0]), np.array([[1.0]]), np.array([[1.0]]))
    assert p[0, 0] == pytest.approx(golden, rel=1e-12)
    assert k[0, 0] == pytest.approx(golden / (1 + golden), rel=1e-12)  # K = b P a / (r + b^2 P)


@given(a=st.floats(-2.0, 2.0), b=st.floats(0.1, 3.0), q=st.floats(0.01, 100.0), r=st.floats(0.01, 100.0))
@settings(max_examples=60, deadline=None)
def test_dlqr_solves_the_scalar_riccati_equation_in_closed_form(a, b, q, r):
    # Scalar DARE: b^2 P^2 + (r (1 - a^2) - q b^2) P - q r = 0, the positive root.
    linear = r * (1 - a * a) - q * b * b
    p_expected = (-linear + math.sqrt(linear * linear + 4 * b * b * q * r)) / (2 * b * b)
    k, p = dlqr(np.array([[a]]), np.array([b]), np.array([[q]]), np.array([[r]]))
    assert p[0, 0] == pytest.approx(p_expected, rel=1e-7)
    assert k[0, 0] == pytest.approx(a * b * p_expected / (r + b * b * p_expected), rel=1e-7)
    assert abs(a - b * k[0, 0]) < 1.0  # the closed loop is stable


def test_error_model_is_the_estimators_lane_model_linearised():
    # For a state whose v_n is u dpsi + v, the estimator's (nonlinear) model and the controller's linear one
    # give the same d', dpsi', v', r' to first order.
    speed = 16.7
    a, b, e = continuous_error_model(SEED_PAPER_VEHICLE, speed)
    d, dpsi, v, r, kappa, steer = 0.01, 2e-4, 1e-3, 2e-4, 1e-5, 1e-4
    full = lane_dynamics(np.array([d, dpsi, speed * dpsi + v, v, r, kappa]), steer, speed,
                         single_track_rows(speed, SEED_PAPER_VEHICLE))
    linear = a @ np.array([d, dpsi, v, r]) + b * steer + e * kappa
    np.testing.assert_allclose(linear, full[[0, 1, 3, 4]], rtol=1e-3, atol=1e-9)


def test_the_kinematic_car_as_a_single_track_car_turns_like_the_kinematic_bicycle():
    speed, steer = 16.7, 0.02
    a, b, _ = continuous_error_model(KINEMATIC_CAR, speed)
    v, r = np.linalg.solve(a[2:, 2:], -b[2:] * steer)  # the tyres' steady state
    assert r == pytest.approx(speed * steer / HIGHWAY_ENV_VEHICLE.wheelbase_m, rel=1e-3)
    # The slip angle: v = lr r for wheels that cannot slip; these tyres still need a rear slip angle of
    # (m u r / 2) / C_r ~ 6e-4 rad to carry half the lateral force, which takes u * 6e-4 ~ 0.01 m/s off v.
    assert v == pytest.approx(HIGHWAY_ENV_VEHICLE.cg_to_rear_m * r, rel=0.07)


def test_processing_delay_holds_a_command_back_that_many_steps_and_the_actuator_lags():
    timing = LoopTiming(loop_period_s=1 / 30, actuator_time_constant_s=0.1, processing_delay_steps=2)
    plant = lane_plant(KINEMATIC_CAR, 16.7, timing)
    assert plant.n_states == 4 + 1 + 2
    x = np.zeros(plant.n_states)
    wheel = []
    for step in range(6):
        x = plant.a @ x + plant.b * (1.0 if step == 0 else 0.0)
        wheel.append(x[4])
    assert wheel[0] == wheel[1] == 0.0  # the command is still in flight for two steps
    assert wheel[2] == pytest.approx(1 - math.exp(-(1 / 30) / 0.1))  # then the actuator's first-order response


@pytest.mark.parametrize("timing", [LoopTiming(), LoopTiming(1 / 30, 0.1, 2)])
@pytest.mark.parametrize("vehicle", [KINEMATIC_CAR, SEED_PAPER_VEHICLE])
def test_feedforward_leaves_no_steady_offset_on_a_curve(timing, vehicle):
    gains = lqr_gains(vehicle, 16.7, timing, max_steering_rad=0.4)
    plant = gains.plant
    assert np.all(np.abs(gains.closed_loop_poles) < 1.0)
    kappa = 0.01
    settled = {}
    for with_feedforward in (True, False):
        x = np.zeros(plant.n_states)
        for _ in range(2000):
            u = -gains.feedback @ x + (gains.feedforward_rad_per_1pm * kappa if with_feedforward else 0.0)
            x = plant.a @ x + plant.b * u + plant.e * kappa
        settled[with_feedforward] = x[0]
    assert abs(settled[True]) < 1e-9
    assert abs(settled[False]) > 0.05  # the feedback alone leaves the car this far out in the curve


def test_bryson_weights_trade_offset_against_steering():
    loose = lqr_gains(KINEMATIC_CAR, 16.7, tolerances=BrysonTolerances(offset_m=1.0))
    tight = lqr_gains(KINEMATIC_CAR, 16.7, tolerances=BrysonTolerances(offset_m=0.1))
    assert tight.feedback[0] > 3 * loose.feedback[0]
    with pytest.raises(ValueError, match="offset_m"):
        BrysonTolerances(offset_m=0.0)
    with pytest.raises(ValueError, match="processing_delay_steps"):
        LoopTiming(processing_delay_steps=1.5)


def test_controller_remembers_its_commands_in_flight_and_clips():
    controller = LqrLaneController(KINEMATIC_CAR, LoopTiming(1 / 30, 0.0, 2), max_steering_rad=0.2)
    first = controller.command(np.array([0.5, 0.0, 0.0, 0.0]), 16.7, 0.0)
    second = controller.command(np.array([0.5, 0.0, 0.0, 0.0]), 16.7, 0.0)
    assert controller.in_flight_rad == [first, second]
    assert controller.command(np.array([50.0, 0.0, 0.0, 0.0]), 16.7, 0.0) == -0.2
    controller.reset()
    assert controller.in_flight_rad == [0.0, 0.0]


@pytest.mark.slow
def test_ekf_lane_keeper_holds_the_lane_centre_on_a_stretch_of_the_train_track():
    # 400 steps (20 s): the opening straight, a 120 m radius right curve entered and left, and the next entry.
    # The bound is the lane-keeping target on the test track (1.5x the reference Base Model's 0.067 m).
    from plm_highway.lane_ekf.policy import ekf_policy
    from plm_highway.rollout.closed_loop import drive

    log = drive("ekf", ekf_policy(seed=0), "train", "const:0", 0, max_steps=400)
    summary = log.summary()
    assert not summary["left_road"] and summary["steps"] == 400
    assert summary["lateral_offset_rms_m"] < 0.10
    assert summary["lateral_offset_max_m"] < 0.5
