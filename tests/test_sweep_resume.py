"""A resumed sweep equals a fresh one whatever input changed in between: cells are keyed by the content of
everything they were made from (track and trace files, checkpoint files, settings, kit version) and carry a
digest of their own content, so an edited input or an edited cell is run again, never reused."""

from __future__ import annotations

import json
import shutil

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tiny_models import other_tiny_checkpoints, tiny_checkpoints

from plm_highway.sweep import SweepGrid, run_sweep

STEPS = 6


def track_text(radius_m: float) -> str:
    """A track that turns at once, so its radius changes the first steps' steering."""
    return json.dumps({"name": "toy", "lanes": 1, "lane_width_m": 4.0,
                       "segments": [{"type": "arc", "radius_m": radius_m, "angle_deg": 90, "direction": "left"},
                                    {"type": "straight", "length_m": 100}]})


def trace_text(latency_s: float) -> str:
    return f"t,latency_s\n0,{latency_s}\n10,{latency_s}\n"


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    return tiny_checkpoints(tmp_path_factory), other_tiny_checkpoints(tmp_path_factory)


def toy_grid(root) -> SweepGrid:
    return SweepGrid(latencies=(f"trace:{root / 'trace.csv'}",), tracks=(str(root / "t.json"),), seeds=(0,),
                     policies=("plm",), max_steps=STEPS)


def table(out) -> str:
    return (out / "results.csv").read_text(encoding="utf-8")


def set_inputs(root, pairs, radius_m, latency_s, pair):
    (root / "t.json").write_text(track_text(radius_m))
    (root / "trace.csv").write_text(trace_text(latency_s))
    shutil.rmtree(root / "ck", ignore_errors=True)
    shutil.copytree(pairs[pair], root / "ck")  # what 'train ... --overwrite' into --checkpoints leaves


EDITS = st.one_of(
    st.tuples(st.just("track"), st.sampled_from([40.0, 60.0, 250.0])),
    st.tuples(st.just("trace"), st.sampled_from([0.0, 0.05, 0.3])),
    st.tuples(st.just("checkpoints"), st.just(1)),
    st.tuples(st.just("cell"), st.sampled_from([("lateral_offset_rms_m", 7.5), ("left_road", True),
                                                ("steps", 1), ("steering", [0.5] * STEPS)])),
)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edit=EDITS, which=st.integers(0, 10))
def test_resume_after_any_edit_equals_a_fresh_run(pairs, tmp_path_factory, edit, which):
    root = tmp_path_factory.mktemp("toy")
    set_inputs(root, pairs, 100.0, 0.15, 0)
    grid = toy_grid(root)
    first = run_sweep(grid, root / "out", workers=0, checkpoints=root / "ck", progress=False)
    assert first["ran"] == first["cells"] == 2  # PLM-Net, and the BM without latency it is compared with
    before = table(root / "out")

    what, value = edit
    if what == "track":
        set_inputs(root, pairs, value, 0.15, 0)
    elif what == "trace":
        set_inputs(root, pairs, 100.0, value, 0)
    elif what == "checkpoints":
        set_inputs(root, pairs, 100.0, 0.15, value)
    else:
        cells = sorted((root / "out" / "cells").glob("*.json"))
        victim = cells[which % len(cells)]
        data = json.loads(victim.read_text())
        data[value[0]] = value[1]
        victim.write_text(json.dumps(data))

    resumed = run_sweep(grid, root / "out", workers=0, checkpoints=root / "ck", progress=False)
    fresh = run_sweep(grid, root / "fresh", workers=0, checkpoints=root / "ck", progress=False)
    assert table(root / "out") == table(root / "fresh")
    assert resumed["rows"] == fresh["rows"] or json.dumps(resumed["rows"]) == json.dumps(fresh["rows"])
    assert resumed["ran"] >= 1  # something was run again: nothing made from the old input was reused
    if what != "cell" and table(root / "fresh") == before:
        pytest.fail(f"the edit {edit} did not change the table: it cannot tell a reused cell from a new one")


