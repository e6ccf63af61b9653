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
from plm_highway.errors import BadInput
from plm_highway.evaluation.plm_vs_ekf import CompareConfig, CompareResult, RunRow, planned_runs, verdict, who_wins
from plm_highway.lane_ekf.policy import EkfLaneKeepingPolicy, EkfPolicyConfig, ekf_policy
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


def test_planned_runs_reference_first_then_no_latency_then_every_policy_per_setting_then_biases():
    config = CompareConfig(settings=("const:0.1", "const:0.3"), biases_s=(-0.05, 0.1))
    runs = planned_runs(config)
    assert runs[:3] == [("bm", "const:0", 0.0), ("plm", "const:0", 0.0), ("ekf", "const:0", 0.0)]
    assert runs[3:7] == [("bm", "const:0.1", 0.0), ("plm", "const:0.1", 0.0), ("ekf_nc", "const:0.1", 0.0),
                         ("ekf", "const:0.1", 0.0)]
    assert len(runs) == 3 + 2 * 4 + 2 * 2
    assert runs[-4:] == [("plm", "const:0.25", -0.05), ("ekf", "const:0.25", -0.05), ("plm", "const:0.25", 0.1),
                         ("ekf", "const:0.25", 0.1)]


@pytest.mark.parametrize("kwargs, match", [
    ({"settings": ()}, "at least one"), ({"settings": ("const:abc",)}, "abc"), ({"biases_s": (math.nan,)}, "biases"),
    ({"biases_s": (0.0,)}, "nonzero"), ({"settings": ("const:0", "const:0.2")}, "reference"),
    ({"conditions": "sunny"}, "sunny"), ({"max_steps": 1}, "max-steps"),
])
def test_bad_comparison_conditions_are_refused(kwargs, match):
    with pytest.raises(BadInput, match=match):
        CompareConfig(**kwargs)


def _result_with(values: dict[str, list[float]], metric="offset_rms_m", latency="const:0.2") -> CompareResult:
    result = CompareResult(CompareConfig(settings=(latency,)), (0, 1, 2))
    for policy, per_seed in values.items():
        for seed, value in enumerate(per_seed):
            result.rows.append(RunRow(policy, latency, 0.0, seed, {metric: value}))
    return result


def test_paired_difference_is_per_seed_with_a_student_t_interval():
    ekf, plm = [0.30, 0.32, 0.34], [0.10, 0.13, 0.12]
    result = _result_with({"ekf": ekf, "plm": plm})
    diff = result.paired_difference("const:0.2", "offset_rms_m", "ekf", "plm")
    differences = np.array(ekf) - np.array(plm)
    half = 4.302652729911275 * differences.std(ddof=1) / math.sqrt(3)  # t(0.975, 2), worked by hand
    assert diff["mean"] == pytest.approx(differences.mean())
    assert diff["low"] == pytest.approx(differences.mean() - half)
    assert verdict(diff, "ekf", "plm") == "PLM-Net better"
    assert verdict({"mean": -1.0, "low": -2.0, "high": -0.5}, "ekf", "plm") == "EKF lane keeper, delay compensated better"
    assert verdict({"mean": 0.1, "low": -0.2, "high": 0.4}, "ekf", "plm") == "no clear difference"
    # a seed the second policy lacks is left out of the pairs
    result.rows = [r for r in result.rows if not (r.policy == "plm" and r.seed == 2)]
    assert result.paired_difference("const:0.2", "offset_rms_m", "ekf", "plm")["n"] == 2


@given(st.lists(st.tuples(st.floats(0, 2), st.floats(0, 2)), min_size=3, max_size=3))
def test_paired_difference_turns_over_when_the_pair_does(pairs):
    result = _result_with({"ekf": [a for a, _ in pairs], "plm": [b for _, b in pairs]})
    forward = result.paired_difference("const:0.2", "offset_rms_m", "ekf", "plm")
    backward = result.paired_difference("const:0.2", "offset_rms_m", "plm", "ekf")
    assert forward["mean"] == pytest.approx(-backward["mean"], abs=1e-12)
    assert forward["low"] == pytest.approx(-backward["high"], abs=1e-9)
    assert forward["low"] <= forward["mean"] <= forward["high"]


