"""``plm-highway reproduce``: the paper's numbers as transcribed, the report and figures, bad input."""

from __future__ import annotations

import csv
import json

import pytest
from tiny_models import tiny_checkpoints

from plm_highway import cli
from plm_highway.evaluation import paper_results as paper
from plm_highway.evaluation import protocol, reproduce
from plm_highway.metrics.steering import reduction_pct

TABLE_NAMES = ["Table 3", "Table 4", "Table 5", "Table 6", "Table A1", "Table A2", "Table A3", "Table A4",
               "Table A5", "Table A6"]


@pytest.fixture(scope="session")
def checkpoints(tmp_path_factory):
    return tiny_checkpoints(tmp_path_factory)


# ---------------------------------------------------------------------------------------------
# the transcription, spot-checked by hand against the paper's text
# ---------------------------------------------------------------------------------------------


def test_steering_tables_as_printed():
    assert paper.steering("const:0.2", "baseline") == {"mae": 0.1915, "mse": 0.0716, "rmse": 0.2676}  # Table 3
    assert paper.steering("const:0.2", "mitigated") == {"mae": 0.0726, "mse": 0.0125, "rmse": 0.1119}
    assert paper.steering("steps:0.0-0.35:1.0", "baseline")["mae"] == 0.3336  # Table 5
    assert paper.steering("const:0.15", "mitigated") == {"mae": 0.053122, "mse": 0.00691402, "rmse": 0.0831506}  # A1
    assert paper.steering("const:0.25", "baseline")["mse"] == 0.18581  # A3: "0.3347270.185810.431057"
    assert paper.steering("const:0.3", "mitigated")["rmse"] == 0.10375  # A5: "0.07106740.01076410.10375"


def test_trajectory_rows_as_split_by_hand():
    # "1.192.1764658.150.3491253.210.034", the reference row of every table
    reference = (1.19, 2.176, 4658.15, 0.349, 1253.21, 0.034)
    for setting in paper.SETTINGS.values():
        assert setting["trajectory"]["full"]["reference"] == reference
    # "0.6741.571.8160.0581.8850.01" (Table 4, left turn, PLM-Net)
    assert paper.SETTINGS["const:0.2"]["trajectory"]["left"]["mitigated"] == (0.674, 1.5, 71.816, 0.05, 81.885, 0.01)
    # "0.7463.971285.6410.08169.8750.113" (Table A2, right turn, BM with latency)
    assert paper.SETTINGS["const:0.15"]["trajectory"]["right"]["baseline"] == (0.746, 3.971, 285.641, 0.08, 169.875,
                                                                                 0.113)
    # "8.07718.91725,958.22.097459.150.36" (Table A4, full track, BM with latency)
    assert paper.SETTINGS["const:0.25"]["trajectory"]["full"]["baseline"] == (8.077, 18.917, 25958.2, 2.09, 7459.15,
                                                                                0.36)
    # "1.2359.11321.130.2545.0150.482" (Table A6, right turn, BM with latency)
    assert paper.SETTINGS["const:0.3"]["trajectory"]["right"]["baseline"] == (1.235, 9.1, 1321.13, 0.2, 545.015, 0.482)
    # "21.4281.31912.0970.03249.840.014" (Table 6, straight, PLM-Net)
    assert paper.trajectory("steps:0.0-0.35:1.0", "straight", "mitigated") == dict(
        zip(paper.TRAJECTORY_METRICS, (21.428, 1.319, 12.097, 0.032, 49.84, 0.014)))
    assert paper.trajectory("const:0.1", "full", "baseline") is None


def test_the_only_targets_are_the_papers_own_mae_reductions():
    # Nothing but the paper's five stated reductions (Tables 3 and 5, A1, A3, A5) may be held as a target
    # (a bound such as "Frechet <= 1.5x the reference" is not the paper's and is not one).
    assert paper.TARGETS == {"mae_reduction_pct": {"const:0.15": 69.0, "const:0.2": 62.1, "const:0.25": 72.5,
                                                   "const:0.3": 68.6, "steps:0.0-0.35:1.0": 78.7}}


