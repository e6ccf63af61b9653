"""The latency estimate in the closed loop: the stream adapter reads no truth, ``--latency-source estimated`` reaches
PLM-Net, the EKF and the logs, the measurement's report is its results file's, and sim2real's perception delay."""

from __future__ import annotations

import csv
import json
import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

from plm_highway import cli
from plm_highway.evaluation.latency_estimation import LatencySuite, Results, RunSpec, drive_run, plan
from plm_highway.evaluation.latency_estimation_report import render_markdown, write_latency_report
from plm_highway.latency.synthetic import StreamSpec, Weave, synthetic_stream
from plm_highway.rollout.policies import LATENCY_SOURCES, VisionPolicy

ESTIMATE_COLUMNS = ("latency_estimate_s", "latency_estimate_std_s", "latency_estimable")


def read_csv(path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.slow
def test_evaluate_with_the_estimated_latency_logs_it_beside_the_true_age(tmp_path, capsys):
    out = tmp_path / "eval"
    code = cli.main(["evaluate", "--latency", "const:0.25", "--latency-source", "estimated", "--max-steps", "30",
                     "--out", str(out)])
    assert code == 0
    result = json.loads((out / "result.json").read_text())
    assert result["latency_source"] == "estimated"
    for run in ("reference", "baseline", "mitigated"):
        rows = read_csv(out / f"{run}.csv")
        assert len(rows) == 30
        assert set(ESTIMATE_COLUMNS) <= set(rows[0]) and "observation_age_s" in rows[0]
        # Nothing to align in the first second: the prior, not estimable.
        assert rows[0]["latency_estimable"] == "False" and float(rows[0]["latency_estimate_s"]) == 0.175
    assert {f"mitigated_{c}" for c in ESTIMATE_COLUMNS} <= set(read_csv(out / "steps.csv")[0])


def test_without_the_estimated_source_no_estimate_is_logged(tmp_path):
    from plm_highway.expert import ExpertPolicy
    from plm_highway.rollout.closed_loop import drive

    log = drive("expert", ExpertPolicy(), "test", "const:0.1", 0, max_steps=5)
    assert not set(ESTIMATE_COLUMNS) & set(log.columns)


def test_plm_net_told_the_estimate_reads_it_from_info():
    told = []

    class ModelPolicy:
        def reset(self):
            pass

        def __call__(self, frame, speed_mps, latency_s):
            told.append(latency_s)
            return 0.0

    policy = VisionPolicy(ModelPolicy(), latency_source="estimated")
    assert LATENCY_SOURCES["estimated"] == "latency_estimate_s"
    policy(np.zeros((2, 2), np.uint8), {"speed_mps": 10.0, "latency_estimate_s": 0.31, "observation_age_s": 0.25,
                                        "latency_s": 0.2})
    assert told == [0.31]


def test_the_observer_reads_only_the_fast_sensors():
    """The estimate depends on the frame and the fast sensors alone: the truth in info changes nothing."""
    from plm_highway.camera.pinhole import CameraConfig
    from plm_highway.lane_ekf.lane_camera import LaneDetector, LaneDetectorConfig
    from plm_highway.lane_ekf.latency_stream import FAST_SENSOR_KEYS, CameraLatencyObserver

    frame = np.full((66, 200), 90, np.uint8)
    frame[40:, 60:64] = 230  # a marking
    results = []
    for truth in ({}, {"observation_age_s": 0.3, "latency_s": 0.3, "observed_state": {"time_s": 0.0}}):
        observer = CameraLatencyObserver(LaneDetector(CameraConfig(), LaneDetectorConfig(lane_width_m=4.0)))
        estimates = []
        for k in range(30):
            info = {"time_s": 0.05 * k, "yaw_rate_radps": 0.01 * math.sin(k), "speed_mps": 16.7,
                    "steering_angle_rad": 0.002 * math.sin(k), **truth}
            estimates.append(tuple(observer.observe(frame, info)))
        results.append(estimates)
    assert results[0] == results[1]
    assert FAST_SENSOR_KEYS == ("time_s", "yaw_rate_radps", "speed_mps", "steering_angle_rad")


def test_the_ekf_policy_restamps_by_the_estimate():
    from plm_highway.lane_ekf.policy import EkfLaneKeepingPolicy, EkfPolicyConfig

    stamps = []
    policy = EkfLaneKeepingPolicy(EkfPolicyConfig(latency_source="estimated"))
    policy._fuse_frame = lambda frame, capture_s: stamps.append(capture_s)
    info = {"time_s": 2.0, "speed_mps": 16.7, "yaw_rate_radps": 0.0, "steering": 0.0, "observation_age_s": 0.25,
            "latency_estimate_s": 0.3}
    policy(np.zeros((66, 200), np.uint8), info)
    assert stamps == [pytest.approx(1.7)]
    with pytest.raises(ValueError, match="latency_estimate_s"):
        policy(np.zeros((66, 200), np.uint8), {k: v for k, v in info.items() if k != "latency_estimate_s"})


def test_runs_under_estimated_conditions_carry_the_estimator_and_the_source():
    """What reproduce and evaluate --seeds drive: every run cell estimates its latency and PLM-Net is told that."""
    from plm_highway.road.track import load_track
    from plm_highway.rollout.cells import Cell, runs_under
    from plm_highway.rollout.conditions import CONDITIONS, with_latency_source

    for name in ("ideal", "paper"):
        chosen = with_latency_source(CONDITIONS[name], "estimated")
        runs = runs_under([Cell("mitigated", "plm", "const:0.2", 1), Cell("baseline", "bm", "const:0.2", 1)],
                          load_track("test"), chosen, max_steps=5)
        assert all(run.latency_estimation is chosen.latency_estimation is not None for run in runs)
        assert {run.latency_source for run in runs} == {"estimated"}
    measured = runs_under([Cell("mitigated", "plm", "const:0.2", 1)], load_track("test"),
                          with_latency_source(CONDITIONS["paper"], "measured"), max_steps=5)
    assert measured[0].latency_estimation is None and measured[0].latency_source == "measured"


@pytest.mark.slow
def test_evaluate_the_ekf_with_the_estimated_latency(tmp_path):
    out = tmp_path / "eval"
    code = cli.main(["evaluate", "--policy", "ekf", "--latency", "const:0.25", "--latency-source", "estimated",
                     "--max-steps", "20", "--out", str(out)])
    assert code == 0
    assert json.loads((out / "result.json").read_text())["latency_source"] == "estimated"
    for run in ("reference", "baseline", "mitigated"):  # the re-stamping run would refuse without the estimate
        assert set(ESTIMATE_COLUMNS) <= set(read_csv(out / f"{run}.csv")[0])


def test_the_plan_covers_the_suite():
    suite = LatencySuite(conditions=("ideal",), tracks=("test",), seeds=(0, 1), constants_s=(0.1,),
                         profiles=("steps:0.0-0.35:1.0",), mitigation_constants_s=(0.1,),
                         mitigation_profiles=("steps:0.0-0.35:1.0",))
    runs = plan(suite)
    assert len({run.key for run in runs}) == len(runs)
    per_seed = [run for run in runs if run.seed == 0 and not run.variant]
    assert {(run.latency, run.role) for run in per_seed} == {
        ("const:0", "reference"), ("const:0.1", "estimated"), ("steps:0.0-0.35:1.0", "estimated"),
        ("const:0.1", "baseline"), ("const:0.1", "true"), ("steps:0.0-0.35:1.0", "baseline"),
        ("steps:0.0-0.35:1.0", "true")}
    assert {run.variant for run in runs if run.variant} == {"dropped", "jitter", "drift", "recording", "probe"}
    # the probe under the robustness setting and under each probe setting, per seed
    assert sorted(run.latency for run in runs if run.variant == "probe" and run.seed == 0) == [
        "const:0.25", "steps:0.0-0.35:1.0"]


@pytest.mark.slow
def test_a_recorded_stream_without_timestamps_estimates_as_online():
    record = drive_run(RunSpec("ideal", "test", 1, "const:0.25", "estimated", "recording"), max_steps=60)
    assert record["recording"]["ticks"] == 60
    assert record["recording"]["agrees_with_online_fraction"] == 1.0
    assert record["recording"]["max_difference_from_online_s"] < 1e-3
    assert set(record["estimate"]) >= {"lock", "quiet", "frame_s"}


# -- the steering probe ----------------------------------------------------------------------------------------


def test_the_probe_by_hand():
    from plm_highway.lane_ekf.latency_stream import probe_rad_at

    assert probe_rad_at(0.0, 0.02, (1.0, 0.6)) == pytest.approx(0.02 * math.sin(1.0) / math.sqrt(2.0))
    assert probe_rad_at(0.25, 0.02, (1.0,)) == pytest.approx(0.02)  # a quarter period of one tone
    assert probe_rad_at(1.7, 0.0, (1.0, 0.6)) == 0.0
    # over the tones' common period (3 s) the mean square is amplitude^2 / 2 (each unit sine's mean square is 1/2)
    times_s = np.arange(0.0, 3.0, 1e-3)
    values = np.array([probe_rad_at(t, 0.02, (1.0, 0.6)) for t in times_s])
    assert float(np.sqrt(np.mean(values ** 2))) == pytest.approx(0.02 / math.sqrt(2.0), rel=1e-3)


def test_the_wrapper_adds_the_probe_to_the_command_and_nothing_without_it():
    from plm_highway.lane_ekf.latency_stream import LatencyEstimation, probe_rad_at
    from plm_highway.rollout.closed_loop import make_env

    commands = {}
    for probe_rad in (0.0, 0.02):
        env = make_env("test", "const:0.1", latency_estimation=LatencyEstimation(probe_rad=probe_rad))
        _, info = env.reset(seed=0)
        times_s, seen = [], []
        for _ in range(5):
            times_s.append(info["time_s"])
            _, _, _, _, info = env.step(np.array([0.1], dtype=np.float32))
            seen.append(info["steering_command"])
        env.close()
        commands[probe_rad] = (times_s, seen)
    times_s, plain = commands[0.0]
    assert plain == pytest.approx([0.1] * 5)
    expected = [0.1 + probe_rad_at(t, 0.02, (1.0, 0.6)) / 0.2 for t in times_s]  # the env's 0.2 rad at action 1
    assert commands[0.02][1] == pytest.approx(expected, abs=1e-6)


@pytest.mark.parametrize("field, value", [("probe_rad", -0.01), ("probe_rad", 0.5), ("probe_rad", True),
                                          ("probe_periods_s", ()), ("probe_periods_s", (0.1,)),
                                          ("probe_periods_s", [1.0])])
def test_a_bad_probe_is_refused_by_name(field, value):
    from plm_highway.lane_ekf.latency_stream import LatencyEstimation

    with pytest.raises(ValueError, match=f"LatencyEstimation.{field}="):
        LatencyEstimation(**{field: value})


# -- the report is its results file's ------------------------------------------------------------------------


def fabricated_results(never_locked: bool = False, true_worse: bool = False, none_locked: bool = False) -> dict:
    """A results dict from made-up run records (the shape drive_run writes), no driving.

    ``never_locked``: seed 1's estimate never locks (``lock_s`` None, as a run reads back from the cache);
    ``true_worse``: PLM-Net told the true latency steers worse than the unmitigated BM (no reduction to keep);
    ``none_locked``: no seed's estimate ever locks."""
    suite = LatencySuite(conditions=("ideal",), tracks=("test",), seeds=(0, 1), constants_s=(0.25,),
                         profiles=("frames:9-21:60@30",), mitigation_constants_s=(0.25,),
                         mitigation_profiles=("frames:9-21:60@30",), table3_seeds=())
    records = []
    rng = np.random.default_rng(0)
    for spec in plan(suite):
        spread = {"baseline": 0.1, "true": 0.3 if true_worse else 0.02}.get(spec.role, 0.02)
        steering = rng.normal(0, spread, 40).tolist()
        record = {"spec": spec.__dict__, "summary": {"lateral_offset_rms_m": float(rng.uniform(0.05, 0.3)),
                                                     "left_road": False}, "steering": steering}
        if spec.role in ("estimated", "baseline"):
            lock = {"first_estimable_s": 1.5, "lock_s": float(rng.uniform(1.0, 3.0)), "estimable_fraction": 0.6,
                    "wrong_when_estimable_fraction": 0.01, "within_after_first_fraction": 0.95,
                    "median_error_after_first_s": 0.01, "p90_error_after_first_s": 0.03, "within_fraction": 0.8,
                    "claims": 300, "wrong_claims": 3}
            if none_locked or (never_locked and spec.seed == 1):
                lock.update(first_estimable_s=None, lock_s=None, within_after_first_fraction=None,
                            median_error_after_first_s=None, p90_error_after_first_s=None, claims=0, wrong_claims=0)
            record["estimate"] = {"frame_s": 0.05, "lock": lock, "changing_fraction": 0.1,
                                  "quiet": {"quiet_ticks": 10, "estimable_when_quiet_fraction": 0.0,
                                            "wrong_when_quiet_fraction": 0.0}}
            baseline_lock = {**lock, "claims": 50 if spec.seed == 0 else 0, "wrong_claims": 10 if spec.seed == 0 else 0,
                             "first_estimable_s": 16.0 if spec.seed == 0 else None}
            record["baselines"] = {"scaled": {"frame_s": 0.05, "lock": baseline_lock, "changing_fraction": 0.0,
                                              "windows_accepted": 40},
                                   "published": {"frame_s": 0.05, "lock": {**lock, "claims": 0, "wrong_claims": 0},
                                                 "changing_fraction": 0.0, "windows_accepted": 0}}
            if not spec.latency.startswith("const:"):
                record["estimate"]["steps"] = {"changes": 3, "recovered_within_budget_fraction": 2 / 3,
                                               "median_recovery_s": 0.8, "never_recovered": 0, "within_fraction": 0.7}
                record["estimate"]["claim_steps"] = {"steps": 3, "steps_judged": 2, "stopped": 2, "answered": 1,
                                                     "handled": 1, "unanswered_not_estimable": 1}
        records.append((spec, record))
    synthetic = {"straight_without_steering": {"ticks": 100, "estimable_fraction": 0.0, "wrong_when_estimable": 0,
                                               "final_held_s": 0.175},
                 "straight_with_weave": {"ticks": 100, "estimable_fraction": 0.8, "wrong_when_estimable": 0,
                                         "final_held_s": 0.25}}
    return Results(suite, "plm-highway estimate latency (test)", records, [], synthetic).as_json()


def test_the_report_holds_the_numbers_of_its_results():
    results = json.loads(json.dumps(fabricated_results()))  # as read back from results.json
    report = render_markdown(results)
    assert report.startswith("# Perception latency estimated from the stream")
    met = sum(t["met"] for t in results["targets"])
    assert f"## Targets: {met} of {len(results['targets'])} met" in report
    for target in results["targets"]:
        assert f"| {target['target']} | {'met' if target['met'] else '**missed**'} | {target['detail']} |" in report
    for m in results["mitigation"]:
        row = next(line for line in report.splitlines()
                   if line.startswith(f"| {m['conditions']} | {m['track']} | ") and f"{m['offset_rms_ratio']:.2f}" in line)
        assert f"{100 * m['kept_reduction_fraction']:.0f}%" in row
    constant = next(e for e in results["estimation"] if e["role"] == "estimated" and e["setting"] == "const:0.25")
    assert f"{constant['locked_within_budget']} of {len(constant['seeds'])}" in report
    # claims pooled over the seeds' runs, the baseline's beside them on the same row
    assert constant["claims"] == 600 and constant["wrong_claims"] == 6
    row = next(line for line in report.splitlines() if line.startswith("| ideal | test | `const:0.25` | PLM-Net told"))
    assert "| 6 of 600 (1.0%) |" in row and "| 10 of 50 (20.0%) |" in row and row.endswith("| no claim |")
    assert "| 16.0 s (n=1, no interval), 1 of 2 runs claimed |" in row
    target = next(t for t in results["targets"] if t["target"].startswith("const:0.25, ideal, test, estimated:"))
    assert target["met"] and target["detail"] == "6 of 600 claims wrong (1.0%)"
    steps = next(t for t in results["targets"] if t["target"].startswith("frames:9-21:60@30, ideal, test, estimated:")
                 and "step" in t["target"])
    assert not steps["met"] and steps["detail"].startswith("2 of 4 steps handled")


def test_a_run_that_never_locked_and_a_mitigation_without_reduction_are_reported_not_crashed():
    from plm_highway.io import json_text

    results = json.loads(json_text(fabricated_results(never_locked=True, true_worse=True)))  # as results.json holds
    constant = next(e for e in results["estimation"] if e["role"] == "estimated" and e["setting"] == "const:0.25")
    assert constant["locked"] == 1 and constant["locked_within_budget"] <= 1
    report = render_markdown(results)
    for m in results["mitigation"]:
        assert m["kept_reduction_fraction"] is None  # NaN written as null: nothing to keep
        target = next(t for t in results["targets"] if t["target"].startswith(f"mitigation {m['setting']}"))
        assert not target["met"] and target["detail"].startswith("no reduction to keep")
        row = next(line for line in report.splitlines()
                   if line.startswith(f"| {m['conditions']} | {m['track']} | ") and f"{m['offset_rms_ratio']:.2f}" in line)
        assert " | - | " in row


def test_a_mitigation_whose_estimate_never_locked_is_not_counted_as_met():
    from plm_highway.io import json_text

    results = json.loads(json_text(fabricated_results(none_locked=True)))
    mitigation_targets = [t for t in results["targets"] if t["target"].startswith("mitigation ")]
    assert mitigation_targets and not any(t["met"] for t in mitigation_targets)
    assert all(t["detail"].startswith("not testable: the estimate was never claimed right") for t in mitigation_targets)
    # the same runs with locks are judged on their numbers
    locked = json.loads(json_text(fabricated_results()))
    assert any(t["met"] for t in locked["targets"] if t["target"].startswith("mitigation "))


def test_the_summarised_intervals_respect_their_quantity():
    from plm_highway.evaluation.latency_estimation import quantity_scale, summary_interval

    assert [quantity_scale(name) for name in ("lock_s", "mae_true", "offset_rms_m", "reduction_true_pct",
                                              "estimable_fraction")] == ["positive", "positive", "positive",
                                                                        "reduction", "linear"]
    # a time to lock: the log-scale interval, never below 0 (the symmetric one here would reach -1.0 s)
    lock = summary_interval("lock_s", [0.5, 2.0, 9.0, None, math.inf])  # runs that never locked are left out
    assert lock["n"] == 3 and lock["mean"] == pytest.approx(23 / 6)
    symmetric_low = lock["mean"] - 4.302653 * np.std([0.5, 2.0, 9.0], ddof=1) / np.sqrt(3)
    assert symmetric_low < 0 < lock["low"] < lock["mean"] < lock["high"]
    logs = np.log([0.5, 2.0, 9.0])
    half = 4.302653 * np.std(logs, ddof=1) / np.sqrt(3)
    assert lock["low"] == pytest.approx(np.exp(logs.mean() - half), rel=1e-6)
    # an MAE reduction: the ratios' interval, never above 100% (the symmetric one would reach past it)
    reduction = summary_interval("reduction_true_pct", [99.9, 90.0, 50.0])
    assert reduction["mean"] + 4.302653 * np.std([99.9, 90.0, 50.0], ddof=1) / np.sqrt(3) > 100
    assert reduction["low"] < reduction["mean"] < reduction["high"] < 100
    # a share: within [0, 1]
    share = summary_interval("within_fraction", [1.0, 0.9, 0.3])
    assert 0 <= share["low"] < share["mean"] < share["high"] == 1.0
    # fewer than 3 seeds: a mean, no interval; no defined value: nothing
    assert summary_interval("lock_s", [1.0, 3.0]) == {"mean": 2.0, "low": None, "high": None, "n": 2}
    assert summary_interval("lock_s", [None, math.nan]) is None


def test_the_report_prints_intervals_as_their_ends_and_says_when_the_seeds_are_too_few():
    two_seeds = json.loads(json.dumps(fabricated_results()))  # seeds 0 and 1
    report = render_markdown(two_seeds)
    assert "too few seeds for an interval" in report and "(n=2, no interval)" in report and "±" not in report
    three = fabricated_results()
    mitigation = three["mitigation"][0]
    mitigation["mae_true"] = {"mean": 0.02, "low": 0.015, "high": 0.03, "n": 3}
    row = next(line for line in render_markdown(three).splitlines()
               if line.startswith(f"| {mitigation['conditions']} | {mitigation['track']} | ")
               and f"{mitigation['offset_rms_ratio']:.2f}" in line)
    assert "| 0.0200 [0.0150, 0.0300] |" in row


def test_the_report_directory_is_rendered_from_its_results_file(tmp_path):
    results = fabricated_results()
    paths = write_latency_report(results, tmp_path / "report")
    assert [p.name for p in paths] == ["results.json", "report.md", "traces.png", "mitigation.png"]
    stored = json.loads((tmp_path / "report" / "results.json").read_text())
    assert (tmp_path / "report" / "report.md").read_text() == render_markdown(stored)


# -- sim2real: the perception delay of a recording ----------------------------------------------------------------


def lane_log(stream: dict) -> SimpleNamespace:
    """A run log's columns as write_lane_recording reads them, from a synthetic stream."""
    t = stream["time_s"]
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (stream["yaw_rate_radps"][1:] + stream["yaw_rate_radps"][:-1])
                                               * np.diff(t))])
    columns = {"stream_time_s": t, "stream_steer_rad": stream["steer_rad"], "stream_speed_mps": stream["speed_mps"],
               "stream_yaw_rate_radps": stream["yaw_rate_radps"], "stream_lane_offset_m": stream["lane_offset_m"],
               "stream_lane_heading_rad": stream["lane_heading_rad"], "x_m": stream["speed_mps"] * t,
               "y_m": np.zeros_like(t), "heading_rad": heading}
    return SimpleNamespace(name="synthetic", columns=columns)


