"""plm-highway sweep: grids, resumable runs, one table, the same results on every backend."""

from __future__ import annotations

import csv
import importlib.util
import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from plm_highway.cli import main
from plm_highway.errors import BadInput, OutputRefused
from plm_highway.rollout.closed_loop import drive
from plm_highway.rollout.policies import make_policy
from plm_highway.rollout.seeds import parse_seeds
from plm_highway.sweep import SweepGrid, grid_from_mapping, load_grid, run_sweep
from plm_highway.sweep import runner as sweep_runner
from plm_highway.sweep.table import TABLE_COLUMNS, error_bars, mean_and_interval

EXPERT_GRID = dict(latencies=("const:0.1", "steps:0.0-0.35:1.0"), tracks=("test",), seeds=(0, 5),
                   policies=("expert",), max_steps=15)


def read_table(path):
    with open(path, newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


# -- grid ----------------------------------------------------------------------------------------


def test_grid_cells_are_the_product_plus_the_missing_references():
    grid = SweepGrid(latencies=("const:0", "const:0.2"), tracks=("test", "unseen"), seeds=(0, 1),
                     policies=("bm", "plm"), conditions={"a": {}, "b": {"camera": {"pitch_deg": 8}}})
    cells = grid.cells()
    assert grid.size() == 2 * 2 * 2 * 2 * 2
    # const:0 is in the grid, so the BM's references are already there: no extra cell
    assert len(cells) == grid.size() == len(set(cells))
    grid = SweepGrid(latencies=("const:0.2",), seeds=(0, 1), policies=("plm", "expert"))
    cells = grid.cells()
    references = cells[grid.size():]
    assert sorted((c.policy, c.latency, c.seed) for c in references) == \
        [("bm", "const:0", 0), ("bm", "const:0", 1), ("expert", "const:0", 0), ("expert", "const:0", 1)]


def test_cell_keys_are_unique_and_change_with_what_changes_the_run(tmp_path):
    grid = SweepGrid(latencies=("const:0.1", "const:0.2"), seeds=(0, 1, 2), policies=("expert",),
                     conditions={"a": {}, "b": {"env_config": {"speed_mps": 20}}})
    inputs = grid.inputs()
    keys = [cell.key(grid.settings(cell, inputs)) for cell in grid.cells()]
    assert len(set(keys)) == len(keys)
    cell = grid.cells()[0]
    changed = SweepGrid(latencies=grid.latencies, seeds=grid.seeds, policies=grid.policies,
                        conditions={"a": {"camera": {"pitch_deg": 9}}, "b": {}}, max_steps=10)
    assert cell.key(grid.settings(cell, inputs)) != cell.key(changed.settings(cell, inputs))
    # typed: a pitch of 9 and of 9.0 are written differently, so they are not taken for one setting
    typed = SweepGrid(latencies=grid.latencies, seeds=grid.seeds, policies=grid.policies,
                      conditions={"a": {"camera": {"pitch_deg": 9.0}}, "b": {}}, max_steps=10)
    assert cell.key(changed.settings(cell, inputs)) != cell.key(typed.settings(cell, inputs))
    for part, value in (("tracks", {"test": "0" * 64}), ("kit_version", "0.0.0"),
                        ("checkpoints", {"bm.pt": "1" * 64})):
        other = {**inputs, part: value}
        model_cell = type(cell)(cell.condition, cell.track, cell.latency, cell.seed, "bm")
        assert model_cell.key(grid.settings(model_cell, inputs)) != model_cell.key(grid.settings(model_cell, other))


def test_a_track_is_keyed_by_its_content_not_its_path(tmp_path):
    """Two files called t.json in two directories are two tracks; one file edited is another track."""
    from plm_highway.road.track import track_sha256

    shipped = json.loads((__import__("importlib.resources").resources.files("plm_highway.road") / "tracks" /
                          "test.json").read_text())
    for name in ("one", "two"):
        (tmp_path / name).mkdir()
    (tmp_path / "one" / "t.json").write_text(json.dumps(shipped))
    (tmp_path / "two" / "t.json").write_text(json.dumps({**shipped, "name": "another"}))
    assert track_sha256(tmp_path / "one" / "t.json") != track_sha256(tmp_path / "two" / "t.json")
    assert track_sha256(tmp_path / "one" / "t.json") == track_sha256(str(tmp_path / "one" / "t.json"))


@given(st.integers(1, 50))
def test_a_seed_count_means_seeds_0_to_n_minus_1(n):
    assert parse_seeds(n) == list(range(n)) == parse_seeds(str(n))
    assert grid_from_mapping({"seeds": n}).seeds == tuple(range(n)) == grid_from_mapping({"seeds": str(n)}).seeds


def test_seed_lists_and_bad_seeds():
    assert grid_from_mapping({"seeds": "0,3,7"}).seeds == (0, 3, 7)
    assert grid_from_mapping({"seeds": [4, 2]}).seeds == (4, 2)
    assert grid_from_mapping({"seeds": 10_000, "latencies": ["const:0"], "policies": ["bm"]}).seeds == tuple(range(10_000))
    for bad in ("0", "-1", "x", "1,,2", 10**6, [1, 1], [2**32]):
        with pytest.raises(BadInput, match="sweep grid: seeds"):
            grid_from_mapping({"seeds": bad})


@pytest.mark.parametrize("data, message", [
    ({"policies": ["pid"]}, "policy 'pid'"),
    ({"latencies": ["const:abc"]}, "latency 'const:abc'"),
    ({"tracks": ["nowhere"]}, "track 'nowhere'"),
    ({"latencies": []}, "'latencies' is empty"),
    ({"seeds": [1, 1]}, "seeds \\[1, 1\\]: a seed is repeated"),
    ({"max_steps": 0}, "max_steps 0"),
    ({"conditions": {"x": {"wheels": 3}}}, "condition 'x'"),
    ({"latency": ["const:0"]}, "unknown keys \\['latency'\\]"),
    ({"tracks": "test"}, "'tracks' must be a list"),
    ({"seeds": 10_000, "latencies": [f"const:{i / 100}" for i in range(11)]}, "at most 100,000"),
])
def test_bad_grids_are_refused_naming_the_field(data, message):
    with pytest.raises(BadInput, match=message):
        grid_from_mapping(data)


def test_grid_files_yaml_and_json(tmp_path):
    (tmp_path / "g.yaml").write_text("conditions:\n  default: {}\n  pitch8: {camera: {pitch_deg: 8}}\n"
                                     "latencies: [const:0.1, steps:0.0-0.35:1.0]\nseeds: 3\npolicies: [bm]\n")
    grid = load_grid(tmp_path / "g.yaml")
    assert grid.seeds == (0, 1, 2) and grid.policies == ("bm",) and set(grid.conditions) == {"default", "pitch8"}
    (tmp_path / "g.json").write_text(json.dumps(grid.as_dict()))
    assert load_grid(tmp_path / "g.json").as_dict() == grid.as_dict()
    (tmp_path / "bad.yaml").write_text("latencies: [const:0.1\n")
    with pytest.raises(BadInput, match="not valid YAML"):
        load_grid(tmp_path / "bad.yaml")
    with pytest.raises(BadInput, match="no such file"):
        load_grid(tmp_path / "missing.json")


def test_the_figures_error_bars_are_hand_computed_log_scale_t_intervals():
    mean, low, high = mean_and_interval([1.0, 2.0, float("nan"), 3.0])  # a run without a reference has no error
    # logs 0, ln 2, ln 3: mean m, sd s; t(0.975, 2) = 4.302653; n = 3
    logs = np.log([1.0, 2.0, 3.0])
    half = 4.302653 * np.std(logs, ddof=1) / np.sqrt(3)
    assert mean == 2.0
    assert (low, high) == (pytest.approx(np.exp(logs.mean() - half), rel=1e-6),
                           pytest.approx(np.exp(logs.mean() + half), rel=1e-6))
    assert 0 < low < mean < high and high - mean > mean - low  # never below 0, longer upwards
    # a wide spread: the symmetric interval would reach below 0, this one does not
    spread = [0.01, 0.5, 1.2]
    assert np.mean(spread) - 4.302653 * np.std(spread, ddof=1) / np.sqrt(3) < 0 < mean_and_interval(spread)[1]
    for too_few_values in ([4.0], [4.0, 5.0]):  # fewer than 3 seeds: a point, no bar
        point, low, high = mean_and_interval(too_few_values)
        assert point == np.mean(too_few_values) and np.isnan(low) and np.isnan(high)
    assert all(np.isnan(mean_and_interval([float("nan")])))


def test_the_error_bars_are_the_intervals_ends_and_none_where_there_is_no_interval():
    bars = error_bars([2.0, 4.0, 5.0], [1.5, float("nan"), 5.5], [3.0, float("nan"), 6.0])
    assert bars.tolist() == [[0.5, 0.0, 0.0], [1.0, 0.0, 1.0]]


# -- running -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def expert_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "out"
    summary = run_sweep(SweepGrid(**EXPERT_GRID), out, workers=0, progress=False)
    return out, summary


def test_the_table_holds_every_cell_with_the_one_env_runs_figures(expert_sweep):
    out, summary = expert_sweep
    rows = read_table(out / "results.csv")
    assert list(rows[0]) == list(TABLE_COLUMNS)
    # 2 latencies x 2 seeds, plus the expert's reference without latency for each seed
    assert len(rows) == summary["cells"] == 6 and summary["ran"] == 6
    for row in rows:
        log = drive("x", make_policy("expert"), row["track"], row["latency"], int(row["seed"]), max_steps=15)
        assert int(row["steps"]) == log.steps == 15
        assert float(row["lateral_offset_rms_m"]) == pytest.approx(log.summary()["lateral_offset_rms_m"], rel=1e-5,
                                                                   abs=1e-9)
        assert float(row["mean_observation_age_s"]) == pytest.approx(np.mean(log.columns["observation_age_s"]),
                                                                     rel=1e-5, abs=1e-9)
    references = [row for row in rows if row["latency"] == "const:0"]
    assert len(references) == 2 and all(float(row["steering_mae"]) == 0 for row in references)
    assert (out / "figures" / "sweep-default-test.png").is_file()


def test_a_rerun_runs_nothing_and_a_larger_grid_only_the_new_cells(expert_sweep):
    out, first = expert_sweep
    again = run_sweep(SweepGrid(**EXPERT_GRID), out, workers=0, progress=False)
    assert (again["ran"], again["resumed"]) == (0, 6)
    assert again["rows"] == first["rows"] or all(
        {k: v for k, v in a.items() if k != "steering_mae"} == {k: v for k, v in b.items() if k != "steering_mae"}
        for a, b in zip(again["rows"], first["rows"]))
    larger = run_sweep(SweepGrid(**{**EXPERT_GRID, "seeds": (0, 5, 9)}), out, workers=0, progress=False)
    assert (larger["ran"], larger["resumed"]) == (3, 6)
    assert len(read_table(out / "results.csv")) == 9


def test_an_interrupted_sweep_keeps_whole_cells_and_resumes(tmp_path, monkeypatch):
    out = tmp_path / "out"
    real_run_chunk = sweep_runner.run_chunk
    calls = []

    def failing_second_chunk(job):
        calls.append(job)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_run_chunk(job)

    monkeypatch.setattr(sweep_runner, "run_chunk", failing_second_chunk)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(SweepGrid(**EXPERT_GRID), out, workers=0, batch_size=2, progress=False)
    kept = sorted(p.name for p in (out / "cells").iterdir())
    assert len(kept) == 2 and not (out / "results.csv").exists()
    assert all(json.loads((out / "cells" / name).read_text())["steps"] == 15 for name in kept)
    monkeypatch.setattr(sweep_runner, "run_chunk", real_run_chunk)
    summary = run_sweep(SweepGrid(**EXPERT_GRID), out, workers=0, batch_size=2, progress=False)
    assert (summary["ran"], summary["resumed"]) == (4, 2)


def test_a_directory_the_tool_did_not_write_is_refused_and_left_alone(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    with pytest.raises(OutputRefused):
        run_sweep(SweepGrid(**EXPERT_GRID), out, workers=0, progress=False)
    with pytest.raises(OutputRefused):
        run_sweep(SweepGrid(**EXPERT_GRID), out, workers=0, progress=False, overwrite=True)
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


def test_a_foreign_file_among_the_cells_is_refused(expert_sweep, tmp_path):
    out, _ = expert_sweep
    victim = sorted((out / "cells").iterdir())[0]
    original = victim.read_text()
    try:
        victim.write_text(json.dumps({"cell": "something else"}))
        with pytest.raises(BadInput, match="not the result of cell"):
            run_sweep(SweepGrid(**EXPERT_GRID), out, workers=0, progress=False)
    finally:
        victim.write_text(original)


@pytest.mark.slow
def test_the_local_pool_gives_the_in_process_results(expert_sweep, tmp_path):
    _, in_process = expert_sweep
    pooled = run_sweep(SweepGrid(**EXPERT_GRID), tmp_path / "pool", workers=2, batch_size=2, progress=False)
    assert pooled["rows"] == in_process["rows"]


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed (pip install ray)")
def test_a_local_ray_head_on_127_0_0_1_gives_the_in_process_results(expert_sweep, tmp_path):
    _, in_process = expert_sweep
    try:
        ray_run = run_sweep(SweepGrid(**EXPERT_GRID), tmp_path / "ray", workers=2, backend="ray", batch_size=2,
                            progress=False)
    except ConnectionError as exc:  # reported as a skip, never as a pass
        pytest.skip(f"Ray is installed but did not start on this machine: {exc}")
    assert ray_run["rows"] == in_process["rows"]


def test_the_command_line(tmp_path, capsys):
    out = tmp_path / "cli"
    code = main(["sweep", "--out", str(out), "--policy", "expert", "--latency", "const:0.05", "--seeds", "0,2",
                 "--max-steps", "5", "--workers", "0", "--no-progress"])
    assert code == 0
    assert "4 runs (4 run now, 0 kept from earlier)" in capsys.readouterr().out
    rows = read_table(out / "results.csv")
    assert sorted((r["latency"], r["seed"]) for r in rows) == [("const:0", "0"), ("const:0", "2"),
                                                               ("const:0.05", "0"), ("const:0.05", "2")]
    assert main(["sweep", "--out", str(tmp_path / "x"), "--seeds", "0,,1", "--workers", "0"]) == 2
    assert main(["sweep", "--out", str(tmp_path / "x"), "--address", "h:1", "--workers", "0"]) == 2
    assert not (tmp_path / "x").exists()