def test_one_relative_track_name_in_two_directories_is_two_tracks(tmp_path, monkeypatch):
    for name, radius in (("a", 50.0), ("b", 400.0)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "t.json").write_text(track_text(radius))
    def grid():
        return SweepGrid(latencies=("const:0.1",), tracks=("t.json",), seeds=(0,), policies=("expert",),
                         max_steps=STEPS)

    monkeypatch.chdir(tmp_path / "a")
    run_sweep(grid(), tmp_path / "out", workers=0, progress=False)
    before = table(tmp_path / "out")
    monkeypatch.chdir(tmp_path / "b")
    grid = grid()
    again = run_sweep(grid, tmp_path / "out", workers=0, progress=False)
    run_sweep(grid, tmp_path / "fresh", workers=0, progress=False)
    assert table(tmp_path / "fresh") != before  # the two tracks drive differently: a reused row would show
    assert again["ran"] == 2 and table(tmp_path / "out") == table(tmp_path / "fresh")


def test_an_edited_cell_is_kept_aside_and_named(tmp_path, capsys):
    grid = SweepGrid(latencies=("const:0.1",), seeds=(0,), policies=("expert",), max_steps=STEPS)
    run_sweep(grid, tmp_path / "out", workers=0, progress=False)
    victim = sorted((tmp_path / "out" / "cells").glob("*.json"))[0]
    data = json.loads(victim.read_text())
    data["lateral_offset_rms_m"] = 7.5
    victim.write_text(json.dumps(data))
    summary = run_sweep(grid, tmp_path / "out", workers=0, progress=False)
    assert summary["ran"] == 1 and all(row["lateral_offset_rms_m"] != 7.5 for row in summary["rows"])
    aside = victim.with_name(victim.name + ".edited")
    assert json.loads(aside.read_text())["lateral_offset_rms_m"] == 7.5  # the user's file, kept as it was
    assert f"{victim}: its content does not match" in capsys.readouterr().err


def test_other_grids_cells_are_counted_kept_and_pruned_only_when_asked(tmp_path):
    out = tmp_path / "out"
    first = SweepGrid(latencies=("const:0.1", "const:0.2"), seeds=(0,), policies=("expert",), max_steps=STEPS)
    second = SweepGrid(latencies=("const:0.1",), seeds=(0,), policies=("expert",), max_steps=STEPS)
    run_sweep(first, out, workers=0, progress=False)
    cells = out / "cells"
    (cells / "notes.json").write_text('{"mine": true}')  # not the kit's: never counted nor removed
    kept = run_sweep(second, out, workers=0, progress=False)
    assert (kept["ran"], kept["other_cells"], kept["pruned"]) == (0, 1, 0)  # 0.2 s (the reference is shared)
    assert len(list(cells.glob("*.json"))) == 4  # 0.1 s, 0.2 s, the reference, notes.json
    back = run_sweep(first, out, workers=0, progress=False)  # the first grid comes back: nothing runs again
    assert (back["ran"], back["other_cells"]) == (0, 0)
    pruned = run_sweep(second, out, workers=0, progress=False, prune=True)
    assert (pruned["ran"], pruned["other_cells"], pruned["pruned"]) == (0, 1, 1)
    assert sorted(p.name for p in cells.glob("*.json")) == sorted([*(f"{k}.json" for k in _keys(second)),
                                                                    "notes.json"])
    assert table(out) == table_of_fresh(second, tmp_path / "fresh")


def _keys(grid: SweepGrid) -> list[str]:
    inputs = grid.inputs()
    return [cell.key(grid.settings(cell, inputs)) for cell in grid.cells()]


def table_of_fresh(grid: SweepGrid, out) -> str:
    run_sweep(grid, out, workers=0, progress=False)
    return table(out)
