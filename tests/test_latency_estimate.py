"""The latency estimated from the stream: synthetic streams with a known lag, the not-estimable case, steps,
robustness, the scoring, and the estimator's inputs (never the truth)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from plm_highway.errors import BadInput
from plm_highway.latency.estimate import (
    DeadReckoning,
    FastSample,
    LaneSample,
    LatencyEstimator,
    LatencyEstimatorConfig,
    estimate_stream,
    fit_alignment,
)
from plm_highway.latency.profiles import TraceProfile
from plm_highway.latency.scoring import lock_metrics, quiet_metrics, quiet_ticks, step_metrics
from plm_highway.latency.synthetic import StreamSpec, Weave, synthetic_stream

FRAME_S = 0.05  # the synthetic streams' 20 Hz loop


def run(stream: dict) -> dict:
    return estimate_stream(stream["time_s"], stream["yaw_rate_radps"], stream["speed_mps"], stream["steer_rad"],
                           stream["lane_offset_m"], stream["lane_heading_rad"])


def test_dead_reckoning_integrates_a_steady_turn_exactly():
    reckoning = DeadReckoning(horizon_s=10.0)
    speed, rate, lateral = 10.0, 0.2, 0.3
    for k in range(21):
        reckoning.add(0.1 * k, rate, speed, lateral)
    t = np.array([0.0, 0.55, 1.0, 2.0])
    s, heading, displacement = reckoning.at(t)
    np.testing.assert_allclose(s, speed * t, atol=1e-12)
    np.testing.assert_allclose(heading, rate * t, atol=1e-12)
    # D = int (u R + v) dt = u r t^2 / 2 + v t: the trapezoidal rule is exact at the ticks, linear in between.
    at_ticks = speed * rate * t ** 2 / 2 + lateral * t
    np.testing.assert_allclose(displacement[[0, 2, 3]], at_ticks[[0, 2, 3]], atol=1e-12)


def test_dead_reckoning_refuses_time_going_backwards():
    reckoning = DeadReckoning(horizon_s=1.0)
    reckoning.add(1.0, 0.0, 10.0, 0.0)
    with pytest.raises(BadInput, match="not after"):
        reckoning.add(1.0, 0.0, 10.0, 0.0)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(lag_steps=st.integers(2, 20), curvature=st.floats(-0.008, 0.008),
       frequency=st.floats(0.4, 1.0), amplitude=st.floats(0.01, 0.03), seed=st.integers(0, 1000))
def test_noise_free_alignment_is_best_at_the_true_lag(lag_steps, curvature, frequency, amplitude, seed):
    """Without camera noise, the window's cost is smallest at the lag the stream was made with (on the 20 ms grid)."""
    lag_s = 0.02 * lag_steps
    stream = synthetic_stream(StreamSpec(duration_s=5.0, latency=lag_s, curvature_1pm=curvature, offset_noise_m=0.0,
                                         heading_noise_rad=0.0, weave=Weave((amplitude,), (frequency,), (0.0,))),
                              np.random.default_rng(seed))
    estimator = LatencyEstimator()
    for k in range(len(stream["time_s"])):
        estimator.reckoning.add(stream["time_s"][k], stream["yaw_rate_radps"][k], stream["speed_mps"][k],
                                estimator.lateral_velocity_mps(stream["steer_rad"][k], stream["speed_mps"][k]))
    window = stream["time_s"] >= 2.0
    lanes = np.column_stack([stream["lane_heading_rad"][window], stream["lane_offset_m"][window]])
    fit = fit_alignment(stream["time_s"][window], lanes, np.full(window.sum(), np.nan), estimator.lags_s,
                        estimator.reckoning, (0.003, 0.02))
    assert estimator.lags_s[fit.best] == pytest.approx(lag_s, abs=1e-9)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(lag_s=st.sampled_from([0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35]), curvature=st.floats(-0.006, 0.006),
       frequency=st.floats(0.5, 1.0), seed=st.integers(0, 1000))