def test_summaries_stay_within_their_quantitys_range():
    # skewed offsets, a road left in 4 and in 1 of 5 seeds: linear intervals would reach below 0 and above 1
    result = _result_with({"plm": [0.1, 0.1, 0.1, 0.1, 3.0]}, metric="offset_rms_m")
    offsets = result.summary("plm", "const:0.2")["offset_rms_m"]
    assert 0 < offsets["low"] < offsets["high"] and offsets["mean"] == pytest.approx(0.68)
    result = _result_with({"plm": [0.0, 1.0, 1.0, 1.0, 1.0]}, metric="left_road")
    left = result.summary("plm", "const:0.2")["left_road"]
    assert left["mean"] == pytest.approx(0.8) and left["low"] > 0.0 and left["high"] == 1.0
    result = _result_with({"plm": [0.0, 0.0, 0.0, 0.0, 1.0]}, metric="left_road")
    left = result.summary("plm", "const:0.2")["left_road"]
    assert left["low"] == 0.0 and left["high"] < 1.0


def test_who_wins_reads_the_paired_interval():
    entry = {"paired": {"ekf-plm": {"offset_rms_m": {"mean": -0.1, "low": -0.2, "high": -0.01, "n": 5}}}}
    assert who_wins(entry, "offset_rms_m") == "EKF"
    entry["paired"]["ekf-plm"]["offset_rms_m"].update(low=0.01, high=0.2)
    assert who_wins(entry, "offset_rms_m") == "PLM-Net"
    entry["paired"]["ekf-plm"]["offset_rms_m"].update(low=-0.01, high=0.2)
    assert who_wins(entry, "offset_rms_m") == "neither"


@pytest.mark.slow
def test_compare_command_drives_five_policies_under_both_conditions_and_publishes(tmp_path):
    from plm_highway import cli

    out, json_path = tmp_path / "report", tmp_path / "c.json"
    assert cli.main(["estimate", "compare", "--conditions", "ideal,paper", "--seeds", "2", "--settings", "const:0.2",
                     "--biases=0.1", "--max-steps", "12", "--json", str(json_path), "--out", str(out)]) == 0
    data = json.loads(json_path.read_text())
    assert [r["config"]["conditions"] for r in data["reports"]] == ["ideal", "paper"]
    for report in data["reports"]:
        assert report["steps_scored"] == 12 and report["seeds"] == [0, 1]
        runs = report["runs"]
        assert len(runs) == 2 * (3 + 4 + 2)
        reference = [r for r in runs if (r["policy"], r["latency"]) == ("bm", "const:0")]
        assert all(r["outcomes"]["steering_mae_paper"] == 0.0 and r["outcomes"]["frechet_m"] == 0.0
                   for r in reference)
        assert all(r["outcomes"]["steps_driven"] == 12 for r in runs)
        (no_latency, at_02, biased) = report["settings"]
        assert set(no_latency["policies"]) == {"bm", "plm", "ekf"}
        assert set(at_02["policies"]) == {"bm", "plm", "ekf_nc", "ekf"}
        assert set(at_02["paired"]) == {"ekf-plm", "ekf-ekf_nc", "plm-bm"}
        assert at_02["policies"]["ekf"]["offset_rms_m"]["n"] == 2
        assert biased["bias_s"] == 0.1 and set(biased["policies"]) == {"plm", "ekf"}
        assert report["command"].startswith(f"plm-highway estimate compare --conditions {report['config']['conditions']}")
    # the seeds start from different poses (seed 0 centred)
    ideal = data["reports"][0]["runs"]
    offsets = {r["seed"]: r["outcomes"]["offset_max_m"] for r in ideal if r["policy"] == "bm" and r["latency"] == "const:0"}
    assert offsets[0] != offsets[1]
    assert data["reports"][1]["conditions"]["policy_frequency_hz"] == 30
    text = (out / "compare.md").read_text()
    assert "## Who wins where" in text and "## Conditions `paper`" in text and "told +0.10 s off" in text
    assert (out / "compare.png").stat().st_size > 10_000
    assert (out / "runs.csv").read_text().count("\n") == 2 * 2 * (3 + 4 + 2) + 1
    assert json.loads((out / "compare.json").read_text()) == data
    # refusals: an output it did not write, and bad options, cost no driving
    assert cli.main(["estimate", "compare", "--seeds", "1", "--json", str(json_path)]) == 2
    assert cli.main(["estimate", "compare", "--conditions", "sunny", "--seeds", "1"]) == 2
    assert cli.main(["estimate", "compare", "--settings", "const:0", "--seeds", "1"]) == 2
    assert cli.main(["estimate", "compare", "--biases", "x", "--seeds", "1"]) == 2


@pytest.mark.slow
def test_policy_camera_noise_is_the_measured_one_on_the_train_track():
    from plm_highway.lane_ekf.policy import measure_camera_noise

    measured = measure_camera_noise("train")
    assert measured["frames"] > 2000
    for configured, std in zip(EkfPolicyConfig().camera_std, measured["std"]):
        assert configured == pytest.approx(std, rel=0.1)
