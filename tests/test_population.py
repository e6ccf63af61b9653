"""`plm-highway population` end to end: training, driving, resuming, failures and the report."""

from __future__ import annotations

import csv
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from plm_highway.population import layout
from plm_highway.population.plan import make_plan
from plm_highway.population.recipe import recipe_named, with_overrides
from plm_highway.population.report import RESULT_COLUMNS, read_results, render_report
from plm_highway.population.study import RunOptions, read_plan, run_population

TINY = {"episodes": 4, "max_samples": 40, "epochs": 1}
TINY_STEPS = 12
REPO = Path(__file__).resolve().parent.parent


def tiny_plan(pairs: int = 1, seeds=(0,), remedies=()):
    recipe = with_overrides(recipe_named(None, "ideal"), **TINY)
    return make_plan(recipe, "ideal", pairs, settings=("const:0", "const:0.25"), sim_seeds=seeds, max_steps=TINY_STEPS,
                     remedies=remedies)


def options(tmp_path: Path, **changes) -> RunOptions:
    fields = {"work": tmp_path / "work", "out": tmp_path / "out", "workers": 0, "progress": False}
    return RunOptions(**{**fields, **changes})


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """One tiny population of two pairs, two simulator seeds, run to the end."""
    tmp_path = tmp_path_factory.mktemp("population")
    plan = tiny_plan(pairs=2, seeds=(0, 1))
    result = run_population(plan, options(tmp_path))
    return tmp_path, plan, result


@pytest.mark.slow
def test_every_planned_run_has_a_row_with_its_pairs_seeds(finished):
    tmp_path, plan, _ = finished
    rows = read_results(tmp_path / "out" / "results.csv")
    # per pair and seed: the reference, BM and PLM-Net at 0.25 s, PLM-Net at 0 s
    assert len(rows) == 2 * 2 * 4
    assert {(r["pair"], r["data_seed"], r["bm_seed"], r["tapm_seed"]) for r in rows} == {(0, 1, 0, 0), (1, 2, 1, 1)}
    roles = sorted((r["role"], r["setting"]) for r in rows if r["pair"] == 0 and r["seed"] == 1)
    assert roles == [("baseline", "const:0.25"), ("mitigated", "const:0"), ("mitigated", "const:0.25"),
                     ("reference", "const:0")]
    with open(tmp_path / "out" / "results.csv", newline="") as handle:
        assert tuple(next(csv.reader(handle))) == RESULT_COLUMNS
    for r in rows:
        assert r["steps_scored"] == TINY_STEPS
        if r["role"] == "reference":
            assert r["steering_mae_paper"] == 0.0 and r["frechet_m"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.slow
def test_the_plan_is_on_record_and_the_report_renders_from_the_published_files(finished):
    tmp_path, plan, _ = finished
    assert read_plan(tmp_path / "work") == plan
    document = json.loads((tmp_path / "out" / "population.json").read_text())
    figures = sorted(p.name for p in (tmp_path / "out").glob("*.png"))
    assert (tmp_path / "out" / "report.md").read_text() == render_report(document, ["errors.png", "reductions.png",
                                                                                   "offset_rms.png", "drift.png"])
    assert figures == ["drift.png", "errors.png", "offset_rms.png", "reductions.png"]
    gains = json.loads((tmp_path / "work" / "pairs" / "pair-00" / "feedback.json").read_text())["gains"]
    assert set(gains) == {"bm", "law", "plm@0.25"}
    assert "not the recipe's numbers" in (tmp_path / "out" / "report.md").read_text()


@pytest.mark.slow
def test_a_resumed_run_redrives_only_what_is_missing_and_gives_the_same_rows(finished, tmp_path):
    source, plan, _ = finished
    import shutil

    shutil.copytree(source / "work", tmp_path / "work")
    removed = layout.runs_path(tmp_path / "work", 1, 1)
    kept = layout.runs_path(tmp_path / "work", 0, 0)
    kept_before = kept.stat().st_mtime_ns
    removed.unlink()
    run_population(plan, options(tmp_path))
    assert removed.is_file() and kept.stat().st_mtime_ns == kept_before
    assert read_results(tmp_path / "out" / "results.csv") == read_results(source / "out" / "results.csv")


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed (pip install ray)")
def test_a_local_ray_head_trains_and_drives_what_is_missing_and_gives_the_in_process_rows(finished, tmp_path):
    import shutil

    source, plan, _ = finished
    shutil.copytree(source / "work", tmp_path / "work")
    shutil.rmtree(tmp_path / "work" / "pairs" / "pair-01")  # pair 1 trained again, now as a Ray task
    for path in (tmp_path / "work" / "runs").glob("pair-01-*"):
        path.unlink()
    try:
        run_population(plan, options(tmp_path, backend="ray", workers=2))
    except ConnectionError as exc:  # reported as a skip, never as a pass
        pytest.skip(f"Ray is installed but did not start on this machine: {exc}")
    assert json.loads((tmp_path / "work" / "pairs" / "pair-01" / "training.json").read_text())["ok"]
    assert {p.name for p in (tmp_path / "work" / "runs").glob("pair-01-*.json")} == {
        "pair-01-seed-0.json", "pair-01-seed-1.json"}
    assert read_results(tmp_path / "out" / "results.csv") == read_results(source / "out" / "results.csv")


@pytest.mark.slow
def test_a_work_directory_of_another_population_is_refused(finished, tmp_path):
    source, plan, _ = finished
    other = tiny_plan(pairs=2, seeds=(0, 2))
    from plm_highway.errors import BadInput

    with pytest.raises(BadInput, match="holds another population \\(sim_seeds differ\\)"):
        run_population(other, options(source, out=tmp_path / "other"))


def test_a_failed_training_is_reported_not_dropped(tmp_path, monkeypatch):
    from plm_highway.population import training

    def broken(recipe, seeds, work, device):
        raise RuntimeError("the optimiser diverged")

    monkeypatch.setattr(training, "_make_pair", broken)
    plan = tiny_plan(pairs=1)
    with pytest.raises(Exception, match="nothing to report"):
        run_population(plan, options(tmp_path))
    record = json.loads((tmp_path / "work" / "pairs" / "pair-00" / "training.json").read_text())
    assert record["ok"] is False and "the optimiser diverged" in record["error"]


def test_an_existing_report_is_refused_before_any_work(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "mine.txt").write_text("keep")
    result = subprocess.run([sys.executable, "-m", "plm_highway", "population", "--pairs", "1", "--out",
                             str(tmp_path / "out"), "--work", str(tmp_path / "work")], capture_output=True, text=True)
    assert result.returncode == 2
    assert "refusing to replace" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "work").exists() and (tmp_path / "out" / "mine.txt").read_text() == "keep"