@example(lag_s=0.05, curvature=2.225073858507e-311, frequency=1.0, seed=0)  # a lane too straight for its radius
# Two straight-lane weaves the estimator misses: at 0.2 s an estimable estimate 55 ms off; at 0.1 s estimable on 64%
# of the ticks but withholding at the last one.
@example(lag_s=0.2, curvature=0.0, frequency=1.0, seed=0)
@example(lag_s=0.1, curvature=0.0, frequency=1.0, seed=55)
@pytest.mark.xfail(strict=True, reason="known miss: on a straight lane weaving at 1 Hz the estimator can claim an "
                                       "estimate more than a frame off, or withhold one at the end")
def test_a_weaving_car_gives_an_estimate_within_a_frame(lag_s, curvature, frequency, seed):
    """With the car steering, the estimate becomes estimable, and whenever it is, it is within one frame period."""
    stream = synthetic_stream(StreamSpec(duration_s=10.0, latency=lag_s, curvature_1pm=curvature,
                                         weave=Weave((0.02, 0.01), (frequency, 1.7 * frequency), (0.0, 1.0))),
                              np.random.default_rng(seed))
    result = run(stream)
    estimable = result["estimable"]
    assert estimable[-1], "no estimate after 10 s of weaving"
    assert np.all(np.abs(result["latency_s"][estimable] - lag_s) <= FRAME_S)
    assert abs(result["held_s"][-1] - lag_s) <= FRAME_S / 2


def test_a_straight_without_steering_is_not_estimable():
    stream = synthetic_stream(StreamSpec(duration_s=40.0, latency=0.3, weave=Weave((0.0,), (0.5,), (0.0,))),
                              np.random.default_rng(4))
    result = run(stream)
    assert not result["estimable"].any()
    assert np.all(result["held_s"] == LatencyEstimatorConfig().prior_latency_s)  # the prior: nothing was learnt


def test_nothing_is_estimated_before_the_stream_is_max_latency_old():
    stream = synthetic_stream(StreamSpec(duration_s=3.0, latency=0.1, weave=Weave((0.03,), (1.0,), (0.0,))),
                              np.random.default_rng(5))
    result = run(stream)
    early = stream["time_s"] < LatencyEstimatorConfig().max_latency_s
    assert np.all(np.isnan(result["latency_s"][early])) and not result["estimable"][early].any()


@pytest.mark.parametrize("before_s, after_s", [(0.1, 0.3), (0.3, 0.1)])
def test_a_step_in_the_latency_is_followed(before_s, after_s):
    profile = TraceProfile(np.array([0.0, 11.99, 12.0, 40.0]), np.array([before_s, before_s, after_s, after_s]),
                           spec="trace")
    stream = synthetic_stream(StreamSpec(duration_s=20.0, latency=profile, weave=Weave((0.02, 0.01), (0.5, 0.9),
                                                                                       (0.0, 1.0))),
                              np.random.default_rng(3))
    estimator = LatencyEstimator()
    held = []
    for k in range(len(stream["time_s"])):
        held.append(estimator.update(FastSample(stream["time_s"][k], stream["yaw_rate_radps"][k],
                                                stream["speed_mps"][k], stream["steer_rad"][k]),
                                     LaneSample(stream["lane_offset_m"][k], stream["lane_heading_rad"][k])).held_s)
    held, t = np.array(held), stream["time_s"]
    assert estimator.changes_detected >= 1
    assert np.all(np.abs(held[(t > 6) & (t < 12)] - before_s) <= FRAME_S)
    # Within 3 s of the step the estimate is back within a frame, and stays there.
    assert np.all(np.abs(held[t >= 15] - after_s) <= FRAME_S)


