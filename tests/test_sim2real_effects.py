"""The effect library's kernels: neutral parameters are the simulator, each term does what it says."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal as sps

from plm_highway.sim2real.fit.grid import GridChannel, LinearDirection, grid_statistics, profile_linear
from plm_highway.sim2real.physics.chain import (
    CarParams,
    Drive,
    _delayed,
    _jittered,
    _lagged,
    _servo,
    simulate,
)
from plm_highway.sim2real.physics.effects import (
    EFFECTS,
    EffectParams,
    FitContext,
    chain_grid,
    coordinates_of,
    params_from,
    simulate_yaw_rate,
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
    """The grid statistics give the same best gain/offset and error as simulating with them."""
    _, steer, speed = _inputs()
    a, b, k2 = 1.35, 1.45, 1.5
    cf, cr = (46.0, 50.0) if tire else (0.0, 0.0)
    truth, _ = simulate_yaw_rate(steer, speed, DT, 0.1, 0.05, 0.9, 0.004, cf, cr, a, b, k2)
    rng = np.random.default_rng(1)
    y = truth + 0.003 * rng.standard_normal(len(truth))
    weight = np.ones((1, len(y)))
    weight[0, :100] = 0.0
    point = chain_grid([EffectParams(delay_s=0.1, time_constant_s=0.05, cf_per_kg=cf if tire else None,
                                     cr_per_kg=cr if tire else None).chain()])
    gram = grid_statistics(Drive(steer, speed, DT), CarParams(a, b, k2, 0.5), point, GridChannel(y, np.ones(1), 0),
                           weight, [LinearDirection("gain", 1e-3), LinearDirection("offset_rad", 1e-4)])
    sse, solved = profile_linear(gram[:, 0], np.array([0.2, -0.2]), np.array([5.0, 0.2]),
                                 np.column_stack([point["gain"], point["offset_rad"]]))
    gain, offset = solved[0]
    assert gain == pytest.approx(0.9, abs=0.01)
    assert offset == pytest.approx(0.004, abs=2e-4)
    fitted, _ = simulate_yaw_rate(steer, speed, DT, 0.1, 0.05, gain, offset, cf, cr, a, b, k2)
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


# ----------------------------------------------------------------------------------------------
# The servo (lag + rate limit) and the jittering delay


@settings(max_examples=25, deadline=None)
@given(rate=st.floats(0.01, 2.0), tau=st.sampled_from([0.0, 0.05, 0.2]))
def test_the_servo_never_turns_faster_than_its_rate_limit(rate, tau):
    _, steer, _ = _inputs(600, jitter=0.01)
    out = np.empty_like(steer)
    _servo(steer * 5, DT, tau, rate, out)
    assert np.max(np.abs(np.diff(out))) <= rate * DT * (1 + 1e-12)


def test_an_infinite_rate_limit_is_the_plain_lag_and_a_slow_command_passes_unlimited():
    t, steer, _ = _inputs(600)
    lagged, servo = np.empty_like(steer), np.empty_like(steer)
    _lagged(steer, DT, 0.1, lagged)
    _servo(steer, DT, 0.1, math.inf, servo)
    np.testing.assert_array_equal(servo, lagged)
    slow = 0.01 * np.sin(2 * math.pi * 0.1 * t)  # at most 0.0063 rad/s
    _servo(slow, DT, 0.0, 0.05, servo)
    np.testing.assert_allclose(servo, slow, atol=1e-15)


def test_a_jittering_delay_keeps_ramps_and_constants_and_without_jitter_is_the_delay():
    n = 400
    ramp = np.linspace(0.0, 1.0, n)
    out, plain = np.empty(n), np.empty(n)
    _jittered(ramp, 10.0, 2.5, out)  # a symmetric smoothing leaves a ramp's interior unchanged
    _delayed(ramp, 10.0, plain)
    np.testing.assert_allclose(out[40:], plain[40:], atol=1e-12)
    _jittered(np.full(n, 0.3), 10.0, 2.5, out)
    np.testing.assert_allclose(out, 0.3, atol=1e-12)
    _jittered(ramp, 10.0, 0.0, out)
    np.testing.assert_array_equal(out, plain)


# ----------------------------------------------------------------------------------------------
# The registry


CTX = FitContext(a_m=1.35, b_m=1.45, k2_m2=1.5, dt_s=DT, mass_kg=1850.0, inertia_known=True)


@pytest.mark.parametrize("name", list(EFFECTS))
def test_every_registry_entry_is_complete_and_its_coordinates_round_trip(name):
    effect = EFFECTS[name]
    assert effect.fingerprint and effect.term and effect.concealed
    assert set(effect.conceal) == set(effect.synth_defaults) == set(effect.synth_bounds)
    for key, value in effect.synth_defaults.items():
        lo, hi = effect.synth_bounds[key]
        assert lo <= value <= hi or math.isnan(value)  # NaN: the car's own value
    grid = effect.grid(CTX)
    nonlinear = [p for p in effect.parameters if not p.linear]
    assert grid.shape[1] == len(nonlinear) and grid.shape[0] >= 1
    for p in effect.parameters:
        lo, hi = p.bounds_for(CTX)
        assert lo < hi and p.scale > 0
    # A point inside the bounds maps onto the chain and back unchanged.
    values = {f"{name}.{p.name}": 0.5 * sum(p.bounds_for(CTX)) for p in effect.parameters}
    if "tire" in name:
        values |= {f"{name}.understeer": 0.002, f"{name}.log_cr": math.log(50.0)}
    params = params_from((name,), values, CTX)
    back = coordinates_of((name,), params, CTX)
    for key, value in values.items():
        assert back[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
    assert set(effect.report(params, CTX)) <= set(effect.public_keys)


def test_neutral_registry_values_give_the_simulator():
    _, steer, speed = _inputs()
    r_plain, vy_plain, _ = simulate(steer, speed, DT, EffectParams(), 2.5, 2.5, 6.25)
    r_kin, _ = kinematic_bicycle_rates(steer, speed, HIGHWAY_ENV_VEHICLE)
    np.testing.assert_allclose(r_plain, r_kin, rtol=1e-13, atol=1e-15)
    neutral = EffectParams(gain=1.0, offset_rad=0.0, delay_s=0.0, time_constant_s=0.0, max_rate_radps=math.inf,
                           sensor_delay_s=0.0, jitter_s=0.0)
    r, vy, _ = simulate(steer, speed, DT, neutral, 2.5, 2.5, 6.25)
    np.testing.assert_array_equal(r, r_plain)
    np.testing.assert_array_equal(vy, vy_plain)


@pytest.mark.slow
def test_an_effect_registered_at_run_time_is_concealed_named_and_recovered(monkeypatch):
    """The registry claim, at run time: an effect the chain can express is one new EFFECTS entry. Here the
    servo lag is re-registered under another name with its time constant in milliseconds (and the original
    entry removed, so that the two cannot tie); make-recording conceals it and the diagnosis names it and
    recovers it, without any other table being touched."""
    import dataclasses

    from plm_highway.sim2real.diagnose import diagnose
    from plm_highway.sim2real.physics import effects as effects_module
    from plm_highway.sim2real.physics.synth import make_recording
    from plm_highway.sim2real.rendering import to_json

    lag = effects_module.EFFECTS["actuator_lag"]
    servo_ms = dataclasses.replace(
        lag, name="servo_lag_ms",
        parameters=(effects_module.Parameter("time_constant_ms", "ms", (0.0, 800.0), 50.0,
                                             grid=tuple(1000.0 * np.asarray(effects_module.LAG_GRID_S))),),
        public_keys=("time_constant_ms",),
        # make-recording's side keeps the concealed physics' own field (seconds).
        synth_defaults={"time_constant_s": 0.15}, synth_bounds={"time_constant_s": (0.0, 2.0)},
        conceal={"time_constant_s": lag.conceal["time_constant_s"]},
        set_params=lambda v, ctx: {"time_constant_s": v["time_constant_ms"] / 1000.0},
        read_params=lambda p, ctx: {"time_constant_ms": 1000.0 * p.time_constant_s},
        report=lambda p, ctx: {"time_constant_ms": 1000.0 * p.time_constant_s},
        sentence=lambda p, ci: f"a servo lag of {p['time_constant_ms']:.0f} ms",
        separated_from={},
    )
    monkeypatch.delitem(effects_module.EFFECTS, "actuator_lag")
    monkeypatch.setitem(effects_module.EFFECTS, "servo_lag_ms", servo_ms)

    recording, _ = make_recording({"servo_lag_ms": 0.2}, rng=np.random.default_rng(4242), duration_s=120.0)
    result = to_json(diagnose(recording))
    named = {effect["name"]: effect for effect in result["effects"]}
    assert result["verdict"] == "mismatch" and set(named) == {"servo_lag_ms"}, result["summary"]
    estimate_ms = named["servo_lag_ms"]["params"]["time_constant_ms"]
    assert abs(estimate_ms - 200.0) <= 0.2 * 200.0, estimate_ms
    assert "servo lag of" in result["summary"]