def test_transcription_agrees_with_the_percentages_stated_in_the_text():
    for setting, target in paper.TARGETS["mae_reduction_pct"].items():
        base, mit = paper.steering(setting, "baseline"), paper.steering(setting, "mitigated")
        assert round(reduction_pct(base["mae"], mit["mae"]), 1) == target, setting
    for setting in ("const:0.2", "steps:0.0-0.35:1.0"):
        stated = paper.SETTINGS[setting]["stated_in_text"]
        base, mit = paper.steering(setting, "baseline"), paper.steering(setting, "mitigated")
        for metric in ("mse", "rmse"):
            assert round(reduction_pct(base[metric], mit[metric]), 1) == stated[f"{metric}_reduction_pct"]
        full = paper.SETTINGS[setting]["trajectory"]["full"]
        for run in ("baseline", "mitigated"):  # "PCM ... increased by 238.7%", etc.
            increase = 100 * (full[run][0] / full["reference"][0] - 1)
            assert round(increase, 1) == stated["full_pcm_increase_pct"][run]
    frechet = paper.SETTINGS["steps:0.0-0.35:1.0"]["trajectory"]["full"]
    assert round(100 * (frechet["baseline"][1] / frechet["reference"][1] - 1), 1) == 254.9
    assert round(100 * (frechet["mitigated"][1] / frechet["reference"][1] - 1), 1) == 66.2


def test_the_protocol_says_how_intervals_are_made_and_when_there_is_none():
    from types import SimpleNamespace

    from plm_highway.evaluation.report import protocol_lines
    from plm_highway.metrics.intervals import MIN_INTERVAL_VALUES
    from plm_highway.rollout.conditions import CONDITIONS

    lines = protocol_lines(SimpleNamespace(seeds=[0, 1], conditions=CONDITIONS["ideal"]))
    text = next(line for line in lines if line.startswith("**Confidence intervals**"))
    assert f"fewer than {MIN_INTERVAL_VALUES} seeds there are too few seeds for an interval" in text
    assert "{" not in text and "never below 0" in text and "never above 100%" in text


def test_settings_labels_and_tags():
    assert protocol.split_settings(["const:0.2,steps:0.0-0.35:1.0", "const:0.2"]) == ["const:0.2", "steps:0.0-0.35:1.0"]
    assert protocol.paper_key("const:0.20") == "const:0.2" and protocol.paper_key("const:0.1") is None
    assert protocol.setting_tag("const:0.2") == "0.20s" and protocol.setting_tag("steps:0.0-0.35:1.0") == "time_varying"
    assert protocol.setting_label("const:0.1") == "0.10 s"