def test_lost_lane_measurements_and_a_fast_clock():
    spec = StreamSpec(duration_s=12.0, latency=0.2, weave=Weave((0.02,), (0.6,), (0.0,)), drop_fraction=0.3)
    stream = synthetic_stream(spec, np.random.default_rng(8))
    assert np.isnan(stream["lane_offset_m"]).mean() == pytest.approx(0.3, abs=0.06)
    result = run(stream)
    assert result["estimable"][-1] and abs(result["held_s"][-1] - 0.2) <= FRAME_S / 2
    # A car clock 1% fast measures every interval 1% longer: the estimate is in its seconds.
    fast = dict(stream, time_s=stream["time_s"] * 1.01)
    assert run(fast)["held_s"][-1] == pytest.approx(1.01 * result["held_s"][-1], abs=0.01)


@pytest.mark.parametrize("field, value", [("window_s", 0.0), ("max_latency_s", float("nan")), ("min_samples", 3),
                                          ("lag_step_s", 0.9), ("vehicle_model", "hovercraft"),
                                          ("split_samples", (4, 0)), ("max_std_frames", True)])
def test_a_bad_configuration_is_refused_by_name(field, value):
    with pytest.raises(BadInput, match=field if field != "vehicle_model" else "hovercraft"):
        LatencyEstimatorConfig(**{field: value})


def test_estimate_stream_refuses_columns_of_different_lengths():
    with pytest.raises(BadInput, match="length"):
        estimate_stream(np.arange(5.0), np.zeros(5), np.ones(4), np.zeros(5), np.zeros(5), np.zeros(5))


def test_a_non_finite_fast_sample_is_refused():
    with pytest.raises(BadInput, match="finite"):
        LatencyEstimator().update(FastSample(0.0, math.nan, 10.0, 0.0))


# -- scoring -------------------------------------------------------------------------------------------------


def test_lock_metrics_by_hand():
    t = np.arange(8) * 0.5
    true = np.full(8, 0.2)
    held = np.array([0.175, 0.175, 0.4, 0.4, 0.22, 0.21, 0.2, 0.5])
    estimable = np.array([0, 0, 1, 0, 1, 1, 1, 0], bool)
    latency = np.where(estimable, held, np.nan)
    m = lock_metrics(t, true, held, latency, estimable, 0.05)
    assert m["first_estimable_s"] == 1.0  # tick 2, wrong
    assert m["lock_s"] == 2.0  # tick 4: the first estimable and right one
    assert m["estimable_fraction"] == 0.5
    assert m["wrong_when_estimable_fraction"] == 0.25  # 1 of 4 estimable ticks
    assert m["within_after_first_fraction"] == pytest.approx(3 / 6)  # ticks 2..7: 4, 5, 6 within
    assert m["within_fraction"] == pytest.approx(5 / 8)  # 0.175 is within 0.05 of 0.2 too


def test_step_metrics_by_hand():
    t = np.arange(10) * 0.5
    true = np.array([0.1, 0.1, 0.1, 0.3, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1])
    held = np.array([0.1, 0.1, 0.1, 0.1, 0.1, 0.28, 0.3, 0.3, 0.3, 0.3])
    m = step_metrics(t, true, held, 0.05, budget_s=1.0)
    assert m["changes"] == 2
    # The first change (t 1.5) is recovered at t 2.5 (1.0 s), the second (t 3.5) never.
    assert m["recovered_within_budget_fraction"] == 0.5
    assert m["median_recovery_s"] == pytest.approx(1.0)
    assert m["never_recovered"] == 1
    assert m["within_fraction"] == pytest.approx(5 / 10)


def test_quiet_ticks_and_their_claims():
    t = np.arange(0, 10, 0.1)
    rate = np.where(t < 5, 0.05 * np.sin(2 * np.pi * t), 0.0)  # weaving, then straight
    quiet = quiet_ticks(t, rate, 2.0, 0.003)
    assert not quiet[t < 5].any() and quiet[t >= 7.05].all()
    estimable = t > 8
    m = quiet_metrics(quiet, np.where(estimable, 0.5, np.nan), np.full(len(t), 0.2), estimable, 0.05)
    assert m["quiet_ticks"] == quiet.sum()
    assert m["estimable_when_quiet_fraction"] == pytest.approx((estimable & quiet).sum() / quiet.sum())
    assert m["wrong_when_quiet_fraction"] == m["estimable_when_quiet_fraction"]  # 0.5 is wrong for 0.2


