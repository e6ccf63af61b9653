"""`plm-highway population` end to end: training, driving, resuming, failures and the report."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import subprocess
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


def tiny_plan(pairs: int = 1, seeds=(0,), remedies=(), latency_source=None):
    recipe = with_overrides(recipe_named(None, "ideal"), **TINY)
    return make_plan(recipe, "ideal", pairs, settings=("const:0", "const:0.25"), sim_seeds=seeds, max_steps=TINY_STEPS,
                     remedies=remedies, latency_source=latency_source)


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
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed (pip install ray)")
@pytest.mark.skipif(os.environ.get("PLM_TEST_RAY_CLUSTER") != "1",
                    reason="a second Ray node on a loaded 2-core machine can hang ray.init for many minutes; "
                           "set PLM_TEST_RAY_CLUSTER=1 to run this two-node test")
def test_a_two_node_ray_cluster_at_an_address_trains_and_drives_what_is_missing(finished, tmp_path):
    """``--address`` against a cluster of two nodes (a head and a worker node, both on 127.0.0.1, one CPU each):
    the pair trained and driven there gives the in-process rows. Its two seeds are driven as two one-CPU tasks
    submitted together, so with one CPU per node both nodes run one."""
    import shutil

    from ray.cluster_utils import Cluster

    source, plan, _ = finished
    shutil.copytree(source / "work", tmp_path / "work")
    shutil.rmtree(tmp_path / "work" / "pairs" / "pair-01")
    for path in (tmp_path / "work" / "runs").glob("pair-01-*"):
        path.unlink()
    import ray

    cluster = Cluster(shutdown_at_exit=False)
    try:
        try:
            cluster.add_node(num_cpus=1, include_dashboard=False, node_ip_address="127.0.0.1")
            cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1")
            cluster.wait_for_nodes()
            ray.init(address=cluster.address, include_dashboard=False, log_to_driver=False)
            alive = len([n for n in ray.nodes() if n["Alive"]])
            ray.shutdown()
        # Ray's node start on a loaded machine can time out, and its SIGTERM handler exits the process: either is
        # reported as a skip, never as a pass.
        except (Exception, SystemExit) as exc:
            pytest.skip(f"a two-node Ray cluster did not start on this machine: {exc!r}")
        assert alive == 2
        try:
            run_population(plan, options(tmp_path, backend="ray", address=cluster.address))
        except ConnectionError as exc:
            pytest.skip(f"the two-node Ray cluster could not be reached: {exc}")
    finally:
        ray.shutdown()
        cluster.shutdown()
    assert json.loads((tmp_path / "work" / "pairs" / "pair-01" / "training.json").read_text())["ok"]
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


def test_an_existing_report_is_refused_before_any_work(tmp_path, capsys):
    from plm_highway.cli import main

    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "mine.txt").write_text("keep")
    code = main(["population", "--pairs", "1", "--out", str(tmp_path / "out"), "--work", str(tmp_path / "work")])
    stderr = capsys.readouterr().err
    assert code == 2
    assert "refusing to replace" in stderr and "Traceback" not in stderr
    assert not (tmp_path / "work").exists() and (tmp_path / "out" / "mine.txt").read_text() == "keep"


@pytest.mark.slow
def test_the_smoke_run_completes(tmp_path):
    """The smoke run docs/population.md shows, as written (two pairs of the paper recipe shrunk to 4 episodes and 100
    samples, 40 steps per run): every stage of the command, on the process pool, at toy size."""
    documented = (REPO / "docs" / "population.md").read_text()
    command = ("plm-highway population --pairs 2 --episodes 4 --max-samples 100 --epochs 1 --max-steps 40 --seeds 2 "
               "--out DIR")
    assert f"`{command}`" in documented
    result = subprocess.run([*command.split(), "--no-progress"], cwd=tmp_path, capture_output=True, text=True,
                            timeout=1800)
    assert result.returncode == 0, result.stderr[-3000:]
    rows = read_results(tmp_path / "DIR" / "results.csv")
    assert len(rows) == 2 * 2 * 12
    # The yardstick is each pair's own BM without latency: a BM trained on 100 samples may leave the road before
    # step 40, and then every run of that pair and seed is scored over the reference's span, never beyond 40.
    scored = {}
    for r in rows:
        scored.setdefault((r["pair"], r["seed"]), set()).add(r["steps_scored"])
    assert all(len(s) == 1 and 0 < next(iter(s)) <= 40 for s in scored.values()), scored
    assert all(r["steps_driven"] <= 40 for r in rows)
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


def _copy_report(source: Path, target: Path) -> None:
    """The report directory as a fresh clone has it: committed files only, no work directory beside it."""
    import shutil

    shutil.copytree(source, target)


@pytest.mark.slow
def test_a_committed_study_grows_in_a_fresh_clone_without_training_its_pairs_again(finished, tmp_path):
    source, plan, _ = finished
    _copy_report(source / "out", tmp_path / "out")
    committed = {p.name: p.read_bytes() for p in (tmp_path / "out" / "pairs").iterdir()}
    assert set(committed) == {"pair-00.json", "pair-01.json"}
    # --report-only: the report of the planned three from the two committed pairs, nothing trained
    shown = run_population(tiny_plan(pairs=3, seeds=(0, 1)), options(tmp_path, work=tmp_path / "w0",
                                                                      report_only=True))
    assert shown["pairs_planned"] == 3 and shown["pairs_driven"] == [0, 1]
    assert not (tmp_path / "w0").exists()  # no work directory is made for a report of committed pairs
    run_population(tiny_plan(pairs=3, seeds=(0, 1)), options(tmp_path))
    # only the new pair was trained and driven here; the committed records are untouched
    assert sorted(p.name for p in (tmp_path / "work" / "pairs").iterdir()) == ["pair-02"]
    assert {p.name: p.read_bytes() for p in (tmp_path / "out" / "pairs").iterdir() if p.name in committed} == committed
    grown = read_results(tmp_path / "out" / "results.csv")
    assert [r for r in grown if r["pair"] in (0, 1)] == read_results(source / "out" / "results.csv")
    assert {r["pair"] for r in grown} == {0, 1, 2}
    record = json.loads((tmp_path / "out" / "pairs" / "pair-02.json").read_text())
    stages = record["training"]["summary"]["stages"]
    assert set(stages) == {"collect", "bm_training", "tapm_training"}
    assert all(s["wall_s"] > 0 and s["cpu_s"] > 0 for s in stages.values())
    assert set(record["checkpoints"]) == {"bm/model.pt", "tapm/model.pt"}
    assert "## Trainings" in (tmp_path / "out" / "report.md").read_text()


@pytest.mark.slow
def test_a_committed_pair_edited_by_hand_is_refused_by_name(finished, tmp_path):
    from plm_highway.errors import BadInput

    source, plan, _ = finished
    _copy_report(source / "out", tmp_path / "out")
    path = tmp_path / "out" / "pairs" / "pair-01.json"
    record = json.loads(path.read_text())
    record["runs"][0]["offset_rms_m"] = 7.5
    path.write_text(json.dumps(record))
    with pytest.raises(BadInput, match="pair-01.json: its contents were changed"):
        run_population(plan, options(tmp_path))


@pytest.mark.slow
def test_a_committed_pair_of_another_population_is_refused_naming_what_differs(finished, tmp_path):
    from plm_highway.errors import BadInput

    source, _, _ = finished
    _copy_report(source / "out", tmp_path / "out")
    other = make_plan(with_overrides(recipe_named(None, "ideal"), **TINY), "ideal", 2,
                      settings=("const:0", "const:0.2"), sim_seeds=(0, 1), max_steps=TINY_STEPS)
    with pytest.raises(BadInput, match="pair-00.json: this pair was made for another population \\(settings differ"):
        run_population(other, options(tmp_path, overwrite=True))


@pytest.mark.slow
def test_a_committed_pair_retrained_for_a_new_remedy_must_reproduce_its_checkpoints(finished, tmp_path):
    """A fresh clone has no checkpoints: a remedy needs the pair's BM, so the pair is trained again and its files
    checked against the committed hashes; a pair whose training does not reproduce is refused, not mixed in."""
    from plm_highway.errors import BadInput
    from plm_highway.population import ledger

    source, _, _ = finished
    _copy_report(source / "out", tmp_path / "out")
    record = json.loads((tmp_path / "out" / "pairs" / "pair-00.json").read_text())
    record.pop("plm_highway_output"), record.pop("record_sha256")
    record["checkpoints"]["bm/model.pt"] = "0" * 64
    from plm_highway.population.report import POPULATION_REPORT

    ledger.write_record(tmp_path / "out", record, POPULATION_REPORT)
    with_remedy = tiny_plan(pairs=2, seeds=(0, 1), remedies=("onpolicy-tapm",))
    with pytest.raises(BadInput, match="pair-00: retrained .* differ from the committed ones \\(bm/model.pt\\)"):
        run_population(with_remedy, options(tmp_path))


@pytest.mark.slow
def test_restart_trains_every_pair_again_with_the_new_recipe(finished, tmp_path):
    import shutil

    source, plan, _ = finished
    shutil.copytree(source / "work", tmp_path / "work")
    _copy_report(source / "out", tmp_path / "out")
    longer = make_plan(with_overrides(recipe_named(None, "ideal"), **{**TINY, "epochs": 2}), "ideal", 1,
                       settings=("const:0", "const:0.25"), sim_seeds=(0,), max_steps=TINY_STEPS)
    from plm_highway.errors import BadInput

    with pytest.raises(BadInput):  # another recipe: refused without --restart
        run_population(longer, options(tmp_path))
    run_population(longer, options(tmp_path, restart=True))
    bm = json.loads((tmp_path / "work" / "pairs" / "pair-00" / "bm" / "model.json").read_text())
    assert bm["training"]["config"]["epochs"] == 2
    assert sorted(p.name for p in (tmp_path / "work" / "pairs").iterdir()) == ["pair-00"]
    assert sorted(p.name for p in (tmp_path / "out" / "pairs").iterdir()) == ["pair-00.json"]
    assert {r["pair"] for r in read_results(tmp_path / "out" / "results.csv")} == {0}
    assert json.loads((tmp_path / "work" / "plan.json").read_text())["recipe"]["bm"]["epochs"] == 2


@pytest.mark.slow
def test_the_prepared_gpu_run_completes_at_toy_size_on_the_cpu(tmp_path):
    """.ci/gpu-run as docs/devices.md documents it, shrunk (PLM_GPU_RUN_TOY) and on the CPU: the CUDA tests' step,
    the models bench and a population whose pairs are committed as records, each step's wall time on record."""

    env = {**os.environ, "PLM_GPU_RUN_TOY": "1", "PLM_GPU_RUN_DEVICE": "cpu", "PLM_GPU_RUN_WORKERS": "1"}
    out = tmp_path / "gpu-run"
    result = subprocess.run([str(REPO / ".ci" / "gpu-run"), str(out)], env=env, capture_output=True, text=True,
                            timeout=1200)
    assert result.returncode == 0, result.stderr[-3000:] + result.stdout[-3000:]
    walls = dict(line.split() for line in (out / "wall_s.txt").read_text().splitlines())
    assert list(walls) == ["cuda-tests", "bench-models", "population"]
    assert sorted(p.name for p in (out / "population" / "pairs").iterdir()) == ["pair-00.json", "pair-01.json"]
    assert json.loads((out / "bench-models.json").read_text())
    assert "`.ci/gpu-run OUT`" in (REPO / "docs" / "devices.md").read_text()
    again = subprocess.run([str(REPO / ".ci" / "gpu-run"), str(out)], env=env, capture_output=True, text=True)
    assert again.returncode == 2 and "exists" in again.stderr


@pytest.mark.slow
def test_plm_net_told_the_estimated_latency_is_a_population_of_its_own(tmp_path):
    from plm_highway.errors import BadInput
    from plm_highway.population.ledger import made_from

    plain, estimated = tiny_plan(), tiny_plan(latency_source="estimated")
    # a plan with the conditions' own source reads and hashes as the committed ones were made
    assert "latency_source" not in plain.as_dict() and "latency_source" not in made_from(plain)
    assert estimated.as_dict()["latency_source"] == "estimated"
    assert made_from(estimated) == {**made_from(plain), "latency_source": "estimated"}
    with pytest.raises(BadInput, match="--latency-source 'guessed'"):
        tiny_plan(latency_source="guessed")
    run_population(estimated, options(tmp_path))
    assert read_plan(tmp_path / "work") == estimated
    rows = read_results(tmp_path / "out" / "results.csv")
    assert len(rows) == 4 and all(r["steps_scored"] == TINY_STEPS for r in rows)
    assert "conditions (PLM-Net told the estimated latency)" in (tmp_path / "out" / "report.md").read_text()
    # the same pair under the conditions' own source is another population: its work directory is refused
    with pytest.raises(BadInput):
        run_population(plain, options(tmp_path, out=tmp_path / "plain"))