def test_the_perception_delay_of_a_recording_with_a_lane_signal(tmp_path):
    from plm_highway.latency.lane_recording import write_lane_recording
    from plm_highway.sim2real.perception_delay import perception_delay, perception_delay_lines

    stream = synthetic_stream(StreamSpec(duration_s=15.0, latency=0.3, weave=Weave((0.02,), (0.6,), (0.0,)),
                                         drop_fraction=0.1), np.random.default_rng(2))
    path = tmp_path / "rec.csv"
    write_lane_recording(path, lane_log(stream))
    found = perception_delay(path)
    assert found["estimated"] and abs(found["latency_s"] - 0.3) <= 0.05
    lines = perception_delay_lines(found, {"transport_delay/delay_s": 0.1})
    assert lines[0] == "## Perception delay" and "transport_delay/delay_s 0.100 s" in "\n".join(lines)


def test_a_recording_without_a_lane_signal_says_so(tmp_path):
    from plm_highway.sim2real.perception_delay import perception_delay, perception_delay_lines

    path = tmp_path / "rec.csv"
    path.write_text("t,steer,speed,x,y,heading\n0,0,10,0,0,0\n0.1,0,10,1,0,0\n")
    found = perception_delay(path)
    assert not found["estimated"] and "no camera-derived lane signal" in found["reason"]
    assert "The diagnosis fitted no delay" in "\n".join(perception_delay_lines(found, {}))


