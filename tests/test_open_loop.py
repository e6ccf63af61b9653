"""The open-loop check of PLM-Net along the reference run (plm_highway.evaluation.open_loop)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.evaluation import open_loop
from plm_highway.rollout.conditions import CONDITIONS


def test_holding_and_predicting_on_a_ramp():
    steering = np.arange(10, dtype=float) * 0.1  # the action grows 0.1 per step
    exact = steering + 0.3  # from frame k, the action 3 steps later
    holding, predicted = open_loop.open_loop_errors(steering, exact, 3)
    assert holding == pytest.approx(0.3) and predicted == pytest.approx(0.0)
    # Predicting the present (what holding does) is as good as holding; predicting twice the change, as bad.
    assert open_loop.open_loop_errors(steering, steering, 3) == pytest.approx((0.3, 0.3))
    assert open_loop.open_loop_errors(steering, steering + 0.6, 3)[1] == pytest.approx(0.3)


def test_only_steps_with_a_frame_lag_steps_earlier_count():
    steering = np.array([0.0, 0.0, 1.0, 1.0])
    predicted = np.array([9.0, 0.0, 0.0, 5.0])  # the last prediction has no later action to be judged by
    holding, error = open_loop.open_loop_errors(steering, predicted, 1)
    assert holding == pytest.approx(1 / 3)  # |0-0|, |0-1|, |1-1|
    assert error == pytest.approx((9 + 1 + 1) / 3)  # |9-0|, |0-1|, |0-1|


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=2, max_size=40), st.integers(1, 5))
def test_a_predictor_that_knows_the_future_has_no_error(values, lag):
    steering = np.asarray(values)
    if lag >= len(steering):
        lag = len(steering) - 1
    future = np.concatenate([steering[lag:], np.zeros(lag)])
    holding, predicted = open_loop.open_loop_errors(steering, future, lag)
    assert predicted == 0.0 and holding >= 0.0


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="equal 1-D shapes"):
        open_loop.open_loop_errors(np.zeros(5), np.zeros(4), 1)
    with pytest.raises(ValueError, match="lag 5 steps"):
        open_loop.open_loop_errors(np.zeros(5), np.zeros(5), 5)
    with pytest.raises(ValueError, match="less than one 30 Hz step"):
        open_loop.lag_steps(0.0, 30)


def test_the_lag_is_the_age_of_the_frame_the_env_serves():
    # At 30 Hz, 0.15 s is 4.5 steps: the wrapper serves the newest frame at least that old, 5 steps (0.167 s).
    assert open_loop.lag_steps(0.2, 30) == 6 and open_loop.lag_steps(0.15, 30) == 5
    assert open_loop.lag_steps(0.25, 30) == 8 and open_loop.lag_steps(0.15, 20) == 3
    assert open_loop.constant_latencies(["const:0.15", "steps:0.0-0.35:1.0", "const:0", "const:0.3"], 30) == [0.15, 0.3]
    from plm_highway.rollout.closed_loop import make_env

    env = make_env("test", "const:0.12", None, {"policy_frequency": 20, "simulation_frequency": 20})
    try:
        env.reset(seed=0)
        for _ in range(6):
            _, _, _, _, info = env.step(np.array([0.0], np.float32))
    finally:
        env.close()
    assert info["observation_age_s"] == pytest.approx(open_loop.lag_steps(0.12, 20) / 20) == pytest.approx(0.15)


def test_plm_net_is_told_what_the_conditions_tell_it():
    assert open_loop.told_latency_s(0.15, 5, CONDITIONS["paper"]) == 0.15  # the requested latency (legacy FIFO)
    assert open_loop.told_latency_s(0.12, 3, CONDITIONS["ideal"]) == pytest.approx(0.15)  # the frame's age at 20 Hz


def test_measured_on_a_short_reference_run_with_the_shipped_models():
    from plm_highway.road.track import load_track
    from plm_highway.rollout.policies import make_policies

    conditions = CONDITIONS["ideal"]
    policies = make_policies(None, conditions)
    track = load_track("test")
    recording = open_loop.record_reference(policies["bm"], track, conditions, 0, 40)
    assert recording.frames.shape[0] == 40 == len(recording.steering) and recording.frames.dtype == np.uint8
    # The BM run again on the recorded frames gives the actions it took: the frames are what it saw.
    again = policies["bm"].model_policy.steer_batch(recording.frames, recording.speeds_mps)
    np.testing.assert_array_equal(again, recording.steering)
    result = open_loop.measure_open_loop(track, conditions, policies, [0, 1], [0.15, 0.25], max_steps=40)
    assert set(result) == {0.15, 0.25}
    assert result[0.15]["lag_steps"] == 3 and result[0.25]["lag_steps"] == 5
    first = result[0.15]["per_seed"][0]
    predicted = open_loop.predict(policies["plm"].model_policy, recording, 0.15)
    assert (first["holding_mae"], first["plm_mae"]) == open_loop.open_loop_errors(recording.steering, predicted, 3)
    assert result[0.15]["holding_mae"].n == 2


def _reproduction(open_loop_reduction, closed_loop_reduction):
    from types import SimpleNamespace

    from plm_highway.metrics.intervals import Estimate

    def estimate(mean, half_width=5.0):
        return Estimate(mean, mean - half_width, mean + half_width, 5)

    entry = {"lag_steps": 6, "holding_mae": estimate(0.02, 0.001), "plm_mae": estimate(0.03, 0.002),
             "reduction_pct": estimate(open_loop_reduction)}
    settings = {"const:0.20": {"steering": {"mae_reduction_pct": estimate(closed_loop_reduction)}}}
    return SimpleNamespace(open_loop={0.2: entry}, track=SimpleNamespace(settings=settings, targets=[]),
                           conditions=CONDITIONS["paper"], seeds=[0, 1, 2, 3, 4])


def test_the_report_says_when_the_closed_loop_gain_is_not_prediction():
    from plm_highway.evaluation import report

    damping = _reproduction(-50.0, 40.0)  # open loop worse than holding (CI -55..-45), closed loop better
    lines = report.open_loop_lines(damping)
    assert lines[0] == ("0.20 s: PLM-Net predicts the BM's action worse than holding the earlier one (the CI is below "
                        "0); in closed loop it reduces the BM's error by 40.0%.")
    assert "its gain is not prediction" in lines[1]
    assert any("at 0.20 s (Open loop)" in line for line in report.shows_lines(damping, 0))
    predicting = _reproduction(30.0, 40.0)
    assert "better than holding" in report.open_loop_lines(predicting)[0]
    assert len(report.open_loop_lines(predicting)) == 1
    assert not any("(Open loop)" in line for line in report.shows_lines(predicting, 0))
    both_worse = _reproduction(-50.0, -4.7)  # worse than holding and worse than the BM: no damping gain to explain
    assert report.open_loop_lines(both_worse)[0].endswith("it makes the BM's error 4.7% larger.")
    assert len(report.open_loop_lines(both_worse)) == 1
    assert not any("(Open loop)" in line for line in report.shows_lines(both_worse, 0))
    undecided = _reproduction(2.0, 40.0)  # CI -3..7
    assert "not told apart" in report.open_loop_lines(undecided)[0]
    table = report.open_loop_table(damping)
    assert table[1] == [["0.20 s (6 steps)", "0.0200 [0.0190, 0.0210]", "0.0300 [0.0280, 0.0320]", "-50.0% [-55.0, -45.0]",
                         "40.0% [35.0, 45.0]"]]
