"""The vehicle-model table and the env's ego car: the dynamic model against closed forms, sensors,
speed schedules and the steering actuator (the kinematic model's results are held by the golden test)."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle
from hypothesis import given, settings
from hypothesis import strategies as st

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.envs.speed import parse_speed
from plm_highway.vehicle.models import (
    VEHICLE_MODELS,
    VehicleState,
    dynamic_steady_state,
    kinematic_car_with_friction,
    vehicle_model,
)
from plm_highway.vehicle.single_track import SEED_PAPER_VEHICLE

# The seed paper's Table 2 car, written out here (not read from the code under test).
M_KG, IZ_KGM2, A_M, B_M, CF_NPRAD, CR_NPRAD = 1850.0, 2800.0, 1.35, 1.45, 86_000.0, 92_000.0
L_M = A_M + B_M
# Understeer gradient K = m (b Cr - a Cf) / (L Cf Cr)  [rad / (m/s^2)]
K_US = M_KG * (B_M * CR_NPRAD - A_M * CF_NPRAD) / (L_M * CF_NPRAD * CR_NPRAD)
STRAIGHT = {"name": "long", "lanes": 3, "lane_width_m": 4.0, "segments": [{"type": "straight", "length_m": 3000}]}


def settle(model_name: str, steer_rad: float, speed_mps: float, seconds: float = 8.0, dt_s: float = 0.01):
    model = vehicle_model(model_name)
    state = model.initial_state(0.0, 0.0, 0.0, 0.0, speed_mps)
    for _ in range(int(seconds / dt_s)):
        state = model.step(state, steer_rad, steer_rad, speed_mps, speed_mps, dt_s, model.default_params)
    return model, state


def test_default_dynamic_car_is_the_papers_table_2_car():
    assert vehicle_model("dynamic").default_params == SEED_PAPER_VEHICLE
    p = SEED_PAPER_VEHICLE
    assert (p.mass_kg, p.yaw_inertia_kgm2, p.cg_to_front_m, p.cg_to_rear_m) == (M_KG, IZ_KGM2, A_M, B_M)
    assert (p.cornering_stiffness_front, p.cornering_stiffness_rear) == (CF_NPRAD, CR_NPRAD)


@pytest.mark.parametrize("speed_mps", [8.0, 16.7, 30.0])
@pytest.mark.parametrize("steer_rad", [0.01, -0.03])
def test_dynamic_steady_state_yaw_gain_is_u_over_l_plus_k_u2(speed_mps, steer_rad):
    """Steady cornering of a linear single-track car: r / delta = u / (L + K u^2) (understeer)."""
    model, state = settle("dynamic", steer_rad, speed_mps)
    expected_r = speed_mps * steer_rad / (L_M + K_US * speed_mps ** 2)
    assert state.yaw_rate_radps == pytest.approx(expected_r, rel=1e-6)
    assert K_US > 0  # the paper's car understeers: it turns less than the kinematic u delta / L
    assert abs(state.yaw_rate_radps) < abs(speed_mps * steer_rad / L_M)
    sensors = model.sensors(state, steer_rad, speed_mps, model.default_params)
    # In a steady turn the body lateral acceleration is u r (vy' = 0).
    assert sensors.lateral_acceleration_mps2 == pytest.approx(speed_mps * expected_r, rel=1e-6)
    # Steady sideslip of the linear model: vy / r = b - m a u^2 / (L Cr).
    assert state.lateral_velocity_mps / state.yaw_rate_radps == pytest.approx(
        B_M - M_KG * A_M * speed_mps ** 2 / (L_M * CR_NPRAD), rel=1e-6)
    assert dynamic_steady_state(steer_rad, speed_mps, model.default_params) == pytest.approx(
        (state.lateral_velocity_mps, state.yaw_rate_radps), rel=1e-6)


def test_dynamic_derivatives_are_the_papers_equation_1():
    """vy' and r' written from Equation (1)'s matrix entries by hand."""
    u, vy, r, delta = 20.0, 0.3, 0.05, 0.02
    vy_dot = (-(CF_NPRAD + CR_NPRAD) / (M_KG * u) * vy + ((B_M * CR_NPRAD - A_M * CF_NPRAD) / (M_KG * u) - u) * r
              + CF_NPRAD / M_KG * delta)
    r_dot = ((B_M * CR_NPRAD - A_M * CF_NPRAD) / (IZ_KGM2 * u) * vy
             - (A_M ** 2 * CF_NPRAD + B_M ** 2 * CR_NPRAD) / (IZ_KGM2 * u) * r + A_M * CF_NPRAD / IZ_KGM2 * delta)
    model = vehicle_model("dynamic")
    heading = 0.4
    d = model.derivatives(VehicleState(1.0, 2.0, heading, vy, r), delta, u, model.default_params)
    assert (d.lateral_velocity_mps, d.yaw_rate_radps) == pytest.approx((vy_dot, r_dot), rel=1e-12)
    assert (d.x_m, d.y_m, d.heading_rad) == pytest.approx(
        (u * math.cos(heading) - vy * math.sin(heading), u * math.sin(heading) + vy * math.cos(heading), r))


