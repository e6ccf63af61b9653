"""The ``plm-highway`` command line: routing, evaluate, collect, demo zigzag and bench env."""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from plm_highway.cli import ADAPTERS, build_parser
from plm_highway.data.dataset import read_dataset
from plm_highway.rollout.closed_loop import LOG_COLUMNS

SUMMARY_KEYS = {"left_road", "completed_fraction", "lateral_offset_rms_m", "lateral_offset_max_m", "steps"}


def plm(*args: str, cwd=None, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "MPLBACKEND": "Agg", "SDL_VIDEODRIVER": "offscreen"}
    return subprocess.run([sys.executable, "-m", "plm_highway", *args], capture_output=True, text=True,
                          timeout=timeout, check=False, cwd=cwd, env=env)


def read_csv(path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _command_words() -> list[tuple[str, ...]]:
    import importlib

    words = []
    for name in ADAPTERS:
        module = importlib.import_module(f"plm_highway.cli.{name}")
        prefix = (name,) if getattr(module, "GROUP_HELP", None) else ()
        words += [(*prefix, command.name) for command in module.COMMANDS]
    return words


def test_help_lists_every_command_and_group():
    result = plm("--help")
    assert result.returncode == 0, result.stderr
    for words in _command_words():
        assert words[0] in result.stdout
    no_args = plm()
    assert no_args.returncode == 0 and "commands:" in no_args.stdout


@pytest.mark.parametrize("group", ["demo", "train", "estimate", "bench", "sim2real", "lessons"])
def test_group_help_lists_its_commands(group):
    result = plm(group, "--help")
    assert result.returncode == 0, result.stderr
    commands = [words[1] for words in _command_words() if words[0] == group]
    assert commands and all(command in result.stdout for command in commands)
    bare = plm(group)  # a group without its command: its help, and a usage error
    assert bare.returncode == 2 and all(command in bare.stdout for command in commands)


def test_every_command_and_option_has_help_text():
    for words in _command_words():
        parser = build_parser(list(words))
        sub = parser
        for word in words:
            sub = next(a for a in sub._subparsers._group_actions).choices[word]
        for action in sub._actions:
            if action.dest != "help":
                assert action.help, f"plm-highway {' '.join(words)}: option {action.option_strings or action.dest} has no help"


def test_console_script_is_installed():
    script = shutil.which("plm-highway")
    if script is None:
        pytest.skip("plm-highway is not on PATH")
    result = subprocess.run([script, "--help"], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0 and "evaluate" in result.stdout


def test_unknown_command_exits_2():
    result = plm("frobnicate", "--now")
    assert result.returncode == 2
    assert "invalid choice" in result.stderr and "frobnicate" in result.stderr
    assert "Traceback" not in result.stderr


def test_command_help():
    result = plm("evaluate", "--help")
    assert result.returncode == 0
    assert "--latency" in result.stdout and "--max-steps" in result.stdout


def test_evaluate_expert_writes_json_and_csvs(tmp_path):
    run_dir = tmp_path / "results" / "run"
    out = run_dir / "result.json"
    result = plm("evaluate", "--policy", "expert", "--latency", "const:0.2", "--max-steps", "200",
                 "--out", str(run_dir), "--print-json")
    assert result.returncode == 0, result.stderr
    data = json.loads(out.read_text())
    assert json.loads(result.stdout) == data  # --print-json: the same result is printed
    assert data["latency"] == "const:0.2" and data["policy"] == "expert" and data["track"] == "test"
    assert set(data["runs"]) == {"reference", "baseline"}
    for run in data["runs"].values():
        assert SUMMARY_KEYS <= set(run)
        assert run["steps"] == 200 and run["left_road"] is False
        # 200 steps of 0.835 m on the 1145 m test track.
        assert run["completed_fraction"] == pytest.approx(200 * 16.7 * 0.05 / 1144.97, abs=0.005)
        assert 0 <= run["lateral_offset_rms_m"] <= run["lateral_offset_max_m"] < 1.0
    # 10 s include the first curve (from 120 m): the late run zig-zags more.
    assert data["runs"]["baseline"]["lateral_offset_rms_m"] > 1.5 * data["runs"]["reference"]["lateral_offset_rms_m"]
    names = {p.name for p in run_dir.iterdir()}
    assert names == {".plm-highway-output.json", "result.json", "baseline.csv", "reference.csv", "steps.csv"}
    assert [p.name for p in run_dir.parent.iterdir()] == ["run"]  # no temporary files left behind
    for name, latency in (("reference", 0.0), ("baseline", 0.2)):
        rows = read_csv(run_dir / f"{name}.csv")
        assert len(rows) == 200
        assert tuple(rows[0]) == LOG_COLUMNS
        assert all(float(row["latency_s"]) == latency for row in rows)
        ages = [float(row["observation_age_s"]) for row in rows]
        times = [float(row["t_s"]) for row in rows]
        assert ages == pytest.approx([min(latency, t) for t in times], abs=1e-6)
        assert float(rows[-1]["t_s"]) == pytest.approx(199 * 0.05)


def test_evaluate_bad_latency_exits_2_and_writes_nothing(tmp_path):
    out = tmp_path / "out.json"
    result = plm("evaluate", "--policy", "expert", "--latency", "const:abc", "--max-steps", "5", "--json", str(out))
    assert result.returncode == 2
    assert "const:abc" in result.stderr
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_collect_writes_a_readable_dataset(tmp_path):
    out = tmp_path / "ds"
    result = plm("collect", "--track", "test", "--episodes", "2", "--episode-seconds", "1", "--out", str(out))
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["samples"] == 40 and summary["episodes"] == 2
    data = read_dataset(out)
    assert len(data) == 40 and data.frames.shape == (40, 66, 200)
    assert data.manifest["counts"] == {"samples": 40, "episodes": 2}
    assert data.manifest["track"] == "test"
    assert data.manifest["command"].startswith("plm-highway collect --track test")
    assert sorted(set(data.steps["episode_id"].tolist())) == [0, 1]


def test_collect_with_a_broken_track_exits_2_naming_the_field(tmp_path):
    track = tmp_path / "broken.json"
    track.write_text(json.dumps({"name": "broken", "segments": [
        {"type": "straight", "length_m": 50},
        {"type": "arc", "radius_m": 5, "angle_deg": 90, "direction": "left"},
    ]}))
    out = tmp_path / "ds"
    result = plm("collect", "--track", str(track), "--episodes", "1", "--episode-seconds", "1", "--out", str(out))
    assert result.returncode == 2
    assert "radius_m" in result.stderr and "segment 1" in result.stderr
    assert "Traceback" not in result.stderr
    assert not out.exists()


def test_collect_with_a_missing_track_exits_2(tmp_path):
    result = plm("collect", "--track", str(tmp_path / "nope.json"), "--episodes", "1", "--out", str(tmp_path / "ds"))
    assert result.returncode == 2
    assert "nope.json" in result.stderr


def test_demo_zigzag_writes_a_png_and_prints_both_runs(tmp_path):
    out = tmp_path / "figs" / "z.png"
    result = plm("demo", "zigzag", "--policy", "expert", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out.stat().st_size > 10_000
    assert [p.name for p in out.parent.iterdir()] == ["z.png"]  # no temporary file left
    pattern = re.compile(r"^\s*(.+?): lateral offset max ([0-9.]+) m, RMS ([0-9.]+) m, left road: (\w+)$")
    runs = {m.group(1): (float(m.group(2)), float(m.group(3)), m.group(4))
            for m in map(pattern.match, result.stdout.splitlines()) if m}
    assert set(runs) == {"no latency", "latency const:0.25"}
    for max_m, rms_m, left in runs.values():
        assert 0 < rms_m <= max_m and left == "False"
    assert runs["latency const:0.25"][1] >= 2 * runs["no latency"][1]
    assert "policy: expert" in result.stdout


def test_bench_env_prints_every_side_and_the_ratios_of_one_run(tmp_path):
    out = tmp_path / "bench.json"
    result = plm("bench", "env", "--steps", "50", "--repeats", "1", "--json", str(out))
    assert result.returncode == 0, result.stderr
    data = json.loads(out.read_text())
    median = data["steps_per_s_median"]
    assert set(median) == {"lane_keeping_v0", "racetrack_large_v0", "ours", "ours_latency",
                           "limit_warp_ground_rows", "limit_warp_whole_frame"}
    assert all(value > 0 for value in median.values())
    ratios = data["ratios"]
    assert ratios["ours_over_lane_keeping_v0"] == pytest.approx(median["ours"] / median["lane_keeping_v0"])
    assert ratios["ours_latency_over_racetrack_large_v0"] == pytest.approx(
        median["ours_latency"] / median["racetrack_large_v0"])
    assert ratios["ours_over_limit_ground_rows"] == pytest.approx(median["ours"] / median["limit_warp_ground_rows"])
    assert data["config"]["steps"] == 50 and data["config"]["repeats"] == 1
    lines = result.stdout.splitlines()
    for label in ("highway-env lane-keeping-v0 + Grayscale 200x66", "highway-env racetrack-large-v0",
                  "plm_highway LaneKeeping-v0 + LatencyWrapper (const:0.2)", "limit: warpPerspective alone"):
        assert any(line.startswith(label) for line in lines), label
    headline = [line for line in lines if line.startswith("ours / lane-keeping-v0 (headline)")]
    assert len(headline) == 1
    assert f"{ratios['ours_over_lane_keeping_v0']:6.1f}x" in headline[0]
    assert "load average" in lines[0]


def test_bench_env_rejects_too_few_steps():
    result = plm("bench", "env", "--steps", "5")
    assert result.returncode == 2 and "--steps" in result.stderr