@pytest.mark.slow
def test_the_smoke_run_completes(tmp_path):
    """The smoke run docs/population.md shows, as written (two pairs of the paper recipe shrunk, 100 steps per run)."""
    documented = (REPO / "docs" / "population.md").read_text()
    command = "plm-highway population --pairs 2 --max-samples 300 --epochs 1 --max-steps 100 --seeds 2 --out DIR"
    assert f"`{command}`" in documented
    result = subprocess.run([*command.split(), "--no-progress"], cwd=tmp_path, capture_output=True, text=True,
                            timeout=1800)
    assert result.returncode == 0, result.stderr[-3000:]
    rows = read_results(tmp_path / "DIR" / "results.csv")
    assert len(rows) == 2 * 2 * 12
    # The yardstick is each pair's own BM without latency: a BM trained on 300 samples may leave the road before
    # step 100, and then every run of that pair and seed is scored over the reference's span, never beyond 100.
    scored = {}
    for r in rows:
        scored.setdefault((r["pair"], r["seed"]), set()).add(r["steps_scored"])
    assert all(len(s) == 1 and 0 < next(iter(s)) <= 100 for s in scored.values()), scored
    assert all(r["steps_driven"] <= 100 for r in rows)
    assert "2 independently trained BM/PLM-Net pairs" in result.stdout


@pytest.mark.slow
def test_a_remedy_is_tried_on_the_same_pairs_and_compared_pair_by_pair(finished, tmp_path):
    import shutil

    source, plan, _ = finished
    shutil.copytree(source / "work", tmp_path / "work")
    base_runs = sorted(p.name for p in (tmp_path / "work" / "runs").iterdir())
    with_remedy = tiny_plan(pairs=2, seeds=(0, 1), remedies=("onpolicy-tapm",))
    result = run_population(with_remedy, options(tmp_path))
    # the base runs were kept, the remedy's were added
    runs = sorted(p.name for p in (tmp_path / "work" / "runs").iterdir())
    assert set(base_runs) < set(runs) and "pair-01-seed-1-onpolicy-tapm.json" in runs
    rows = read_results(tmp_path / "out" / "results.csv")
    remedy_rows = [r for r in rows if r["remedy"] == "onpolicy-tapm"]
    assert {(r["role"], r["setting"]) for r in remedy_rows} == {("mitigated", "const:0"), ("mitigated", "const:0.25")}
    assert len(remedy_rows) == 2 * 2 * 2
    comparison = result["remedies"]["onpolicy-tapm"]
    assert comparison["settings"]["const:0.25"]["pairs"] == 2
    assert comparison["decision"] in ("shipped", "not shipped")
    record = json.loads((tmp_path / "work" / "pairs" / "pair-00" / "remedy-onpolicy-tapm" / "training.json")
                        .read_text())
    assert record["ok"] and record["summary"]["rows_on_policy"] > 0
    assert "## Remedy `onpolicy-tapm`" in (tmp_path / "out" / "report.md").read_text()
