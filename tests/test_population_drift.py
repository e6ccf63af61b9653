"""Drift measurements of the population study (plm_highway.population.drift)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plm_highway.mitigation.posing import slope
from plm_highway.population.drift import drift_summary, offset_bands


def test_offset_bands_separate_a_slow_swing_from_a_fast_weave():
    t_s = np.arange(0.0, 400.0, 1 / 30)
    slow = 1.0 * np.sin(2 * np.pi * 0.05 * t_s)
    fast = 0.3 * np.sin(2 * np.pi * 1.0 * t_s)
    bands = offset_bands(t_s, slow + fast)
    # a sine of amplitude A has RMS A / sqrt(2)
    assert bands["slow_rms_m"] == pytest.approx(1.0 / math.sqrt(2), rel=0.01)
    assert bands["fast_rms_m"] == pytest.approx(0.3 / math.sqrt(2), rel=0.01)
    assert bands["rms_m"] == pytest.approx(math.sqrt(0.5 + 0.045), rel=0.01)


def test_a_run_too_short_to_filter_has_no_bands():
    bands = offset_bands(np.arange(5) / 30, np.ones(5))
    assert math.isnan(bands["slow_rms_m"]) and bands["rms_m"] == pytest.approx(1.0)


def test_slope_is_the_least_squares_slope():
    assert slope([-1, 0, 1], [2.0, 0.0, -2.0]) == pytest.approx(-2.0)


def test_drift_summary_relates_lost_offset_gain_to_slow_drift():
    bands, feedback = {}, {}
    for pair, gain_ratio in enumerate([1.0, 0.5, 0.25]):
        bands[(pair, "reference")] = [{"slow_rms_m": 0.1, "fast_rms_m": 0.05}]
        bands[(pair, "baseline@const:0.25")] = [{"slow_rms_m": 0.2, "fast_rms_m": 0.5}]
        # the slow drift grows exactly as the offset gain shrinks
        bands[(pair, "mitigated@const:0.25")] = [{"slow_rms_m": 0.1 / gain_ratio, "fast_rms_m": 0.06}]
        feedback[pair] = {"bm": {"offset_gain_per_m": -0.2, "heading_gain_per_rad": -2.0},
                          "plm@0.25": {"offset_gain_per_m": -0.2 * gain_ratio, "heading_gain_per_rad": -2.0}}
    summary = drift_summary(bands, feedback, ["const:0.25"])
    entry = summary["settings"]["const:0.25"]
    assert entry["plm_over_bm_offset_gain_per_m"] == pytest.approx((1.0 + 0.5 + 0.25) / 3)
    assert entry["plm_over_bm_heading_gain_per_rad"] == pytest.approx(1.0)
    assert entry["plm_slow_rms_m"] == pytest.approx((0.1 + 0.2 + 0.4) / 3)
    fit = summary["gain_explains_drift"]
    assert fit["slope"] == pytest.approx(1.0) and fit["r"] == pytest.approx(1.0)
