"""Run outcomes on the lane and on the steering, over the whole scored track (plm_highway.evaluation.outcomes)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.evaluation.outcomes import OUTCOMES, path_frechet_m, run_outcomes
from plm_highway.rollout.closed_loop import RunLog

# the paper's unit per normalised steering at 0.4 rad: 0.4 rad x 12 (steering ratio) / 450 deg, worked by hand
PAPER_UNIT_PER_STEERING_AT_04 = 0.4 * 12.0 / math.radians(450.0)


def straight_log(steering, offset_m, left_road=False, speed_mps=15.0, dt_s=0.1, name="run"):
    steering = np.asarray(steering, dtype=float)
    offset_m = np.asarray(offset_m, dtype=float)
    n = len(steering)
    t_s = np.arange(n) * dt_s
    x_m = speed_mps * t_s
    columns = {"t_s": t_s, "steering": steering, "x_m": x_m, "y_m": offset_m, "lateral_offset_m": offset_m,
               "arc_length_m": x_m, "segment": np.array(["straight"] * n)}
    return RunLog(name, columns, left_road, 1.0)


def test_identical_runs_have_no_error_and_share_the_lane_outcomes():
    reference = straight_log(np.zeros(50), np.full(50, 0.3))
    outcomes = run_outcomes(reference, reference, None, 0.4)
    assert set(outcomes) == set(OUTCOMES)
    assert outcomes["steering_mae_paper"] == 0.0
    assert outcomes["frechet_m"] == pytest.approx(0.0, abs=1e-12)
    assert outcomes["offset_rms_m"] == pytest.approx(0.3)
    assert outcomes["offset_max_m"] == pytest.approx(0.3)
    assert outcomes["left_road"] is False and outcomes["left_road_t_s"] is None


def test_a_constant_steering_bias_is_reported_in_the_papers_unit():
    reference = straight_log(np.zeros(40), np.zeros(40))
    run = straight_log(np.full(40, 0.05), np.zeros(40))
    outcomes = run_outcomes(run, reference, None, 0.4)
    assert outcomes["steering_mae_paper"] == pytest.approx(0.05 * PAPER_UNIT_PER_STEERING_AT_04)
    assert outcomes["steering_mae_paper_common"] == pytest.approx(0.05 * PAPER_UNIT_PER_STEERING_AT_04)


def test_leaving_the_road_is_penalised_over_the_whole_track_in_steering_and_offset():
    reference = straight_log(np.zeros(10), np.zeros(10))
    # drives 4 of the 10 scored steps with error 0.1, then leaves at 6.5 m from the lane centre
    run = straight_log([0.1] * 4, [0.0, 1.0, 3.0, 6.5], left_road=True)
    outcomes = run_outcomes(run, reference, None, 0.4)
    # by hand: (4 x 0.1 + 6 missed steps x 1.0) / 10 = 0.64 normalised
    assert outcomes["steering_mae_paper"] == pytest.approx(0.64 * PAPER_UNIT_PER_STEERING_AT_04)
    assert outcomes["steering_mae_paper_common"] == pytest.approx(0.1 * PAPER_UNIT_PER_STEERING_AT_04)
    # offsets 0, 1, 3, 6.5 then 6 more steps at 6.5 m: sqrt((0 + 1 + 9 + 7 x 42.25) / 10)
    assert outcomes["offset_rms_m"] == pytest.approx(math.sqrt((1 + 9 + 7 * 42.25) / 10))
    assert outcomes["offset_rms_driven_m"] == pytest.approx(math.sqrt((1 + 9 + 42.25) / 4))
    assert outcomes["offset_max_m"] == pytest.approx(6.5)
    assert outcomes["left_road"] is True
    assert outcomes["left_road_t_s"] == pytest.approx(0.3)
    assert outcomes["steps_driven"] == 4 and outcomes["steps_scored"] == 10


def test_frechet_between_parallel_paths_is_their_separation():
    a = straight_log(np.zeros(30), np.zeros(30))
    b = straight_log(np.zeros(30), np.full(30, 0.5))
    assert path_frechet_m(b.columns, a.columns) == pytest.approx(0.5, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=40), st.lists(st.floats(-2.0, 2.0), min_size=3,
                                                                          max_size=40))
def test_frechet_is_symmetric_and_at_least_the_gap_at_the_ends(offsets_a, offsets_b):
    a = straight_log(np.zeros(len(offsets_a)), offsets_a)
    b = straight_log(np.zeros(len(offsets_b)), offsets_b)
    d_ab = path_frechet_m(a.columns, b.columns)
    d_ba = path_frechet_m(b.columns, a.columns)
    assert d_ab == pytest.approx(d_ba, rel=1e-12, abs=1e-12)
    start_gap = abs(offsets_a[0] - offsets_b[0])
    end_gap = math.hypot(a.columns["x_m"][-1] - b.columns["x_m"][-1], offsets_a[-1] - offsets_b[-1])
    # every coupling pairs the two starts and the two ends
    assert d_ab >= max(start_gap, end_gap) - 1e-9
