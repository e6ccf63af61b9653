"""The realistic lane measurement: its noise model's statistics, how it is measured, and Table 3 under it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.lane_ekf.policy import error_statistics
from plm_highway.lane_ekf.sensors import LaneMeasurementNoise
from plm_highway.lane_ekf.table3 import (
    REALISTIC_LANE_NOISE,
    SCENARIOS,
    SimulationConfig,
    Table3Report,
    Table3Result,
    measurement_config,
    realistic_config,
    run_scenario,
)

NOISE = LaneMeasurementNoise(bias=(0.02, -0.001, 0.0003), std=(0.06, 0.01, 0.001), correlation_time_s=(0.2, 0.0, 1.0))


@pytest.fixture(scope="module")
def long_sample():
    times = np.arange(200_000) * 0.05
    return times, NOISE.sample(times, np.random.default_rng(3))


def test_noise_has_the_stated_bias_and_standard_deviation(long_sample):
    _, errors = long_sample
    for mean, bias, std in zip(errors.mean(axis=0), NOISE.bias, NOISE.std):
        assert abs(mean - bias) < 0.05 * std  # the sample's mean is far closer than this to the bias
    np.testing.assert_allclose(errors.std(axis=0), NOISE.std, rtol=0.03)


def test_noise_correlates_over_its_correlation_time_only(long_sample):
    times, errors = long_sample
    stats = error_statistics(errors, np.ones(len(times), bool), 0.05)
    # first order: the correlation over one 0.05 s frame is exp(-0.05 / tau)
    assert stats["lag1_correlation"][0] == pytest.approx(math.exp(-0.05 / 0.2), abs=0.01)
    assert abs(stats["lag1_correlation"][1]) < 0.01  # tau = 0: white
    assert stats["lag1_correlation"][2] == pytest.approx(math.exp(-0.05 / 1.0), abs=0.01)
    assert stats["correlation_time_s"][0] == pytest.approx(0.2, rel=0.05)
    assert stats["correlation_time_s"][1] < 0.02  # white: well under one frame
    np.testing.assert_allclose(stats["std"], NOISE.std, rtol=0.03)


def test_noise_over_uneven_gaps_keeps_what_the_gap_allows():
    # pairs 0.1 s apart, the pairs 10 s apart from each other: within a pair the correlation is exp(-0.1 / tau),
    # across pairs none
    times = np.repeat(np.arange(40_000) * 10.0, 2) + np.tile([0.0, 0.1], 40_000)
    errors = LaneMeasurementNoise(std=(1.0, 1.0, 1.0), correlation_time_s=(0.5, 0.5, 0.5)).sample(
        times, np.random.default_rng(0))[:, 0]
    within = np.corrcoef(errors[0::2], errors[1::2])[0, 1]
    across = np.corrcoef(errors[1:-1:2], errors[2::2])[0, 1]
    assert within == pytest.approx(math.exp(-0.1 / 0.5), abs=0.02)
    assert abs(across) < 0.02


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=20, deadline=None)
def test_noise_is_a_pure_function_of_the_generator(seed):
    times = np.linspace(0.0, 3.0, 11)
    first = REALISTIC_LANE_NOISE.sample(times, np.random.default_rng(seed))
    np.testing.assert_array_equal(first, REALISTIC_LANE_NOISE.sample(times, np.random.default_rng(seed)))
    assert first.shape == (11, 3) and np.all(np.isfinite(first))


def test_noise_refuses_bad_settings_and_times():
    with pytest.raises(ValueError, match="std"):
        LaneMeasurementNoise(std=(0.1, -0.1, 0.0))
    with pytest.raises(ValueError, match="bias"):
        LaneMeasurementNoise(bias=(0.0, math.nan, 0.0))
    with pytest.raises(ValueError, match="non-decreasing"):
        NOISE.sample([0.0, 0.2, 0.1], np.random.default_rng(0))


def test_error_statistics_skips_frames_that_are_not_kept():
    errors = np.zeros((6, 3))
    errors[:, 0] = [1.0, -1.0, 1.0, 50.0, 1.0, -1.0]
    kept = np.array([True, True, True, False, True, True])
    stats = error_statistics(errors, kept, 0.05)
    assert stats["bias"][0] == pytest.approx(0.2)  # 50 is not counted
    assert stats["lag1_correlation"][0] == pytest.approx(-1.0)  # pairs (0,1), (1,2), (4,5) only


def test_realistic_config_tells_the_filter_the_larger_noise_but_not_the_bias():
    clean = SimulationConfig()
    realistic = realistic_config(clean)
    assert realistic.lane_noise == REALISTIC_LANE_NOISE and clean.lane_noise is None
    for old, noise, new in zip(clean.estimator.camera_std, REALISTIC_LANE_NOISE.std, realistic.estimator.camera_std):
        assert new == pytest.approx(math.sqrt(old ** 2 + noise ** 2))
    assert measurement_config("clean", clean) is clean
    with pytest.raises(ValueError, match="measurement"):
        measurement_config("noisy")


@pytest.fixture(scope="module")
def scenario1_runs():
    return {name: run_scenario(SCENARIOS[0], 0, measurement_config(name)) for name in ("clean", "realistic")}


def test_realistic_measurement_adds_the_detector_error_to_the_same_frames(scenario1_runs):
    clean, realistic = scenario1_runs["clean"], scenario1_runs["realistic"]
    # same truth, same frames, same sensors: only the lane measurement differs
    np.testing.assert_array_equal(clean.truth.d_m, realistic.truth.d_m)
    np.testing.assert_array_equal(clean.steer_measured_rad, realistic.steer_measured_rad)
    assert [c[:2] for c in clean.camera_captures] == [c[:2] for c in realistic.camera_captures]
    added = realistic.camera_errors - clean.camera_errors
    assert np.std(added[:, 0]) == pytest.approx(REALISTIC_LANE_NOISE.std[0], rel=0.5)
    np.testing.assert_array_equal(clean.estimates["truth_held"], realistic.estimates["truth_held"])


def test_the_delay_alone_row_is_the_camera_row_without_measurement_error(scenario1_runs):
    run = scenario1_runs["clean"]
    lag, camera = run.errors("camera_lag"), run.errors("camera")
    assert lag.shape == camera.shape
    # the clean measurement errs by a few cm at capture: the two rows differ by about that, not by the delay
    assert np.sqrt(np.mean((camera[:, 0] - lag[:, 0]) ** 2)) < 0.05
    assert np.sqrt(np.mean(lag[:, 0] ** 2)) > 0.15  # the delay alone, at 60 km/h in a 1 m weave


def test_report_judges_the_camera_row_within_the_stated_factor(scenario1_runs):
    from plm_highway.lane_ekf.table3 import ScenarioResult
    from plm_highway.metrics.intervals import Estimate

    def result(measurement, camera_d_rmse):
        metrics = {v: {s: {"rmse": Estimate(1.0, 0.9, 1.1, 5), "peak": Estimate(1.0, 0.9, 1.1, 5)}
                       for s in ("d", "dpsi", "vn")} for v in ("camera", "ekf", "ekf_dc", "camera_held", "camera_lag")}
        metrics["camera"]["d"]["rmse"] = Estimate(camera_d_rmse, camera_d_rmse, camera_d_rmse, 5)
        metrics["camera"]["dpsi"]["rmse"] = Estimate(1.003, 1.0, 1.0, 5)  # the paper's S1 values
        metrics["camera"]["vn"]["rmse"] = Estimate(0.271, 0.27, 0.27, 5)
        return Table3Result((0,), (ScenarioResult(SCENARIOS[0], metrics, {}, 3.0, {}),), SimulationConfig(),
                            measurement)

    report = Table3Report((result("clean", 0.201 * 1.49), result("realistic", 0.201 * 1.51)))
    assert report.camera_row_near_paper() == {"clean": {1: True}, "realistic": {1: False}}
    assert report.ratios("camera")["realistic"][1]["d"] == pytest.approx(1.51)
    assert report.command == "plm-highway estimate table3 --seeds 1 --scenarios 1"


@pytest.mark.slow
def test_realistic_noise_is_the_one_measured_on_the_kits_frames_of_the_train_track():
    from plm_highway.lane_ekf.policy import measure_camera_noise

    measured = measure_camera_noise("train", steady_only=True)
    assert measured["frames"] > 1500
    for name in ("std", "correlation_time_s"):
        np.testing.assert_allclose(getattr(REALISTIC_LANE_NOISE, name), measured[name], rtol=0.05)
    np.testing.assert_allclose(REALISTIC_LANE_NOISE.bias, measured["bias"], atol=1e-4)