@settings(max_examples=50, deadline=None)
@given(curvature=st.one_of(st.just(0.0), st.floats(-0.1, 0.1)), x_m=st.floats(-500.0, 500.0),
       y_m=st.floats(-5.0, 5.0))
def test_the_synthetic_lane_offset_is_the_distance_to_the_lane_circle(curvature, x_m, y_m):
    """On any lane, straight or curved, |offset| is the distance from the point to the lane's centre line (a circle
    through the origin centred at (0, 1/kappa), or the x axis), and the car on the centre line has offset 0."""
    from plm_highway.latency.synthetic import _lane_state

    offset_m, _ = _lane_state(np.array([x_m]), np.array([y_m]), np.array([0.0]), curvature)
    if abs(curvature) < 1e-9:
        expected_m = abs(y_m)
    else:
        radius_m = 1.0 / curvature
        expected_m = abs(abs(radius_m) - math.hypot(x_m, y_m - radius_m))
    assert abs(offset_m[0]) == pytest.approx(expected_m, abs=1e-6)


# -- claims: "estimated" only when right, "changing" after a step ---------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(latency_s=st.floats(0.0, 1.0), std_s=st.floats(0.0, 1.0))
def test_an_interval_holds_its_estimate_and_never_reaches_below_zero(latency_s, std_s):
    from plm_highway.latency.estimate import LatencyEstimate

    low, high = LatencyEstimate(latency_s, std_s, True, latency_s, 20, "estimated").interval_s
    assert 0.0 <= low <= latency_s <= high
    assert high - latency_s == pytest.approx(2.0 * std_s)
    assert all(math.isnan(end) for end in LatencyEstimate(math.nan, math.inf, False, 0.175, 0).interval_s)


def claims_after_steps(profile, seed: int):
    from plm_highway.latency.scoring import claim_step_metrics

    stream = synthetic_stream(StreamSpec(duration_s=24.0, latency=profile, weave=Weave((0.02, 0.01), (0.5, 0.9),
                                                                                        (0.0, 1.0))),
                              np.random.default_rng(seed))
    result = run(stream)
    claimed, true_s = result["estimable"], stream["true_latency_s"]
    wrong = claimed & (np.abs(result["held_s"] - true_s) > FRAME_S + 1e-9)
    steps = claim_step_metrics(stream["time_s"], true_s, result["held_s"], claimed, result["changing"], FRAME_S)
    return result, claimed, wrong, steps


@pytest.mark.parametrize("before_s, after_s", [(0.1, 0.3), (0.3, 0.1)])
def test_after_a_step_the_old_value_is_not_claimed_and_the_new_one_is_within_5_s(before_s, after_s):
    profile = TraceProfile(np.array([0.0, 11.99, 12.0, 40.0]), np.array([before_s, before_s, after_s, after_s]),
                           spec="trace")
    result, claimed, wrong, steps = claims_after_steps(profile, 3)
    assert steps["steps_judged"] == 1 and steps["handled"] == 1, steps
    t = np.arange(len(claimed)) * FRAME_S
    assert not wrong[t >= 13.0 - 1e-9].any()  # the old value may be claimed for up to a second, never later
    assert claimed[t < 12.0].any()  # a steady weave with a constant latency is claimed


def test_a_latency_that_changes_every_second_is_not_claimed_wrong():
    # the paper's time-varying profile: a new latency in [0, 0.35] s every second; the window (3 s) holds three
    for seed in (0, 1):
        _, claimed, wrong, _ = claims_after_steps("steps:0.0-0.35:1.0", seed)
        assert wrong.sum() <= 0.05 * max(claimed.sum(), 1), (seed, int(wrong.sum()), int(claimed.sum()))