def test_dynamic_step_converges_to_the_exact_solution_at_second_order():
    """Halving the step quarters the error of the pose after a steering step (trapezoid + midpoint)."""
    def pose_after(dt_s):
        model = vehicle_model("dynamic")
        state = model.initial_state(0.0, 0.0, 0.0, 0.0, 15.0)
        for _ in range(int(round(2.0 / dt_s))):
            state = model.step(state, 0.03, 0.03, 15.0, 15.0, dt_s, model.default_params)
        return np.array(state[:3])

    reference = pose_after(0.0005)
    coarse, fine = np.linalg.norm(pose_after(0.02) - reference), np.linalg.norm(pose_after(0.01) - reference)
    assert 3.0 < coarse / fine < 5.0


def test_kinematic_table_entry_is_highway_env_vehicle_step():
    model = vehicle_model("kinematic")
    rng = np.random.default_rng(4)
    vehicle = Vehicle(road=None, position=[3.0, -2.0], heading=0.3, speed=17.0)
    state = model.initial_state(3.0, -2.0, 0.3, 0.0, 17.0)
    for steer in rng.uniform(-0.4, 0.4, 200):
        vehicle.action = {"steering": float(steer), "acceleration": 0}
        vehicle.step(0.05)
        state = model.step(state, float(steer), float(steer), 17.0, 17.0, 0.05, model.default_params)
        assert (state.x_m, state.y_m, state.heading_rad) == (vehicle.position[0], vehicle.position[1], vehicle.heading)
        # The yaw rate the state carries is the heading rate the step applied.
        assert state.yaw_rate_radps == pytest.approx(17.0 * math.sin(math.atan(0.5 * math.tan(steer))) / 2.5)


def test_unknown_model_and_parameters_are_refused():
    with pytest.raises(ValueError, match=r"'bicycle'.*\['dynamic', 'kinematic', 'saturating'\]"):
        vehicle_model("bicycle")
    with pytest.raises(ValueError, match="vehicle_model"):
        gymnasium.make(ENV_ID, config={"track": STRAIGHT, "vehicle_model": "tank"})
    with pytest.raises(ValueError, match="mass_kilograms.*allowed"):
        gymnasium.make(ENV_ID, config={"track": STRAIGHT, "vehicle_model": "dynamic",
                                       "vehicle_params": {"mass_kilograms": 1500}})
    with pytest.raises(ValueError, match=r"\['mass_kg'\] = -1: must be a number in \[50, 60000\]"):
        gymnasium.make(ENV_ID, config={"track": STRAIGHT, "vehicle_model": "dynamic",
                                       "vehicle_params": {"mass_kg": -1}})


# -- the env with each model -----------------------------------------------------------------------


def run_constant_steering(config: dict, action: float, steps: int):
    env = gymnasium.make(ENV_ID, config={"track": STRAIGHT, **config})
    _, info = env.reset(seed=0)
    infos = [info]
    for _ in range(steps):
        _, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        infos.append(info)
        if terminated or truncated:
            break
    return infos