def test_a_lane_recording_with_a_bad_value_is_refused_by_line(tmp_path):
    from plm_highway.errors import BadInput
    from plm_highway.latency.lane_recording import read_lane_recording

    path = tmp_path / "rec.csv"
    path.write_text("t,steer,speed,yaw_rate,lane_offset,lane_heading\n0,0,10,0,0.1,0\n0.1,0,ten,0,0.1,0\n")
    with pytest.raises(BadInput, match=re.escape("line 3, column 'speed'")):
        read_lane_recording(path)


@pytest.mark.slow
def test_the_sim2real_report_puts_the_perception_delay_beside_its_own(tmp_path):
    from plm_highway.latency.lane_recording import write_lane_recording

    stream = synthetic_stream(StreamSpec(duration_s=20.0, latency=0.25, weave=Weave((0.02, 0.01), (0.4, 0.9),
                                                                                    (0.0, 1.0))),
                              np.random.default_rng(6))
    path = tmp_path / "rec.csv"
    write_lane_recording(path, lane_log(stream))
    code = cli.main(["sim2real", "diagnose", str(path), "--report", str(tmp_path / "report"), "--json",
                     str(tmp_path / "diagnosis.json")])
    assert code == 0
    summary = (tmp_path / "report" / "summary.md").read_text()
    section = summary[summary.index("## Perception delay"):]
    assert re.search(r"The camera's lane signal is 0\.2[2-8]\d s", section), section
    found = json.loads((tmp_path / "diagnosis.json").read_text())["perception_delay"]
    assert found["estimated"] and abs(found["latency_s"] - 0.25) <= 0.05 and "diagnosis_delays_s" in found


