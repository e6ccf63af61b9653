"""``plm-highway evaluate``: the JSON (runs, steering, trajectory), the CSV logs, and bad input."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
from tiny_models import tiny_checkpoints

from plm_highway import cli
from plm_highway.evaluation import evaluate as evaluate_cli
from plm_highway.evaluation.trajectory import METRICS, PARTS, RESAMPLE_SPACING_M
from plm_highway.rollout.closed_loop import LOG_COLUMNS, RunLog

RUN_COLUMNS = ("t_s", "steering", "latency_s", "observation_age_s", "x_m", "y_m", "lateral_offset_m", "segment")


@pytest.fixture(scope="session")
def checkpoints(tmp_path_factory):
    return tiny_checkpoints(tmp_path_factory)


def read_csv(path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.slow
def test_plm_evaluation_writes_json_with_trajectory_and_csv_logs(checkpoints, tmp_path, capsys):
    run_dir = tmp_path / "eval"
    out = run_dir / "result.json"
    code = cli.main(["evaluate", "--policy", "plm", "--latency", "const:0.2", "--max-steps", "180",
                     "--checkpoints", str(checkpoints), "--out", str(run_dir)])
    assert code == 0
    result = json.loads(out.read_text())
    screen = capsys.readouterr().out  # a short summary; the full result is in the file
    assert f"full result: {run_dir}" in screen and '"trajectory"' not in screen
    for run, title in (("reference", "reference (no latency)"), ("baseline", "baseline (with latency)"),
                       ("mitigated", "mitigated (with latency)")):
        line = next(line for line in screen.splitlines() if line.startswith(title))
        assert f"{result['runs'][run]['lateral_offset_rms_m']:.3f} m" in line
        assert f"{result['runs'][run]['lateral_offset_max_m']:.3f} m" in line
        if run != "reference":
            assert line.endswith(f"{result['steering'][run]['mae']:.4f}")
    assert f"steering MAE {result['steering']['mae_reduction_pct']:.1f}%" in screen
    assert result["latency"] == "const:0.2" and result["policy"] == "plm"
    runs = ("reference", "baseline", "mitigated")
    assert list(result["runs"]) == list(runs)
    for run in runs:
        assert result["runs"][run]["steps"] <= 180
    steering = result["steering"]
    for key in ("mae_reduction_pct", "mse_reduction_pct", "rmse_reduction_pct"):
        assert isinstance(steering[key], float)
    assert steering["baseline"]["mae"] > 0  # the same BM, fed 0.2 s old frames, steers differently
    # trajectory: {part: {run: {metric: value}}}
    trajectory = result["trajectory"]
    assert list(trajectory) == list(PARTS)
    for part in PARTS:
        assert list(trajectory[part]) == list(runs)
        for run in runs:
            assert list(trajectory[part][run]) == list(METRICS)
    for run in runs:
        assert trajectory["full"][run]["frechet_dist"] >= 0
        assert trajectory["right"][run]["frechet_dist"] is None  # 180 steps (150 m) never reach a right turn
    assert trajectory["straight"]["reference"]["pcm"] is None  # the first straight heads east: PCM undefined
    assert result["trajectory_method"]["resample_spacing_m"] == RESAMPLE_SPACING_M
    # one CSV per run with every logged column, and the runs side by side
    for run in runs:
        rows = read_csv(run_dir / f"{run}.csv")
        assert tuple(rows[0]) == LOG_COLUMNS and set(RUN_COLUMNS) <= set(rows[0])
        assert len(rows) == result["runs"][run]["steps"]
        assert float(rows[0]["t_s"]) == 0.0 and rows[0]["segment"] == "straight"
    combined = read_csv(run_dir / "steps.csv")
    for run in runs:
        for column in RUN_COLUMNS[1:]:
            assert f"{run}_{column}" in combined[0]
    assert {row["baseline_latency_s"] for row in combined} == {"0.2"}
    mitigated_log = read_csv(run_dir / "mitigated.csv")
    assert [row["steering"] for row in mitigated_log] == [row["mitigated_steering"] for row in combined][:len(mitigated_log)]


def test_expert_evaluation_has_trajectory_for_both_runs(tmp_path):
    result, _ = evaluate_cli.evaluate("test", "const:0.25", "expert", max_steps=60)
    assert set(result["trajectory"]["full"]) == {"reference", "baseline"}
    assert "steering" not in result
    # the expert starts centred and drives straight: both stay within centimetres of the lane centre
    assert result["trajectory"]["full"]["reference"]["frechet_dist"] < 0.05


def _bad_track(tmp_path):
    path = tmp_path / "bad_track.json"
    path.write_text(json.dumps({"name": "bad", "segments": [{"type": "straight", "length_m": 100},
                                                            {"type": "arc", "radius_m": 3, "angle_deg": 90,
                                                             "direction": "left"}]}))
    return path


@pytest.mark.parametrize("arguments, message", [
    (["--latency", "const:abc"], "'const:abc'"),
    (["--latency", "wobble:0.2"], "expected one of"),
    (["--latency", "const:2"], "beyond the buffer"),
    (["--checkpoints", "{tmp}/no_such_dir"], "no such directory"),
    (["--track", "{bad_track}"], "segment 1: field 'radius_m'"),
    (["--track", "{tmp}/missing.json"], "neither a shipped track"),
    (["--max-steps", "0"], "--max-steps: 0 is outside the accepted range"),
])
def test_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, arguments, message):
    bad_track = _bad_track(tmp_path)
    out_dir = tmp_path / "out"
    arguments = [a.format(tmp=tmp_path, bad_track=bad_track) for a in arguments]
    code = cli.main(["evaluate", "--policy", "plm", *arguments, "--json", str(out_dir / "r.json")])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not out_dir.exists()


def test_checkpoint_dir_without_checkpoints_is_bad_input(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert cli.main(["evaluate", "--checkpoints", str(tmp_path / "empty"), "--json", str(tmp_path / "r.json")]) == 2
    assert "expected bm/model.pt and tapm/model.pt" in capsys.readouterr().err
    assert not (tmp_path / "r.json").exists()


def test_a_run_with_nan_positions_fails_cleanly_without_partial_output(tmp_path, capsys, monkeypatch):
    real_drive = evaluate_cli.drive

    def drive_with_nan(name, *args, **kwargs):
        log = real_drive(name, *args, **kwargs)
        if name == "baseline":
            columns = dict(log.columns)
            columns["x_m"] = columns["x_m"].copy()
            columns["x_m"][5] = np.nan
            log = RunLog(log.name, columns, log.left_road, log.completed_fraction, log.extras)
        return log

    monkeypatch.setattr(evaluate_cli, "drive", drive_with_nan)
    out = tmp_path / "out" / "r.json"
    assert cli.main(["evaluate", "--policy", "expert", "--max-steps", "40", "--json", str(out)]) == 2
    assert "path_xy: 1 NaN value at row [5]" in capsys.readouterr().err
    assert not out.parent.exists()


def test_the_installed_command_exits_2_on_a_bad_latency(tmp_path):
    completed = subprocess.run([sys.executable, "-m", "plm_highway", "evaluate", "--latency", "const:-1",
                                "--json", str(tmp_path / "r.json")], check=False, capture_output=True, text=True,
                               timeout=300)
    assert completed.returncode == 2
    assert "const:-1" in completed.stderr and "Traceback" not in completed.stderr
    assert not (tmp_path / "r.json").exists()


def test_any_track_file_works_and_a_closed_track_is_driven_for_one_lap(tmp_path):
    ring = tmp_path / "ring.json"
    ring.write_text(json.dumps({"name": "ring", "closed": True, "segments": [
        {"type": "straight", "length_m": 30}, {"type": "arc", "radius_m": 30, "angle_deg": 180, "direction": "left"},
        {"type": "straight", "length_m": 30}, {"type": "arc", "radius_m": 30, "angle_deg": 180, "direction": "left"}]}))
    out = tmp_path / "ring_result.json"
    assert cli.main(["evaluate", "--track", str(ring), "--policy", "expert", "--latency", "const:0.1",
                     "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    lap_m = 2 * 30 + 2 * np.pi * 30
    assert result["track"] == str(ring)
    assert result["runs"]["reference"]["steps"] == int(np.ceil(lap_m / 16.7 * 20)) + 1  # one lap, then stop
    assert result["trajectory_method"]["parts"]["left"]["segments"] == [1, 3]
    assert result["trajectory"]["right"]["reference"]["frechet_dist"] is None  # no right turn on this track
    assert 0 < result["trajectory"]["full"]["baseline"]["frechet_dist"] < 1.0


@pytest.mark.slow
def test_paper_conditions_drive_the_runs_as_reproduce_does(tmp_path, capsys):
    from plm_highway.road.track import load_track
    from plm_highway.rollout.cells import Cell, run_cells, runs_under
    from plm_highway.rollout.conditions import CONDITIONS
    from plm_highway.rollout.policies import make_policies, single_threaded_inference

    out = tmp_path / "paper"
    assert cli.main(["evaluate", "--conditions", "paper", "--latency", "const:0.15", "--seed", "2", "--max-steps", "20",
                     "--out", str(out)]) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["conditions"] == "paper" and "per_seed" not in result
    baseline = read_csv(out / "baseline.csv")
    assert float(baseline[1]["t_s"]) - float(baseline[0]["t_s"]) == pytest.approx(1 / 30)  # the paper's 30 Hz loop
    # The same runs as reproduce --conditions paper drives them (paper checkpoints, pipeline, seed-2 start).
    conditions = CONDITIONS["paper"]
    cells = [Cell("baseline", "bm", "const:0.15", 2), Cell("mitigated", "plm", "const:0.15", 2)]
    with single_threaded_inference():
        logs = run_cells(runs_under(cells, load_track("test"), conditions, make_policies(None, conditions), 20),
                         preset=conditions.checkpoint_preset)
    with single_threaded_inference():
        _, evaluated = evaluate_cli.evaluate("test", "const:0.15", "plm", seed=2, max_steps=20, conditions="paper")
    for log, name in zip(logs, ("baseline", "mitigated")):
        np.testing.assert_array_equal(evaluated[name].columns["steering"], log.columns["steering"])
        written = np.array([float(row["steering"]) for row in read_csv(out / f"{name}.csv")])
        np.testing.assert_allclose(written, log.columns["steering"], rtol=1e-5)  # the CSV's 6 significant digits


def test_the_ekf_drives_under_paper_conditions_with_their_plant(tmp_path):
    from plm_highway.lane_ekf.lateral_control import LoopTiming
    from plm_highway.rollout.conditions import CONDITIONS
    from plm_highway.rollout.policies import ekf_plant, make_policy

    plant = ekf_plant(CONDITIONS["paper"])
    assert plant["timing"] == LoopTiming(1 / 30, 0.1, 2) and plant["max_steering_rad"] == 0.4
    assert plant["camera"].height_px == 160 and plant["camera"].crop_rows_px == 140
    policy = make_policy("ekf", conditions=CONDITIONS["paper"], compensate_delay=False)
    assert policy.controller.timing == plant["timing"] and not policy.estimator.compensate_delay
    out = tmp_path / "e.json"
    assert cli.main(["evaluate", "--conditions", "paper", "--policy", "ekf", "--latency", "const:0.2",
                     "--max-steps", "12", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["conditions"] == "paper" and set(result["runs"]) == {"reference", "baseline", "mitigated"}
    assert all(run["steps"] == 12 for run in result["runs"].values())


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["bm-warp", "bm-smith"])
def test_a_plug_in_mitigation_is_evaluated_as_the_mitigated_run(policy, tmp_path, capsys):
    out = tmp_path / "m.json"
    assert cli.main(["evaluate", "--policy", policy, "--latency", "const:0.25", "--max-steps", "60",
                     "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["policy"] == policy and set(result["runs"]) == {"reference", "baseline", "mitigated"}
    screen = capsys.readouterr().out
    assert f"reduction by {policy} against the baseline" in screen
    # the mitigated run is not the BM's: it steered on other input
    assert result["steering"]["mitigated"]["mae"] != result["steering"]["baseline"]["mae"]


def test_the_ekf_named_in_a_run_takes_that_run_s_plant():
    from plm_highway.road.track import load_track
    from plm_highway.rollout.cells import Cell, _policy_for, runs_under
    from plm_highway.rollout.conditions import CONDITIONS
    from plm_highway.rollout.policies import ekf_plant

    conditions = CONDITIONS["paper"]
    [run] = runs_under([Cell("mitigated", "ekf", "const:0.2", 1)], load_track("test"), conditions, None, 5)
    policy = _policy_for(run, {})
    plant = ekf_plant(conditions)
    assert policy.controller.timing == plant["timing"]
    assert policy.config.camera == plant["camera"] and policy.config.max_steering_rad == plant["max_steering_rad"]
    assert policy.config.latency_source == conditions.latency_source  # told the frame's age as PLM-Net is
