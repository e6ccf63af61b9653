"""A resumed population equals a fresh one whatever input changed in between, or it refuses naming the input.

Training, driving and the posed-gain measurement are replaced by fakes whose outputs are a pure function of
exactly what the real ones read (recipe, training-track geometry and seeds; checkpoint bytes, test-track geometry,
latency, seed and step limit), so a result reused from stale inputs shows as a difference from a fresh run. Everything
else (plan, work directory, committed pair records, report) is the kit's own code, run as the command runs it, except
the drawing of the report's figures: they plot numbers population.json holds (compared here), and drawing them was most
of each run's time; tests/test_population.py draws them for real.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plm_highway.errors import BadInput, OutputRefused
from plm_highway.population.plan import make_plan
from plm_highway.population.recipe import recipe_named, with_overrides
from plm_highway.population.study import RunOptions, run_population
from plm_highway.rollout.closed_loop import RunLog

STEPS = 12


def _geometry(spec) -> str:
    data = asdict(spec)
    data.pop("source", None)
    return json.dumps(data, sort_keys=True, default=str)


def _digest(*parts) -> int:
    text = json.dumps(parts, sort_keys=True, default=str)
    return int(hashlib.sha256(text.encode("utf-8")).hexdigest()[:15], 16)


def _weights(checkpoints: str | Path) -> str:
    directory = Path(checkpoints)
    return hashlib.sha256((directory / "bm" / "model.pt").read_bytes()
                          + (directory / "tapm" / "model.pt").read_bytes()).hexdigest()


def fake_make_pair(recipe, seeds, work, device="cpu"):
    from plm_highway.road.track import resolve_track

    made_from = _digest(recipe.as_dict(), _geometry(resolve_track(recipe.track)), asdict(seeds))
    files = {model: {"model.pt": f"{model} weights {made_from}".encode(), "model.json": b"{}"}
             for model in ("bm", "tapm")}
    rng = np.random.default_rng(made_from)
    stage = {"wall_s": 1.0, "cpu_s": 1.0, "load_start": 0.0, "load_end": 0.0}
    summary = {"data_samples": 40, "threads": recipe.threads,
               "stages": {"collect": stage, "bm_training": stage, "tapm_training": stage},
               **{f"{model}_{key}": value for model in ("bm", "tapm")
                  for key, value in (("best_val_loss", float(rng.uniform(0.01, 0.1))), ("best_epoch", 1),
                                     ("epochs_run", recipe.bm.epochs), ("rows_train", 30), ("rows_val", 10))}}
    return files, summary


def fake_run_cells(cells, checkpoints=None, **_):
    weights = _weights(checkpoints)
    logs = []
    for cell in cells:
        latency = getattr(cell.latency, "spec", cell.latency)
        rng = np.random.default_rng(_digest(weights, _geometry(cell.track), latency, cell.seed, cell.max_steps,
                                            str(cell.policy), cell.latency_source, cell.env_config, cell.camera))
        steps = int(cell.max_steps)
        left_road = bool(rng.random() < 0.2)
        if left_road:
            steps = int(rng.integers(2, steps))
        t_s = np.arange(steps) * 0.1
        offset_m = np.cumsum(rng.normal(0.0, 0.05, steps))
        columns = {"t_s": t_s, "steering": rng.uniform(-0.3, 0.3, steps), "latency_s": np.zeros(steps),
                   "observation_age_s": np.zeros(steps), "x_m": t_s * 20.0, "y_m": offset_m,
                   "lateral_offset_m": offset_m, "heading_error_rad": rng.normal(0.0, 0.01, steps),
                   "arc_length_m": t_s * 20.0, "segment": np.array(["arc"] * steps)}
        logs.append(RunLog(cell.name, columns, left_road, steps / cell.max_steps))
    return logs


def fake_posed_gains(checkpoints, conditions_name, track, latencies_s, *args, **kwargs):
    from plm_highway.road.track import resolve_track

    rng = np.random.default_rng(_digest(_weights(checkpoints), conditions_name,
                                        _geometry(resolve_track(track)), list(latencies_s)))
    names = ["bm", "law", *(f"plm@{latency_s:g}" for latency_s in latencies_s)]
    return {name: {"offset_gain_per_m": float(rng.uniform(-0.3, 0.0)),
                   "heading_gain_per_rad": float(rng.uniform(-3.0, -1.0))} for name in names}


def fake_save_figures(plan, numbers, directory):
    names = ["errors.png", "reductions.png", "offset_rms.png"]
    for name in names:
        (directory / name).write_bytes(b"not drawn")
    return names


def fake_save_drift_figure(plan, drift, directory):
    (directory / "drift.png").write_bytes(b"not drawn")
    return "drift.png"


@pytest.fixture
def fakes(monkeypatch):
    from plm_highway.population import driving, report, study, training
    from plm_highway.rollout import cells

    monkeypatch.setattr(training, "_make_pair", fake_make_pair)
    for module in (cells, driving):  # the runner, and the name the study's driving imported from it
        monkeypatch.setattr(module, "run_cells", fake_run_cells)
    monkeypatch.setattr(study, "posed_gains", fake_posed_gains)
    monkeypatch.setattr(report, "save_figures", fake_save_figures)
    monkeypatch.setattr(report, "save_drift_figure", fake_save_drift_figure)


def track_text(radius_m: float) -> str:
    return json.dumps({"name": "toy", "lanes": 1, "lane_width_m": 4.0,
                       "segments": [{"type": "arc", "radius_m": radius_m, "angle_deg": 90, "direction": "left"},
                                    {"type": "straight", "length_m": 100}]})


def base_inputs(root: Path) -> dict:
    (root / "test.json").write_text(track_text(100.0))
    (root / "train.json").write_text(track_text(80.0))
    return {"pairs": 2, "epochs": 1, "settings": ("const:0", "const:0.25"), "seeds": (0, 1), "max_steps": STEPS,
            "conditions": "ideal"}


def plan_of(root: Path, inputs: dict):
    recipe = with_overrides(recipe_named(None, inputs["conditions"]), episodes=4, max_samples=40,
                            epochs=inputs["epochs"])
    recipe = replace(recipe, track=str(root / "train.json"))
    return make_plan(recipe, inputs["conditions"], inputs["pairs"], track=str(root / "test.json"),
                     settings=inputs["settings"], sim_seeds=inputs["seeds"], max_steps=inputs["max_steps"])


def run(plan, out: Path, work: Path, **options):
    return run_population(plan, RunOptions(work=work, out=out, workers=0, progress=False, **options))


def published(out: Path) -> dict:
    """What a fresh run and a resumed one must agree on: every result, not how long it took."""
    document = json.loads((out / "population.json").read_text(encoding="utf-8"))
    for volatile in ("command", "stages"):
        document.pop(volatile, None)
    for training in document["trainings"].values():
        training["summary"].pop("seconds", None)
    return {"results.csv": (out / "results.csv").read_text(encoding="utf-8"),
            "pairs.csv": (out / "pairs.csv").read_text(encoding="utf-8"),
            "population.json": document}


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text(encoding="utf-8"))
    change(data)
    path.write_text(json.dumps(data), encoding="utf-8")


def uncommitted(root: Path, change) -> None:
    """``change`` to the work directory, with pair 1's committed record gone (so the work is what resumes)."""
    (root / "out" / "pairs" / "pair-01.json").unlink()
    change(root / "work")