@pytest.mark.slow
def test_the_sim2real_tie_in_finds_the_simulated_cameras_delay():
    """The report's tie-in: a paper-conditions run written as a recording with a lane signal and no capture
    timestamps; the estimator's delay lies within one frame of the camera's true latency, beside the diagnosis's."""
    from plm_highway.rollout.conditions import CONDITIONS
    from plm_highway.sim2real.perception_tie_in import SIMULATED_CONDITIONS, tie_in

    out = tie_in()
    assert set(out) == {"simulated"}  # no real recording given
    simulated = out["simulated"]
    frame_s = 1.0 / CONDITIONS[SIMULATED_CONDITIONS].policy_frequency_hz
    assert simulated["true_camera_latency_s"] == pytest.approx(0.2, abs=frame_s)
    found = simulated["perception_delay"]
    assert found["estimated"], found
    assert abs(found["latency_s"] - simulated["true_camera_latency_s"]) <= frame_s
    assert simulated["true_vehicle_delays"]["steering_time_constant_s"] == 0.1
    assert isinstance(simulated["diagnosis_delays_s"], dict) and simulated["verdict"]


# -- the run cache: reused only for the same contents -------------------------------------------------------------


def test_the_run_cache_is_keyed_by_the_checkpoints_contents_and_a_cached_run_edited_is_driven_again(
        tmp_path, tmp_path_factory):
    import shutil

    from tiny_models import other_tiny_checkpoints, tiny_checkpoints

    from plm_highway.evaluation.latency_estimation import drive_suite

    suite = LatencySuite(conditions=("ideal",), tracks=("test",), seeds=(0,), constants_s=(0.15,), profiles=(),
                         mitigation_constants_s=(), mitigation_profiles=(), probe_settings=(), duration_s=1.0,
                         table3_seeds=())
    ck, cache = tmp_path / "ck", tmp_path / "cache"
    shutil.copytree(tiny_checkpoints(tmp_path_factory), ck)

    def measured(checkpoints, cache_dir):
        driven = []
        records = drive_suite(suite, cache_dir, checkpoints=checkpoints, progress=False,
                              on_record=lambda spec, record: driven.append(spec))
        return [record["summary"] for _, record in records], len(driven)

    first, driven = measured(ck, cache)
    assert driven == len(first) >= 2
    assert measured(ck, cache) == (first, 0)  # same contents: all from the cache
    shutil.rmtree(ck)
    shutil.copytree(other_tiny_checkpoints(tmp_path_factory), ck)  # 'train --overwrite' into the same directory
    again, driven = measured(ck, cache)
    fresh, _ = measured(ck, None)
    assert driven == len(first) and again == fresh != first
    victim = sorted(cache.glob("*.json"))[0]
    data = json.loads(victim.read_text())
    data["summary"]["lateral_offset_rms_m"] = 7.5
    victim.write_text(json.dumps(data))
    edited, driven = measured(ck, cache)
    assert driven == 1 and edited == fresh


