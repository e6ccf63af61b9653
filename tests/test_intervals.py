"""Intervals that respect their quantity (plm_highway.metrics.intervals): errors never below 0, reductions never
above 100%, and no interval from fewer than 3 values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from plm_highway.metrics.intervals import MIN_INTERVAL_VALUES, interval_text, mean_ci, prediction_interval

T_975_2 = 4.302652729911275  # t(0.975, 2), from tables
T_975_3 = 3.182446305284263  # t(0.975, 3)

positive_samples = st.lists(st.floats(1e-6, 1e6), min_size=MIN_INTERVAL_VALUES, max_size=20)
reductions = st.lists(st.floats(-1e4, 99.999), min_size=MIN_INTERVAL_VALUES, max_size=20)


def test_a_positive_quantity_is_interval_of_its_logarithms_by_hand():
    # log values 0, 1, 2: mean 1, sd 1; the 95% interval exp(1 -+ t(0.975, 2) / sqrt(3)) around e
    estimate = mean_ci([1.0, math.e, math.e**2], scale="positive")
    assert estimate.centre == pytest.approx(math.e)
    assert estimate.mean == pytest.approx((1 + math.e + math.e**2) / 3)  # the arithmetic mean, inside the interval
    assert estimate.low < estimate.mean < estimate.high
    assert estimate.low == pytest.approx(math.exp(1 - T_975_2 / math.sqrt(3)))
    assert estimate.high == pytest.approx(math.exp(1 + T_975_2 / math.sqrt(3)))
    assert prediction_interval([1.0, math.e, math.e**2], scale="positive") == pytest.approx(
        (math.exp(1 - T_975_2 * math.sqrt(4 / 3)), math.exp(1 + T_975_2 * math.sqrt(4 / 3))))


def test_a_reduction_is_the_interval_of_the_ratio_by_hand():
    # ratios 0.5, 0.25, 0.125 (reductions 50, 75, 87.5%): log2 ratios -1, -2, -3, mean -2 -> ratio 0.25, reduction 75%
    estimate = mean_ci([50.0, 75.0, 87.5], scale="reduction")
    half = T_975_2 * math.log(2) / math.sqrt(3)  # sd of the natural logs: ln 2
    assert estimate.centre == pytest.approx(75.0)
    assert estimate.mean == pytest.approx(212.5 / 3)
    assert estimate.low == pytest.approx(100 * (1 - 0.25 * math.exp(half)))
    assert estimate.high == pytest.approx(100 * (1 - 0.25 * math.exp(-half)))
    assert estimate.high < 100


def test_the_linear_interval_of_a_signed_quantity_is_unchanged():
    estimate = mean_ci([-1.0, 1.0, 3.0, 5.0])
    sd = np.std([-1.0, 1.0, 3.0, 5.0], ddof=1)
    assert estimate.mean == 2.0
    assert (estimate.low, estimate.high) == pytest.approx((2 - T_975_3 * sd / 2, 2 + T_975_3 * sd / 2))


def test_zeros_keep_a_positive_interval_at_or_above_zero():
    # log(0) is undefined: the linear interval of 0, 1, 2 (mean 1, sd 1) clipped at 0
    estimate = mean_ci([0.0, 1.0, 2.0], scale="positive")
    assert estimate.mean == estimate.centre == 1.0 and estimate.low == 0.0
    assert estimate.high == pytest.approx(1 + T_975_2 / math.sqrt(3))
    all_zero = mean_ci([0.0, 0.0, 0.0], scale="positive")
    assert (all_zero.mean, all_zero.low, all_zero.high) == (0.0, 0.0, 0.0)
    # a mitigated error of 0 is a 100% reduction: the interval reaches 100%, never beyond
    assert mean_ci([100.0, 50.0, 0.0], scale="reduction").high == 100.0


@pytest.mark.parametrize("scale", ["linear", "positive", "reduction"])
@pytest.mark.parametrize("n", [1, 2])
def test_fewer_than_three_values_give_no_interval(scale, n):
    estimate = mean_ci([10.0, 30.0][:n], scale=scale)
    assert estimate.low is None and estimate.high is None and estimate.n == n
    assert prediction_interval([10.0, 30.0][:n], scale=scale) is None
    assert interval_text(estimate.mean, estimate.low, estimate.high, n, what="pairs").endswith(
        f"(n={n}, too few pairs for an interval)")


def test_values_outside_the_quantitys_range_are_refused():
    with pytest.raises(ValueError, match="cannot be negative"):
        mean_ci([1.0, -0.5, 2.0], scale="positive")
    with pytest.raises(ValueError, match="cannot exceed 100%"):
        mean_ci([50.0, 101.0, 20.0], scale="reduction")
    with pytest.raises(ValueError, match="scale"):
        mean_ci([1.0, 2.0, 3.0], scale="log")


@settings(max_examples=200, deadline=None)
@given(positive_samples)
def test_a_positive_quantitys_interval_lies_above_zero_and_contains_the_geometric_mean(values):
    estimate = mean_ci(values, scale="positive")
    geometric_mean = math.exp(sum(math.log(v) for v in values) / len(values))
    assert 0 < estimate.low <= estimate.high < math.inf
    assert estimate.centre == pytest.approx(geometric_mean, rel=1e-9)
    assert estimate.low * (1 - 1e-12) <= geometric_mean <= estimate.high * (1 + 1e-12)
    pi_low, pi_high = prediction_interval(values, scale="positive")
    assert 0 < pi_low <= estimate.low * (1 + 1e-12) and estimate.high <= pi_high * (1 + 1e-12)


@settings(max_examples=200, deadline=None)
@given(reductions)
def test_a_reductions_interval_never_exceeds_100_percent_and_contains_its_centre(values):
    estimate = mean_ci(values, scale="reduction")
    ratios = [1 - v / 100 for v in values]
    centre = 100 * (1 - math.exp(sum(math.log(r) for r in ratios) / len(ratios)))
    assert estimate.centre == pytest.approx(centre, rel=1e-9, abs=1e-9)
    assert estimate.low <= estimate.high <= 100
    assert estimate.low - 1e-9 <= centre <= estimate.high + 1e-9
    pi_low, pi_high = prediction_interval(values, scale="reduction")
    assert pi_low <= estimate.low + 1e-9 and estimate.high <= pi_high + 1e-9 and pi_high <= 100


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0, 1e3), min_size=MIN_INTERVAL_VALUES, max_size=20))
@example([1.0, 1.0, 3.2849250158138383e-292])  # logarithms hundreds of decades apart: the upper bound stays finite
def test_a_positive_quantitys_interval_never_goes_below_zero_even_with_zeros(values):
    estimate = mean_ci(values, scale="positive")
    assert 0 <= estimate.low <= estimate.centre * (1 + 1e-9) and estimate.centre <= estimate.high * (1 + 1e-9)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(1e-6, 1e6), min_size=MIN_INTERVAL_VALUES, max_size=4))
def test_with_three_or_four_values_the_arithmetic_mean_lies_inside_the_log_interval(values):
    estimate = mean_ci(values, scale="positive")
    assert estimate.low * (1 - 1e-9) <= estimate.mean <= estimate.high * (1 + 1e-9)