WORK_EDITS = {
    "work: a run's numbers": lambda work: edit_json(work / "runs" / "pair-01-seed-1.json",
                                                    lambda d: d["rows"][0].update(offset_rms_m=7.5)),
    "work: a run's traces": lambda work: shutil.copy(work / "runs" / "pair-01-seed-0.npz",
                                                     work / "runs" / "pair-01-seed-1.npz"),
    "work: a training's numbers": lambda work: edit_json(work / "pairs" / "pair-01" / "training.json",
                                                         lambda d: d["summary"].update(bm_best_val_loss=9.0)),
    "work: a checkpoint replaced": lambda work: shutil.copy(work / "pairs" / "pair-00" / "tapm" / "model.pt",
                                                            work / "pairs" / "pair-01" / "tapm" / "model.pt"),
    "work: posed gains edited": lambda work: edit_json(work / "pairs" / "pair-01" / "feedback.json",
                                                       lambda d: d["gains"]["bm"].update(offset_gain_per_m=3.0)),
    "work: a pair killed while driving": lambda work: (work / "runs" / "pair-01-seed-1.json").unlink(),
}


# Each edit changes one input between a finished run and the next one; ``names`` are the words a refusal must
# use to say which input changed (None: the next run must simply equal a fresh one).
EDITS = {
    "more pairs": (lambda root, inputs: inputs.update(pairs=3), None),
    "test track contents": (lambda root, inputs: (root / "test.json").write_text(track_text(60.0)), "track"),
    "training track contents": (lambda root, inputs: (root / "train.json").write_text(track_text(50.0)),
                                "train_track"),
    "recipe": (lambda root, inputs: inputs.update(epochs=2), "recipe"),
    "settings": (lambda root, inputs: inputs.update(settings=("const:0", "const:0.3")), "settings"),
    "simulator seeds": (lambda root, inputs: inputs.update(seeds=(0, 2)), "sim_seeds"),
    "step limit": (lambda root, inputs: inputs.update(max_steps=STEPS - 2), "max_steps"),
    "conditions": (lambda root, inputs: inputs.update(conditions="paper"), "conditions"),
}


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edit=st.sampled_from(sorted(EDITS)), new_out=st.booleans(), lose_work=st.booleans())
def test_resume_after_any_edit_equals_a_fresh_run_or_names_the_edit(fakes, tmp_path_factory, edit, new_out,
                                                                    lose_work):
    """``new_out``: the next run reports elsewhere but keeps the work directory (its checkpoints and runs);
    ``lose_work``: the next run has the committed records but no work directory (a fresh clone)."""
    root = tmp_path_factory.mktemp("population")
    inputs = base_inputs(root)
    run(plan_of(root, inputs), root / "out", root / "work")
    change, names = EDITS[edit]
    change(root, inputs)
    plan = plan_of(root, inputs)
    out = root / "out-2" if new_out else root / "out"
    if lose_work:
        shutil.rmtree(root / "work")
    fresh_root = tmp_path_factory.mktemp("fresh")
    run(plan, fresh_root / "out", fresh_root / "work")
    fresh = published(fresh_root / "out")
    try:
        run(plan, out, root / "work")
    except BadInput as refusal:
        assert names is not None, f"after '{edit}' the run was refused: {refusal}"
        assert names in str(refusal), f"after '{edit}' the refusal does not name it: {refusal}"
        run(plan, out, root / "work", restart=True)  # and --restart really starts afresh
    else:
        assert names is None or (new_out and lose_work), f"'{edit}' went unnoticed"
    assert published(out) == fresh, f"after '{edit}' the published results are not a fresh run's"