def test_env_dynamic_car_reaches_the_closed_form_yaw_rate_and_reports_its_sensors():
    speed_mps, action = 16.7, 0.05  # 0.01 rad at the wheels: a ~600 m radius turn, stays on the road for 3 s
    infos = run_constant_steering({"vehicle_model": "dynamic", "speed_mps": speed_mps}, action, 60)
    last = infos[-1]
    delta = float(np.float32(action)) * 0.2
    expected_r = speed_mps * delta / (L_M + K_US * speed_mps ** 2)
    assert last["steering_angle_rad"] == pytest.approx(delta, rel=1e-6)
    assert last["yaw_rate_radps"] == pytest.approx(expected_r, rel=1e-4)
    assert last["lateral_acceleration_mps2"] == pytest.approx(speed_mps * expected_r, rel=1e-3)
    # The heading integrates the yaw rate the car reports.
    headings = np.array([i["heading_rad"] for i in infos])
    rates = np.array([i["yaw_rate_radps"] for i in infos])
    np.testing.assert_allclose(np.diff(headings), 0.05 * 0.5 * (rates[1:] + rates[:-1]), rtol=1e-9, atol=1e-12)
    # It turns less than a kinematic bicycle of its own wheelbase would (understeer): u delta / L for 3 s.
    assert 0 < last["heading_rad"] < speed_mps * delta / L_M * last["time_s"]


def test_env_kinematic_sensors_match_its_motion():
    infos = run_constant_steering({}, 0.3, 30)
    headings = np.array([i["heading_rad"] for i in infos])
    rates = np.array([i["yaw_rate_radps"] for i in infos[1:]])
    np.testing.assert_allclose(np.diff(headings) / 0.05, rates, rtol=1e-9)
    last = infos[-1]
    assert last["lateral_acceleration_mps2"] == pytest.approx(last["speed_mps"] * last["yaw_rate_radps"])
    assert last["steering_angle_rad"] == pytest.approx(0.3 * 0.2, rel=1e-6)
    assert last["steering_command"] == pytest.approx(0.3, rel=1e-6)


def test_speed_schedule_is_followed():
    schedule = [[0.0, 10.0], [2.0, 20.0]]
    infos = run_constant_steering({"speed_mps": schedule}, 0.0, 60)
    times = np.array([i["time_s"] for i in infos])
    speeds = np.array([i["speed_mps"] for i in infos])
    np.testing.assert_allclose(speeds, np.interp(times, [0.0, 2.0], [10.0, 20.0]), rtol=1e-12)
    # Distance: 2 s of ramp (average 15 m/s) then 1 s at 20 m/s; forward Euler (speed at the start of each
    # step) falls short by half a step of the ramp, 0.25 m.
    distance_m = infos[-1]["arc_length_m"]
    exact_m = 30.0 + 20.0
    assert abs(distance_m - exact_m) < 0.3


@settings(max_examples=50, deadline=None)
@given(points=st.lists(st.tuples(st.floats(0, 100), st.floats(0.5, 60)), min_size=1, max_size=6, unique_by=lambda p: p[0]),
       t_s=st.floats(-5, 200))