# ---------------------------------------------------------------------------------------------
# the whole command, on a short horizon with tiny models
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_reproduce_writes_report_tables_and_figures(checkpoints, tmp_path, capsys):
    out = tmp_path / "figures" / "reproduce"
    code = cli.main(["reproduce", "--out", str(out), "--checkpoints", str(checkpoints), "--max-steps", "40",
                     "--seeds", "2", "--sweep", "--sweep-max", "0.1", "--sweep-step", "0.1"])
    assert code == 0
    printed = capsys.readouterr()
    assert "report:" in printed.out and "reproduce" in printed.err  # the tqdm bar
    report = (out / "report.md").read_text()
    for name in TABLE_NAMES:
        assert f"### {name}:" in report, name
    for heading in ("## Targets", "## Generalisation", "### The `unseen` track", "## Beyond the paper", "## Methods"):
        assert heading in report
    # only the paper's own targets (one MAE reduction per setting), judged on its test track only
    assert report.count("| **met** |") + report.count("| **missed** |") == 5
    assert "Frechet <=" not in report.split("## Protocol")[0]  # the Protocol section says the invented ones are gone
    assert "Figure 9: steering over time" in report and "Figure 14: trajectories against the lane centre" in report
    for tag in ("0.15s", "0.20s", "0.25s", "0.30s", "time_varying"):
        for kind in ("steering", "trajectories", "comparison"):
            assert (out / f"{tag}_{kind}.png").stat().st_size > 10_000
            assert f"]({tag}_{kind}.png)" in report
    for kind in ("steering", "trajectories", "comparison"):
        assert (out / f"unseen_time_varying_{kind}.png").is_file()
    assert (out / "sweep.png").is_file()
    results = json.loads((out / "results.json").read_text())
    assert list(results["settings"]) == list(reproduce.DEFAULT_SETTINGS)
    assert list(results["generalisation"]) == ["unseen"]
    assert {row["policy"] for row in results["sweep"]["rows"]} == {"bm", "plm", "plm_bias-0.05", "plm_bias+0.05"}
    # the reference is one run, shared by every setting
    steps = {r["runs"]["reference"]["steps"] for s in results["settings"].values() for r in s["per_seed"]}
    assert steps == {40}
    assert results["seeds"] == [0, 1] and all(len(s["per_seed"]) == 2 for s in results["settings"].values())
    with open(out / "steering_tables.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    table3 = {(r["run"], r["metric"]): r for r in rows if r["track"] == "test" and r["setting"] == "const:0.2"}
    assert table3[("baseline", "mae")]["paper"] == "0.1915" and table3[("mitigated", "mae")]["paper"] == "0.0726"
    assert float(table3[("reduction_pct", "mae")]["paper"]) == pytest.approx(62.1, abs=0.05)
    ours = results["settings"]["const:0.2"]["steering"]
    assert float(table3[("reduction_pct", "mae")]["ours"]) == pytest.approx(ours["mae_reduction_pct"]["mean"], rel=1e-5)
    with open(out / "targets.csv", newline="") as handle:
        targets = list(csv.DictReader(handle))
    assert [t["setting"] for t in targets] == list(reproduce.DEFAULT_SETTINGS)
    assert all(t["target"].endswith("(paper)") and float(t["paper"]) > 60 for t in targets)
    with open(out / "trajectory_tables.csv", newline="") as handle:
        trajectory_rows = list(csv.DictReader(handle))
    assert len([r for r in trajectory_rows if r["track"] == "test"]) == 5 * 4 * 4 * 6  # settings x parts x rows x metrics
    assert list(tmp_path.joinpath("figures").iterdir()) == [out]  # no temporary directory left behind
    # PLM-Net in open loop along the reference runs: the four constant latencies (20 Hz: 3-6 steps), two seeds each
    open_loop = results["open_loop"]
    assert list(open_loop) == ["0.15", "0.2", "0.25", "0.3"]
    assert [e["lag_steps"] for e in open_loop.values()] == [3, 4, 5, 6]
    assert all(len(e["per_seed"]) == 2 and e["holding_mae"]["n"] == 2 for e in open_loop.values())
    section = report.split("### Open loop: PLM-Net along the reference run")[1].split("\n## ")[0]
    assert sum(line.startswith("| 0.") for line in section.splitlines()) == 4 and "reduction, closed loop (Summary)" in section
    assert all(line.startswith(("0.15 s:", "0.20 s:", "0.25 s:", "0.30 s:", "Where PLM-Net loses"))
               for line in (row[2:] for row in section.splitlines() if row.startswith("- ")))


def test_the_legacy_fifo_is_compared_with_exact_ages(checkpoints, tmp_path):
    out = tmp_path / "legacy"
    code = cli.main(["reproduce", "--out", str(out), "--checkpoints", str(checkpoints), "--max-steps", "60", "--seeds",
                     "3", "--settings", "const:0.2", "steps:0.1-0.3:0.5", "--generalise", "--injection", "legacy-fifo",
                     "--workers", "0", "--no-progress"])
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    detail = results["conditions_detail"]
    assert (detail["injection"], detail["latency_source"]) == ("legacy-fifo", "requested")
    comparison = results["injection_comparison"]
    assert (comparison["injection"], comparison["latency_source"]) == ("time", "measured")
    assert list(comparison["settings"]) == ["steps:0.1-0.3:0.5"]  # only the time-varying settings are compared
    legacy, exact = results["settings"]["steps:0.1-0.3:0.5"], comparison["settings"]["steps:0.1-0.3:0.5"]
    # The paired difference is legacy minus exact, seed by seed.
    pairs = list(zip(legacy["per_seed"], exact["per_seed"]))
    expected = sum(a["steering"]["baseline"]["mae"] - b["steering"]["baseline"]["mae"] for a, b in pairs) / len(pairs)
    assert comparison["legacy_minus_time"]["steps:0.1-0.3:0.5"]["baseline_mae"]["mean"] == pytest.approx(expected)
    assert legacy["per_seed"][0]["steering"] != exact["per_seed"][0]["steering"]
    report = (out / "report.md").read_text()
    section = report.split("## The legacy FIFO against exact ages")[1].split("\n## ")[0]
    rows = [line for line in section.splitlines() if line.startswith(("| steps:0.1-0.3:0.5", "| *"))]
    assert len(rows) == 3 and "`legacy-fifo`" in rows[0] and "0.20 s" in rows[0] and "`time`" in rows[1]
    assert "legacy - exact, paired" in rows[2]
    assert "**The paper's time-varying baseline was effectively a constant latency.**" in section


def test_under_the_legacy_fifo_the_bm_baseline_sees_a_constant_latency_and_plm_net_the_profile(checkpoints, tmp_path):
    out = tmp_path / "evaluation"
    code = cli.main(["evaluate", "--checkpoints", str(checkpoints), "--latency", "steps:0.1-0.3:0.5", "--max-steps",
                     "80", "--seed", "4", "--injection", "legacy-fifo", "--out", str(out)])
    assert code == 0
    with open(out / "baseline.csv", newline="") as handle:
        baseline = [float(row["latency_s"]) for row in csv.DictReader(handle)]
    with open(out / "mitigated.csv", newline="") as handle:
        mitigated = [float(row["latency_s"]) for row in csv.DictReader(handle)]
    assert set(baseline) == {0.2} and len(set(mitigated)) > 1  # 80 steps at 20 Hz: 8 draws every 0.5 s
    assert json.loads((out / "result.json").read_text())["injection"] == "legacy-fifo"


@pytest.mark.parametrize("arguments, message", [
    (["--settings", "const:0.2", "const:zero"], "'const:zero'"),
    (["--checkpoints", "{tmp}/nowhere"], "no such directory"),
    (["--track", "{bad_track}"], "field 'lanes'"),
    (["--generalise", "{tmp}/missing.json"], "neither a shipped track"),
    (["--max-steps", "-3"], "argument --max-steps: -3 is outside the accepted range"),
    (["--sweep", "--sweep-step", "0"], "argument --sweep-step: 0 is outside the accepted range"),
    (["--seeds", "0"], "--seeds 0: a count must lie in [1, 1000]"),
    (["--seeds", "1,x"], "expected a count"),
    (["--seeds", "3,3"], "a seed is repeated"),
    (["--conditions", "lab"], "invalid choice: 'lab'"),
    (["--injection", "udp"], "invalid choice: 'udp'"),
    (["--injection", "legacy-fifo", "--settings", "sine:0.2:0.1:2"], "use --injection time"),
    (["--conditions", "paper", "--settings", "frames:9-21:60@30", "const:2"], "beyond the buffer"),
])
def test_bad_input_exits_2_before_any_run(tmp_path, capsys, arguments, message, monkeypatch):
    bad_track = tmp_path / "bad.json"
    bad_track.write_text(json.dumps({"name": "bad", "lanes": 9, "segments": [{"type": "straight", "length_m": 50}]}))
    from plm_highway.rollout import cells

    monkeypatch.setattr(cells, "drive_cell", _no_drive)  # the serial path
    monkeypatch.setattr(reproduce, "run_cells", _no_drive)  # every run reproduce drives, the sweep's included
    out = tmp_path / "out"
    arguments = [a.format(tmp=tmp_path, bad_track=bad_track) for a in arguments]
    assert cli.main(["reproduce", "--out", str(out), *arguments]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def _no_drive(*args, **kwargs):
    raise AssertionError("bad input must be refused before any run starts")


def test_a_failing_run_leaves_previous_outputs_untouched(checkpoints, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.md").write_text("previous report\n")
    previous_results = json.dumps({"command": "plm-highway reproduce --out out"})
    (out / "results.json").write_text(previous_results)
    from plm_highway.rollout import closed_loop

    real_make_env = closed_loop.make_env
    calls = []

    def failing_make_env(*args, **kwargs):  # the loop starts each run's env with it
        calls.append(args)
        if len(calls) == 3:
            raise ValueError("latency spec 'const:0.2': simulated failure in the third run")
        return real_make_env(*args, **kwargs)

    monkeypatch.setattr(closed_loop, "make_env", failing_make_env)
    code = cli.main(["reproduce", "--out", str(out), "--checkpoints", str(checkpoints), "--max-steps", "20",
                     "--seeds", "1", "--settings", "const:0.2", "--generalise", "--no-progress", "--overwrite",
                     "--workers", "0"])
    assert code == 2
    assert "simulated failure" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    assert sorted(p.name for p in out.iterdir()) == ["report.md", "results.json"]
    assert (out / "report.md").read_text() == "previous report\n"
    assert (out / "results.json").read_text() == previous_results


@pytest.mark.slow
def test_reproduce_on_the_unseen_track(checkpoints, tmp_path):
    out = tmp_path / "unseen"
    assert cli.main(["reproduce", "--track", "unseen", "--out", str(out), "--checkpoints", str(checkpoints),
                     "--max-steps", "30", "--seeds", "2", "--settings", "const:0.2", "--no-progress"]) == 0
    report = (out / "report.md").read_text()
    assert report.startswith("# Reproducing PLM-Net on the `unseen` track")
    assert "on the `unseen` track they are shown for orientation only" in report
    assert "## Generalisation" not in report  # no extra tracks unless asked for
    assert "### Table 3:" in report and (out / "0.20s_comparison.png").is_file()
    assert reproduce.output_dir(None, "unseen", "unseen") == reproduce.DEFAULT_OUT / "unseen"


def test_a_trace_setting_under_time_injection_runs_and_is_not_compared_under_the_legacy_fifo(checkpoints, tmp_path):
    """The legacy FIFO's BM baseline is defined for steps: and frames: profiles; a trace: setting given with
    --injection time is driven under that injection, and only the profiles the FIFO can drive are compared."""
    trace = tmp_path / "x.csv"
    trace.write_text("t,latency_s\n0,0.1\n0.5,0.2\n10,0.2\n")
    out = tmp_path / "out"
    code = cli.main(["reproduce", "--out", str(out), "--checkpoints", str(checkpoints), "--max-steps", "20",
                     "--seeds", "1", "--settings", f"trace:{trace},steps:0.0-0.35:1.0", "--injection", "time",
                     "--no-progress", "--workers", "0"])
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    text = json.dumps(results)
    assert f"trace:{trace}" in text
    # the legacy FIFO could only have refused the trace setting: it was left out of the comparison, never run there
    assert cli.main(["reproduce", "--out", str(tmp_path / "legacy"), "--checkpoints", str(checkpoints),
                     "--max-steps", "20", "--seeds", "1", "--settings", f"trace:{trace}", "--injection",
                     "legacy-fifo", "--no-progress", "--workers", "0"]) == 2
