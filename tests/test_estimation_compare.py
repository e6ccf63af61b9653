"""The EKF policy in ``evaluate``, and the PLM-Net vs EKF comparison (``estimate compare``)."""

from __future__ import annotations

import json
import math

import gymnasium
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.errors import OutputRefused
from plm_highway.estimation.policy import EkfLaneKeepingPolicy, EkfPolicyConfig, ekf_policy
from plm_highway.evaluation.plm_vs_ekf import (
    CompareConfig,
    CompareResult,
    RunRow,
    compare,
    markdown,
    planned_runs,
    start_pose,
    verdict,
)
from plm_highway.expert import ExpertPolicy
from plm_highway.latency import LatencyWrapper
from plm_highway.rollout.policies import POLICY_NAMES, make_policy


def test_make_policy_knows_the_ekf():
    assert "ekf" in POLICY_NAMES
    policy = make_policy("ekf", latency_bias_s=0.05, seed=3)
    assert isinstance(policy, EkfLaneKeepingPolicy)
    assert policy.config.latency_bias_s == 0.05 and policy.config.compensate_delay and policy.seed == 3
    assert not ekf_policy(compensate_delay=False).estimator.compensate_delay


def _estimate_errors(compensate: bool, latency: str = "const:0.3", steps: int = 70) -> np.ndarray:
    """|estimated d - true d now| per step, from a start 0.6 m off the lane centre (a transient to track)."""
    env = LatencyWrapper(gymnasium.make("plm_highway/LaneKeeping-v0",
                                        config={"track": "test", "start_offset_m": 0.6}), latency)
    policy = ekf_policy(compensate_delay=compensate, seed=0)
    obs, info = env.reset(seed=0)
    policy.reset()
    errors = []
    for _ in range(steps):
        action = policy(obs, info)
        errors.append(policy.estimator.state[0] - info["lateral_offset_m"])
        obs, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        assert not terminated
    env.close()
    return np.abs(np.array(errors[20:]))  # after the first late frames arrived


def test_delay_compensation_estimates_the_present_offset_better_than_fusing_late_frames_as_current():
    compensated, uncompensated = _estimate_errors(True), _estimate_errors(False)
    assert np.sqrt(np.mean(compensated ** 2)) < 0.7 * np.sqrt(np.mean(uncompensated ** 2))


def test_evaluate_policy_ekf_runs_its_own_three_variants():
    from plm_highway.evaluation.evaluate import evaluate

    result, logs = evaluate("test", "const:0.2", "ekf", seed=1, max_steps=25)
    assert set(logs) == {"reference", "baseline", "mitigated"}
    assert result["policy"] == "ekf" and result["latency"] == "const:0.2"
    assert set(result["steering"]) >= {"baseline", "mitigated", "mae_reduction_pct"}
    assert logs["reference"].columns["observation_age_s"].max() == 0.0
    assert logs["mitigated"].columns["observation_age_s"][-1] == pytest.approx(0.2)


def test_evaluate_cli_accepts_policy_ekf(tmp_path):
    from plm_highway import cli

    out = tmp_path / "e.json"
    assert cli.main(["evaluate", "--policy", "ekf", "--latency", "const:0.1", "--max-steps", "10",
                     "--json", str(out)]) == 0
    assert json.loads(out.read_text())["policy"] == "ekf"


@given(st.integers(0, 2**32 - 1))
def test_start_pose_is_a_pure_function_of_the_seed_within_bounds(seed):
    config = CompareConfig(start_offset_max_m=0.4, start_heading_max_rad=0.03)
    pose = start_pose(seed, config)
    assert pose == start_pose(seed, config)
    assert abs(pose["start_offset_m"]) <= 0.4 and abs(pose["start_heading_error_rad"]) <= 0.03


def test_planned_runs_references_first_then_every_policy_per_setting_then_biases():
    config = CompareConfig(settings=("const:0.1", "const:0.3"), biases_s=(-0.05, 0.1))
    runs = planned_runs(config)
    assert runs[:2] == [("bm", "const:0", 0.0), ("ekf", "const:0", 0.0)]
    assert len(runs) == 2 + 2 * 3 + 2 * 2
    assert ("plm", "const:0.25", -0.05) in runs and ("ekf", "const:0.25", 0.1) in runs


