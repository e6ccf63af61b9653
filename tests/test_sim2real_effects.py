"""The effect library's kernels: neutral parameters are the simulator, each term does what it says."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal as sps

from plm_highway.sim2real.effects import (
    _delayed,
    _lagged,
    candidate_statistics,
    profiled_sse,
    simulate_yaw_rate,
    tire_tables,
)
from plm_highway.vehicle.kinematic import HIGHWAY_ENV_VEHICLE, KinematicBicycleParams, kinematic_bicycle_rates

DT = 0.02


def _inputs(n=1500, seed=0, jitter=0.002):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    steer = (0.04 * np.sin(2 * math.pi * 0.4 * t) + 0.02 * np.sin(2 * math.pi * 1.1 * t + 1)
             + jitter * rng.standard_normal(n))
    speed = 18 + 6 * np.sin(2 * math.pi * 0.03 * t)
    return t, steer, speed


def test_neutral_parameters_are_the_simulator_exactly():
    _, steer, speed = _inputs()
    r, slip = simulate_yaw_rate(steer, speed, DT, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 2.5, 2.5, 6.25)
    r_sim, slip_sim = kinematic_bicycle_rates(steer, speed, HIGHWAY_ENV_VEHICLE)
    np.testing.assert_allclose(r, r_sim, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(slip, slip_sim, rtol=1e-13, atol=1e-15)


@settings(max_examples=30, deadline=None)
@given(samples=st.integers(0, 40))
def test_whole_sample_delay_is_a_shift_holding_the_first_command(samples):
    _, steer, _ = _inputs(300)
    out = np.empty_like(steer)
    _delayed(steer, float(samples), out)
    expected = np.concatenate([np.full(samples, steer[0]), steer[: len(steer) - samples]])
    np.testing.assert_allclose(out, expected, atol=1e-15)


def test_fractional_delay_is_continuous_in_the_delay():
    _, steer, _ = _inputs(300)
    a, b = np.empty_like(steer), np.empty_like(steer)
    _delayed(steer, 4.999999, a)
    _delayed(steer, 5.0, b)
    np.testing.assert_allclose(a, b, atol=1e-6)


@pytest.mark.parametrize("tau", [0.03, 0.15, 0.5])
def test_actuator_lag_is_the_exact_first_order_response_to_linear_interpolation(tau):
    t, steer, _ = _inputs(800)
    out = np.empty_like(steer)
    _lagged(steer, DT, tau, out)
    _, expected, _ = sps.lsim(([1.0], [tau, 1.0]), steer, t, X0=[steer[0] * tau], interp=True)
    np.testing.assert_allclose(out, expected, atol=1e-9)


def test_lag_of_zero_passes_the_command_through():
    _, steer, _ = _inputs(100)
    out = np.empty_like(steer)
    _lagged(steer, DT, 0.0, out)
    np.testing.assert_array_equal(out, steer)


@pytest.mark.parametrize("tire", [False, True])
def test_closed_form_gain_and_offset_match_a_direct_fit(tire):
    """The batch statistics give the same best gain/offset and error as simulating with them."""
    _, steer, speed = _inputs()
    a, b, k2 = 1.35, 1.45, 1.5
    cf, cr = (46.0, 50.0) if tire else (0.0, 0.0)
    truth, _ = simulate_yaw_rate(steer, speed, DT, 0.1, 0.05, 0.9, 0.004, cf, cr, a, b, k2)
    rng = np.random.default_rng(1)
    y = truth + 0.003 * rng.standard_normal(len(truth))
    weight = np.ones((1, len(y)))
    weight[0, :100] = 0.0
    if tire:
        maps, starts, units = tire_tables(speed, DT, np.array([cf]), np.array([cr]), a, b, k2, np.ones(1), 0)
        index = np.array([0], np.int64)
    else:
        maps, starts, units = np.zeros((1, 1, 8)), np.zeros((1, 2)), np.zeros((1, 1))
        index = np.array([-1], np.int64)
    stats = candidate_statistics(steer, speed, DT, np.array([0.1]), np.array([0.05]), index, maps, starts, units,
                                 a, b, np.ones(1), 0, y, weight)
    sse, gain, offset = profiled_sse(stats[:, 0, :], True, True)
    assert gain[0] == pytest.approx(0.9, abs=0.01)
    assert offset[0] == pytest.approx(0.004, abs=2e-4)
    fitted, _ = simulate_yaw_rate(steer, speed, DT, 0.1, 0.05, gain[0], offset[0], cf, cr, a, b, k2)
    direct = float(np.sum(((y - fitted) ** 2)[100:]))
    assert sse[0] == pytest.approx(direct, rel=1e-6 if tire else 2e-2)


def test_stiffer_tires_approach_the_kinematic_bicycle():
    """The tire model's lag scales like 1/stiffness: neutral-steer tires converge on the simulator."""
    _, steer, speed = _inputs(jitter=0.0)
    r_kin, _ = simulate_yaw_rate(steer, speed, DT, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.35, 1.45, 1.5)
    errors = []
    for cf in (100.0, 300.0, 900.0):
        r_tire, _ = simulate_yaw_rate(steer, speed, DT, 0.0, 0.0, 1.0, 0.0, cf, cf * 1.35 / 1.45, 1.35, 1.45, 1.5)
        errors.append(np.sqrt(np.mean((r_kin - r_tire) ** 2)) / np.sqrt(np.mean(r_kin**2)))
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.05


def test_understeer_lowers_the_yaw_gain_with_speed():
    params = KinematicBicycleParams(1.35, 1.45)
    steer = np.full(2000, 0.02)
    for speed_mps in (10.0, 30.0):
        speed = np.full(2000, speed_mps)
        r, _ = simulate_yaw_rate(steer, speed, DT, 0.0, 0.0, 1.0, 0.0, 46.5, 49.7, 1.35, 1.45, 1.51)
        r_kin, _ = kinematic_bicycle_rates(steer, speed, params)
        k = 1.45 / 46.5 / 2.8 - 1.35 / 49.7 / 2.8
        assert r[-1] / r_kin[-1] == pytest.approx(2.8 / (2.8 + k * speed_mps**2), rel=2e-3)