@pytest.mark.parametrize("edit", sorted(WORK_EDITS))
def test_every_kind_of_work_edit_is_made_again_as_a_fresh_run_makes_it(fakes, tmp_path, edit):
    inputs = base_inputs(tmp_path)
    plan = plan_of(tmp_path, inputs)
    run(plan, tmp_path / "out", tmp_path / "work")
    expected = published(tmp_path / "out")
    uncommitted(tmp_path, WORK_EDITS[edit])
    try:
        run(plan, tmp_path / "out", tmp_path / "work")
    except OutputRefused as refusal:  # a file the user changed is never replaced: named, and theirs to move
        assert "checkpoint" in edit and "model.pt (changed since plm-highway wrote it" in str(refusal)
        (tmp_path / "work" / "pairs" / "pair-01" / "tapm" / "model.pt").unlink()
        run(plan, tmp_path / "out", tmp_path / "work")
    assert published(tmp_path / "out") == expected, f"after '{edit}' the results are not a fresh run's"
    edited = sorted(path.name for path in (tmp_path / "work").rglob("*.edited*"))
    assert edited or "killed" in edit or "checkpoint" in edit, "an edited work file was neither used nor kept aside"


def test_an_edited_committed_record_is_refused_until_removed_and_then_made_again(fakes, tmp_path):
    inputs = base_inputs(tmp_path)
    plan = plan_of(tmp_path, inputs)
    run(plan, tmp_path / "out", tmp_path / "work")
    expected = published(tmp_path / "out")
    path = tmp_path / "out" / "pairs" / "pair-01.json"
    record = json.loads(path.read_text(encoding="utf-8"))
    record["runs"][0]["offset_rms_m"] = 7.5
    path.write_text(json.dumps(record), encoding="utf-8")
    with pytest.raises(BadInput, match="pair-01.json: its contents were changed"):
        run(plan, tmp_path / "out", tmp_path / "work")
    # --restart removes only what the kit wrote: a record edited by hand is the user's to remove
    with pytest.raises(BadInput, match="pair-01.json: its contents were changed.*remove it"):
        run(plan, tmp_path / "out", tmp_path / "work", restart=True)
    assert json.loads(path.read_text(encoding="utf-8"))["runs"][0]["offset_rms_m"] == 7.5
    path.unlink()
    run(plan, tmp_path / "out", tmp_path / "work")
    assert published(tmp_path / "out") == expected


def test_a_killed_pair_is_made_again_from_what_its_work_directory_holds(fakes, tmp_path):
    inputs = base_inputs(tmp_path)
    plan = plan_of(tmp_path, inputs)
    run(plan, tmp_path / "out", tmp_path / "work")
    expected = published(tmp_path / "out")
    # killed after pair 1 drove one seed: no record, one run file missing
    (tmp_path / "out" / "pairs" / "pair-01.json").unlink()
    for path in (tmp_path / "work" / "runs").glob("pair-01-seed-1*"):
        path.unlink()
    run(plan, tmp_path / "out", tmp_path / "work")
    assert published(tmp_path / "out") == expected