@pytest.mark.parametrize("kwargs, match", [
    ({"settings": ()}, "at least one"), ({"settings": ("const:abc",)}, "abc"), ({"biases_s": (math.nan,)}, "biases"),
    ({"start_offset_max_m": 2.0}, "start_offset"), ({"max_steps": 1}, "max_steps"),
])
def test_bad_comparison_conditions_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        CompareConfig(**kwargs)


def test_paired_difference_and_verdict():
    config = CompareConfig(settings=("const:0.2",), biases_s=())
    result = CompareResult(config, (0, 1, 2))
    ekf = [0.30, 0.32, 0.34]
    plm = [0.10, 0.13, 0.12]
    for seed in range(3):
        result.rows.append(RunRow("ekf", "const:0.2", 0.0, seed, {"steering_mae_vs_bm_ref": ekf[seed]}))
        result.rows.append(RunRow("plm", "const:0.2", 0.0, seed, {"steering_mae_vs_bm_ref": plm[seed]}))
    diff = result.paired_difference("const:0.2", "steering_mae_vs_bm_ref")
    differences = np.array(ekf) - np.array(plm)
    half = 4.302652729911275 * differences.std(ddof=1) / math.sqrt(3)  # t(0.975, 2)
    assert diff["mean"] == pytest.approx(differences.mean())
    assert diff["low"] == pytest.approx(differences.mean() - half)
    assert verdict(diff) == "EKF worse"
    assert verdict({"mean": -1.0, "low": -2.0, "high": -0.5}) == "PLM-Net worse"
    assert verdict({"mean": 0.1, "low": -0.2, "high": 0.4}) == "no clear difference"


def _small_policies(name, latency_bias_s, seed):
    # The learned policies' places taken by the expert (no checkpoints, fast); the EKF is the real one.
    return ekf_policy(latency_bias_s=latency_bias_s, seed=seed) if name == "ekf" else ExpertPolicy()


def test_compare_measures_every_policy_under_the_same_conditions_and_publishes(tmp_path):
    from plm_highway.evaluation.plm_vs_ekf_report import publish_comparison

    config = CompareConfig(settings=("const:0.2",), biases_s=(0.1,), max_steps=20)
    result = compare(2, config, progress=False, policy_factory=_small_policies)
    assert len(result.rows) == 2 * len(planned_runs(config))
    reference = [r for r in result.rows if (r.policy, r.latency) == ("bm", "const:0")]
    assert all(r.metrics["steering_mae_vs_bm_ref"] == 0.0 for r in reference)
    # The seeds start from different poses, so their runs differ.
    offsets = {r.seed: r.metrics["lateral_offset_max_m"] for r in reference}
    assert offsets[0] != offsets[1]
    assert all(r.metrics["ms_per_step"] > 0 for r in result.rows)
    data = result.to_dict()
    (entry, biased) = data["summary"]
    assert entry["policies"]["ekf"]["lateral_offset_rms_m"]["n"] == 2
    assert set(biased["policies"]) == {"plm", "ekf"}
    text = markdown(data)
    assert "### const:0.2" in text and "told +0.10 s off" in text and "## Where each is worse" in text

    out, json_path = tmp_path / "report", tmp_path / "c.json"
    publish_comparison(result, json_path, out)
    assert json.loads((out / "compare.json").read_text())["seeds"] == [0, 1]
    assert (out / "compare.png").stat().st_size > 10_000
    assert (out / "runs.csv").read_text().count("\n") == len(result.rows) + 1
    with pytest.raises(OutputRefused, match="overwrite"):
        publish_comparison(result, json_path, None)


@pytest.mark.slow
def test_policy_camera_noise_is_the_measured_one_on_the_train_track():
    from plm_highway.estimation.policy import measure_camera_noise

    measured = measure_camera_noise("train")
    assert measured["frames"] > 2000
    for configured, std in zip(EkfPolicyConfig().camera_std, measured["std"]):
        assert configured == pytest.approx(std, rel=0.1)
