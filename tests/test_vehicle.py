"""The simulator's vehicle model as pure functions: bit-for-bit highway-env, and the tire model's physics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.vehicle.kinematic import (
    HIGHWAY_ENV_VEHICLE,
    KinematicBicycleParams,
    KinematicState,
    integrate_pose_euler,
    kinematic_bicycle_rates,
    kinematic_bicycle_rollout,
    kinematic_bicycle_step,
)
from plm_highway.vehicle.single_track import (
    SEED_PAPER_VEHICLE,
    front_stiffness_for_understeer,
    params_per_kg,
    single_track_rk4_step,
    single_track_rollout,
    single_track_steady_state,
    understeer_gradient,
)


def _highway_env_trajectory(x0, y0, heading0, speed, steering, dt):
    vehicle = Vehicle(road=None, position=[x0, y0], heading=heading0, speed=speed)
    out = []
    for s in steering:
        vehicle.action = {"steering": float(s), "acceleration": 0}
        vehicle.step(dt)
        out.append((vehicle.position[0], vehicle.position[1], vehicle.heading))
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_step_and_rollout_match_highway_env_vehicle_step(seed):
    rng = np.random.default_rng(seed)
    steering = rng.uniform(-0.6, 0.6, 400)
    x0, y0, heading0 = rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-math.pi, math.pi)
    speed, dt = rng.uniform(5, 35), 1 / 20
    expected = _highway_env_trajectory(x0, y0, heading0, speed, steering, dt)

    state = KinematicState(x0, y0, heading0)
    stepped = []
    for s in steering:
        state = kinematic_bicycle_step(state, s, speed, dt, HIGHWAY_ENV_VEHICLE)
        stepped.append(state)
    np.testing.assert_allclose(np.array(stepped), expected, rtol=0, atol=1e-12)

    x, y, heading = kinematic_bicycle_rollout(KinematicState(x0, y0, heading0), steering, speed, dt,
                                              HIGHWAY_ENV_VEHICLE)
    np.testing.assert_allclose(np.column_stack([x[1:], y[1:], heading[1:]]), expected, rtol=0, atol=1e-12)


def test_rollout_batches_over_candidate_parameter_sets():
    rng = np.random.default_rng(3)
    steering = rng.uniform(-0.3, 0.3, 200)
    speed = np.linspace(10, 20, 200)
    half_lengths = np.array([1.5, 2.5, 3.5])[:, None]
    batch = KinematicBicycleParams(cg_to_front_m=half_lengths, cg_to_rear_m=half_lengths)
    x, _y, heading = kinematic_bicycle_rollout(KinematicState(0.0, 0.0, 0.0), steering, speed, 0.05, batch)
    assert x.shape == (3, 201)
    for i, h in enumerate(half_lengths.ravel()):
        xi, _yi, hi = kinematic_bicycle_rollout(KinematicState(0.0, 0.0, 0.0), steering, speed, 0.05,
                                               KinematicBicycleParams(h, h))
        np.testing.assert_allclose(x[i], xi, atol=1e-12)
        np.testing.assert_allclose(heading[i], hi, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(speed=st.floats(1.0, 40.0), steer=st.floats(-0.5, 0.5), steps=st.integers(1, 60))
def test_mirrored_steering_mirrors_the_path(speed, steer, steps):
    """Positive steer turns left (heading up); the mirror image steers right by the same amount."""
    sequence = np.full(steps, steer)
    left = kinematic_bicycle_rollout(KinematicState(0.0, 0.0, 0.0), sequence, speed, 0.05, HIGHWAY_ENV_VEHICLE)
    right = kinematic_bicycle_rollout(KinematicState(0.0, 0.0, 0.0), -sequence, speed, 0.05, HIGHWAY_ENV_VEHICLE)
    np.testing.assert_allclose(left[0], right[0], atol=1e-9)
    np.testing.assert_allclose(left[1], -right[1], atol=1e-9)
    np.testing.assert_allclose(left[2], -right[2], atol=1e-12)
    # A steer so small that the heading change underflows (e.g. 5e-324 rad) has no sign to check.
    assert np.sign(left[2][-1]) == np.sign(steer) or abs(steer) < 1e-12


@settings(max_examples=40, deadline=None)
@given(speed=st.floats(0.0, 40.0), steps=st.integers(1, 100))
def test_zero_steering_drives_straight_at_the_given_speed(speed, steps):
    x, y, heading = kinematic_bicycle_rollout(KinematicState(0.0, 0.0, 0.3), np.zeros(steps), speed, 0.05,
                                              HIGHWAY_ENV_VEHICLE)
    np.testing.assert_allclose(heading, 0.3)
    np.testing.assert_allclose(np.hypot(x[-1], y[-1]), speed * 0.05 * steps, rtol=1e-12, atol=1e-12)


def test_yaw_rate_of_the_kinematic_bicycle_is_geometry():
    r, slip = kinematic_bicycle_rates(0.1, 20.0, KinematicBicycleParams(1.2, 1.6))
    wheelbase = 2.8
    assert slip == pytest.approx(math.atan(1.6 / wheelbase * math.tan(0.1)))
    # Path curvature at the rear axle is tan(delta) / L.
    assert r == pytest.approx(20.0 * math.cos(slip) * math.tan(0.1) / wheelbase)


def test_pose_integration_is_forward_euler_with_the_old_heading():
    x, y, h = integrate_pose_euler(0.0, 0.0, 0.0, np.array([1.0, 1.0]), np.zeros(2), np.array([10.0, 10.0]), 0.1)
    np.testing.assert_allclose(h, [0.0, 0.1, 0.2])
    np.testing.assert_allclose(x, [0.0, 1.0, 1.0 + math.cos(0.1)])
    np.testing.assert_allclose(y, [0.0, 0.0, math.sin(0.1)])


# ----------------------------------------------------------------------------------------------
# Dynamic single-track model with linear tires


def test_seed_paper_car_understeers():
    k = SEED_PAPER_VEHICLE.understeer_gradient_rad_per_mps2
    assert k == pytest.approx(1850 / 2.8 * (1.45 / 86_000 - 1.35 / 92_000))
    assert 0.001 < k < 0.002


@settings(max_examples=30, deadline=None)
@given(speed=st.floats(3.0, 40.0), understeer=st.floats(-0.0002, 0.01), delta=st.floats(-0.1, 0.1))
def test_steady_state_yaw_rate_is_u_delta_over_l_plus_k_u2(speed, understeer, delta):
    a, b = SEED_PAPER_VEHICLE.cg_to_front_m, SEED_PAPER_VEHICLE.cg_to_rear_m
    cr = 50.0
    cf = front_stiffness_for_understeer(understeer, cr, a, b)
    assert understeer_gradient(cf, cr, a, b) == pytest.approx(understeer, abs=1e-12)
    if 1 + understeer * speed**2 / (a + b) <= 0.05:  # near the critical speed of an oversteering car
        return
    _, r = single_track_steady_state(speed, delta, cf, cr, a, b, 1.5)
    assert r == pytest.approx(speed * delta / (a + b + understeer * speed**2), rel=1e-9, abs=1e-12)


def test_replay_integrator_agrees_with_fine_rk4():
    """The trapezoidal replay at 50 Hz stays within 1% of RK4 at 2 kHz on a weave at varying speed."""
    cf, cr, k2 = params_per_kg(SEED_PAPER_VEHICLE)
    a, b = SEED_PAPER_VEHICLE.cg_to_front_m, SEED_PAPER_VEHICLE.cg_to_rear_m
    t_fine = np.arange(0, 20, 1 / 2000)
    steer_fine = 0.03 * np.sin(2 * math.pi * 0.7 * t_fine) + 0.01 * np.sin(2 * math.pi * 0.2 * t_fine)
    speed_fine = 15 + 5 * np.sin(2 * math.pi * 0.05 * t_fine)
    vy, r = single_track_steady_state(speed_fine[0], steer_fine[0], cf, cr, a, b, k2)
    r_fine = np.empty_like(t_fine)
    r_fine[0] = r
    for k in range(len(t_fine) - 1):
        vy, r = single_track_rk4_step(vy, r, speed_fine[k], speed_fine[k + 1], steer_fine[k], steer_fine[k + 1],
                                      1 / 2000, cf, cr, a, b, k2)
        r_fine[k + 1] = r
    _, r_replay = single_track_rollout(steer_fine[::40].copy(), speed_fine[::40].copy(), 0.02, cf, cr, a, b, k2)
    error = r_replay - r_fine[::40]
    assert np.sqrt(np.mean(error**2)) < 0.01 * np.sqrt(np.mean(r_fine**2))


def test_stiff_tires_tend_to_the_kinematic_bicycle_even_at_low_speed():
    steer = 0.05 * np.sin(np.linspace(0, 6, 500))
    speed = np.full(500, 3.0)
    _, r = single_track_rollout(steer, speed, 0.02, 5000.0, 5000.0, 1.35, 1.45, 1.5)
    r_kin, _ = kinematic_bicycle_rates(steer, speed, KinematicBicycleParams(1.35, 1.45))
    assert np.all(np.isfinite(r))
    np.testing.assert_allclose(r[50:], r_kin[50:], atol=2e-3)