def test_speed_schedule_interpolates_linearly_and_holds_at_the_ends(points, t_s):
    points = sorted(points)
    schedule = parse_speed([list(p) for p in points])
    times, speeds = zip(*points)
    assert schedule.speed_at(t_s) == pytest.approx(float(np.interp(t_s, times, speeds)), rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("model_name", sorted(VEHICLE_MODELS))
def test_first_order_steering_actuator(model_name):
    """A step command reaches the wheels as 1 - exp(-t / tau)."""
    tau_s = 0.2
    infos = run_constant_steering({"vehicle_model": model_name, "steering_time_constant_s": tau_s}, 0.5, 20)
    command_rad = infos[-1]["steering_command"] * 0.2  # 0.1 rad, as the float32 action maps it
    assert command_rad == pytest.approx(0.1, rel=1e-6)
    for info in infos:
        expected = command_rad * (1.0 - math.exp(-info["time_s"] / tau_s))
        assert info["steering_angle_rad"] == pytest.approx(expected, rel=1e-9, abs=1e-15)
        assert info["steering"] == pytest.approx(expected / 0.2, rel=1e-9, abs=1e-15)
    # Instantaneous (the default): the wheels have the command after the first step.
    assert run_constant_steering({"vehicle_model": model_name}, 0.5, 1)[-1]["steering_angle_rad"] == command_rad


# -- tires that saturate ---------------------------------------------------------------------------------

G_MPS2 = 9.81


def test_saturating_car_far_below_its_limit_has_the_linear_cars_closed_form_yaw_rate():
    # The default is the Table 2 car on a dry road (mu 1.0); at 0.01 rad and 16.7 m/s it corners at ~1 m/s^2,
    # where the magic formula is linear to about 0.4%.
    speed_mps, steer_rad = 16.7, 0.01
    _, state = settle("saturating", steer_rad, speed_mps)
    expected_r = speed_mps * steer_rad / (L_M + K_US * speed_mps ** 2)
    assert state.yaw_rate_radps == pytest.approx(expected_r, rel=1e-2)


def test_kinematic_car_with_friction_turns_like_the_kinematic_bicycle_below_the_limit():
    # highway-env's car: 5 m between the axles, reference point in the middle; kinematic yaw rate
    # v sin(beta) / 2.5 with tan(beta) = tan(delta) / 2. At 0.02 rad and 16.7 m/s it corners at ~1.1 m/s^2.
    speed_mps, steer_rad = 16.7, 0.02
    model = vehicle_model("saturating")
    params = kinematic_car_with_friction(1.0)
    assert (params.cg_to_front_m, params.cg_to_rear_m, params.friction_coefficient) == (2.5, 2.5, 1.0)
    state = model.initial_state(0.0, 0.0, 0.0, 0.0, speed_mps, params)
    for _ in range(300):
        state = model.step(state, steer_rad, steer_rad, speed_mps, speed_mps, 1 / 30, params)
    kinematic_r = speed_mps * math.sin(math.atan(0.5 * math.tan(steer_rad))) / 2.5
    assert state.yaw_rate_radps == pytest.approx(kinematic_r, rel=2e-2)


@settings(max_examples=40, deadline=None)
@given(mu=st.floats(0.3, 1.2), speed_mps=st.floats(5.0, 30.0),
       steering=st.lists(st.floats(-0.6, 0.6), min_size=5, max_size=40))
def test_a_saturating_car_never_corners_harder_than_mu_g(mu, speed_mps, steering):
    """The axle forces peak at mu times the axle loads, which add up to the car's weight: whatever the steering
    asks, the lateral acceleration stays within mu g."""
    model = vehicle_model("saturating")
    params = kinematic_car_with_friction(mu)
    state = model.initial_state(0.0, 0.0, 0.0, steering[0], speed_mps, params)
    for start_rad, end_rad in zip(steering, steering[1:]):
        for _ in range(3):  # a tenth of a second per command
            state = model.step(state, start_rad, end_rad, speed_mps, speed_mps, 1 / 30, params)
            start_rad = end_rad
            sensed = model.sensors(state, end_rad, speed_mps, params)
            assert abs(sensed.lateral_acceleration_mps2) <= mu * G_MPS2 * (1 + 1e-9)
            assert all(math.isfinite(v) for v in state)


def test_a_friction_limit_caps_a_hard_turn_that_the_kinematic_car_takes():
    # 0.3 rad at 16.7 m/s asks a kinematic car of 5 m for v^2 sin(beta) / 2.5 = 16.5 m/s^2.
    speed_mps, steer_rad = 16.7, 0.3
    kinematic_accel = speed_mps ** 2 * math.sin(math.atan(0.5 * math.tan(steer_rad))) / 2.5
    assert kinematic_accel > 16.0
    model = vehicle_model("saturating")
    for mu, expected_ratio in ((0.9, None), (3.0, 1.0)):
        params = kinematic_car_with_friction(mu)
        state = model.initial_state(0.0, 0.0, 0.0, 0.0, speed_mps, params)
        for _ in range(90):
            state = model.step(state, steer_rad, steer_rad, speed_mps, speed_mps, 1 / 30, params)
        accel = model.sensors(state, steer_rad, speed_mps, params).lateral_acceleration_mps2
        if expected_ratio is None:  # at 0.9 g the tires hold less than half of what the turn asks
            assert 0.5 * 0.9 * G_MPS2 < accel <= 0.9 * G_MPS2 * (1 + 1e-9)
        else:  # at 3 g the limit does not bind: the kinematic car's lateral acceleration, within 3%
            assert accel == pytest.approx(kinematic_accel, rel=3e-2)


def test_env_drives_the_saturating_car_and_checks_its_friction_coefficient():
    infos = run_constant_steering({"vehicle_model": "saturating", "vehicle_params": {"friction_coefficient": 0.5},
                                   "max_steering_rad": 0.4}, 1.0, 20)
    assert max(abs(i["lateral_acceleration_mps2"]) for i in infos) <= 0.5 * G_MPS2 * (1 + 1e-9)
    with pytest.raises(ValueError, match=r"\['friction_coefficient'\] = 0: must be a number in \[0.05, 3\]"):
        gymnasium.make(ENV_ID, config={"track": STRAIGHT, "vehicle_model": "saturating",
                                       "vehicle_params": {"friction_coefficient": 0}})