def test_the_run_cache_is_keyed_by_the_estimators_source(monkeypatch):
    import importlib

    import plm_highway.io.digests as digests
    import plm_highway.latency as latency_package
    from plm_highway.evaluation.latency_estimation import RunSpec, run_inputs

    spec = RunSpec("ideal", "test", 1, "const:0.25", "estimated", "recording")
    latency_estimation = importlib.import_module("plm_highway.evaluation.latency_estimation")
    assert run_inputs(spec, None)["code_sha256"] == digests.source_sha256(latency_package, latency_estimation)
    monkeypatch.setattr(latency_estimation, "source_sha256", lambda *modules: "another estimator")  # the name it calls
    assert run_inputs(spec, None)["code_sha256"] == "another estimator"


def test_a_source_digest_changes_with_any_source_file_of_the_package_and_nothing_else(tmp_path, monkeypatch):
    import importlib

    from plm_highway.io.digests import source_sha256

    package = tmp_path / "probe_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("X = 1\n")
    (package / "notes.txt").write_text("not code")
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("probe_pkg")
    first = source_sha256(module)
    assert source_sha256(module) == first
    (package / "notes.txt").write_text("still not code")
    assert source_sha256(module) == first
    (package / "a.py").write_text("X = 2\n")
    assert source_sha256(module) != first
    (package / "a.py").write_text("X = 1\n")
    assert source_sha256(module) == first
    (package / "b.py").write_text("")
    assert source_sha256(module) != first


def test_the_docs_claims_block_pools_tracks_and_seeds_from_the_results_file(tmp_path):
    from plm_highway.io import json_text
    from plm_highway.publish.renderers import LATENCY_ESTIMATION, latency_claims

    results = json.loads(json_text(fabricated_results()))
    (tmp_path / LATENCY_ESTIMATION).parent.mkdir(parents=True)
    (tmp_path / LATENCY_ESTIMATION).write_text(json_text(results), encoding="utf-8")
    table = latency_claims(tmp_path)
    # two seeds of 300 claims with 3 wrong each; the baseline's one claiming run, 10 of its 50 claims wrong
    assert "| ideal | PLM-Net told the estimate | `const:0.25` | 2 of 2 | 6 of 600 (1.0%) | - | 1 of 2 | 10 of 50 (20.0%) |" \
        in table
    # two seeds of 2 judged steps, 1 handled and 1 met with "not estimable" throughout each
    assert "| ideal | PLM-Net told the estimate | `frames:9-21:60@30` | 2 of 2 | 6 of 600 (1.0%) | 2 of 4 (2 unseen) |" \
        in table
