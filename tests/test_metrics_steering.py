"""Steering-series errors (plm_highway.metrics.steering) and the run comparison built on them."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.evaluation.comparison import steering_comparison
from plm_highway.metrics import steering

SERIES = st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=0, max_size=30)


def test_errors_against_hand_computed_values():
    reference = [0.0, 0.1, -0.2, 0.3]
    other = [0.1, 0.1, 0.0, 0.0]  # differences 0.1, 0, 0.2, -0.3
    assert steering.steering_mae(reference, other) == pytest.approx(0.6 / 4)
    assert steering.steering_mse(reference, other) == pytest.approx(0.14 / 4)
    assert steering.steering_rmse(reference, other) == pytest.approx(math.sqrt(0.14 / 4))
    assert steering.steering_mae(reference, reference) == 0.0
    errors = steering.steering_errors(reference, other)
    assert errors == pytest.approx({"mae": 0.6 / 4, "mse": 0.14 / 4, "rmse": math.sqrt(0.14 / 4), "steps_compared": 4})
    assert tuple(errors)[:3] == steering.ERROR_NAMES
    assert all(type(errors[name]) is float for name in steering.ERROR_NAMES)


@pytest.mark.parametrize(
    ("reference", "other", "message"),
    [
        ([0.0, 1.0], [0.0, 1.0, 2.0], r"reference and other: lengths differ \(2 vs 3\); .*common_span"),
        ([0.0, math.nan], [0.0, 1.0], r"reference: 1 NaN value at row \[1\]"),
        ([[0.0], [1.0]], [0.0, 1.0], "reference: expected a 1-D array"),
        ([], [], "reference: needs at least 1 sample"),
        ([0.0, 1.0], [0.0, math.inf], r"other: 1 inf value at row \[1\]"),
    ],
)
@pytest.mark.parametrize("name", ["steering_mae", "steering_mse", "steering_rmse", "steering_errors"])
def test_errors_reject_bad_input(name, reference, other, message):
    with pytest.raises(ValueError, match=message):
        getattr(steering, name)(reference, other)


def test_common_span_cuts_every_series_to_the_shortest():
    long, short, middle = [0.0, 0.1, 0.2, 0.3, 0.4], [0.5, 0.1, 0.2], [1.0, 2.0, 3.0, 4.0]
    cut = steering.common_span(long, short, middle)
    assert [c.tolist() for c in cut] == [[0.0, 0.1, 0.2], [0.5, 0.1, 0.2], [1.0, 2.0, 3.0]]
    # the lesson's shorter-run case: compared over the 3 steps both reached
    assert steering.steering_mae(*steering.common_span(long, short)) == pytest.approx(0.5 / 3)
    assert steering.steering_errors(*steering.common_span(long, short))["steps_compared"] == 3


@settings(max_examples=60, deadline=None)
@given(series=st.lists(SERIES, min_size=1, max_size=4))
def test_common_span_properties(series):
    cut = steering.common_span(*series)
    n_steps = min(len(s) for s in series)
    assert len(cut) == len(series)
    for original, part in zip(series, cut):
        assert len(part) == n_steps
        np.testing.assert_array_equal(part, np.asarray(original[:n_steps], dtype=float))


def test_common_span_rejects_no_series_and_bad_values():
    with pytest.raises(ValueError, match="at least one series"):
        steering.common_span()
    with pytest.raises(ValueError, match=r"series 1: 1 NaN value at row \[0\]"):
        steering.common_span([0.0, 1.0], [math.nan])


@pytest.mark.parametrize(
    ("baseline", "mitigated", "expected"),
    [(0.1915, 0.0726, 100 * (1 - 0.0726 / 0.1915)), (0.2, 0.2, 0.0), (0.1, 0.2, -100.0), (0.0, 0.0, 0.0)],
)
def test_reduction_pct(baseline, mitigated, expected):
    assert steering.reduction_pct(baseline, mitigated) == pytest.approx(expected, abs=1e-12)


def fake_logs(**steering_by_run) -> dict:
    return {run: SimpleNamespace(columns={"steering": np.asarray(values, dtype=float)})
            for run, values in steering_by_run.items()}


def test_steering_comparison_each_run_over_its_common_span_with_the_reference():
    logs = fake_logs(reference=[0.0, 0.1, 0.2, 0.3], baseline=[0.2, 0.3], mitigated=[0.0, 0.2, 0.2, 0.3])
    result = steering_comparison(logs)
    assert list(result) == ["baseline", "mitigated", "mae_reduction_pct", "mse_reduction_pct", "rmse_reduction_pct"]
    # baseline left the road after 2 steps: differences 0.2, 0.2
    assert result["baseline"] == pytest.approx({"mae": 0.2, "mse": 0.04, "rmse": 0.2, "steps_compared": 2})
    # mitigated: differences 0, 0.1, 0, 0
    assert result["mitigated"] == pytest.approx({"mae": 0.025, "mse": 0.0025, "rmse": 0.05, "steps_compared": 4})
    assert result["mae_reduction_pct"] == pytest.approx(87.5)
    assert result["mse_reduction_pct"] == pytest.approx(100 * (1 - 0.0025 / 0.04))
    assert result["rmse_reduction_pct"] == pytest.approx(75.0)
