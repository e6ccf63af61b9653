"""``plm-highway population``: train K pairs with one recipe, drive each, judge them as a population.

The work directory (``--work``) holds everything a run makes and is what a resumed run continues from:

- ``plan.json``: the plan (:mod:`~plm_highway.population.plan`), written before anything is trained or driven;
- ``pairs/pair-NN/{bm,tapm}/`` and ``pairs/pair-NN/training.json``: each pair's checkpoints and how its training
  went (or why it failed);
- ``runs/pair-NN-seed-S.json`` (+ ``.npz`` traces): one pair's runs under one simulator seed.

Every file is written whole (staged, then renamed), so a killed run leaves finished pieces whole and the next run
with the same options does only what is missing. The report (``--out``) is rendered from the work directory's
results at the end, in one publication (:mod:`~plm_highway.population.report`).

Work is spread through the sweep backends (a local process pool, or Ray): pairs are trained first, then every
(pair, seed) is driven as one batched chunk. Workers compute and return bytes and rows; this process writes.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

from plm_highway.errors import BadInput
from plm_highway.io import JSON_MARKER_KEY, check_target, directory_kind, file_kind, json_text, write_json, write_output
from plm_highway.models.checkpoints import CHECKPOINT
from plm_highway.population.driving import DriveResult, DriveTask, drive_pair_seed
from plm_highway.population.layout import remedy_dir, runs_path
from plm_highway.population.plan import PopulationPlan, pair_name
from plm_highway.population.training import PairTraining, TrainTask, train_pair

POPULATION_WORK = directory_kind("population-work", "a plm-highway population work directory")
POPULATION_PLAN = file_kind("population-plan", "a population plan JSON file")
PAIR_TRAINING = file_kind("population-training", "a population pair's training record")
PAIR_RUNS = file_kind("population-runs", "a population pair's runs under one seed")
PAIR_FEEDBACK = file_kind("population-feedback", "a population pair's posed feedback gains")
PAIR_TRACES = file_kind("population-traces", "a population pair's run traces (npz)", None,
                        lambda path: path.suffix == ".npz")


@dataclass(frozen=True)
class RunOptions:
    """How a population runs (not what it measures: that is the plan)."""

    work: Path
    out: Path
    backend: str = "local"
    workers: int | None = None
    address: str | None = None
    batch_size: int = 16
    overwrite: bool = False  # replace an earlier report at ``out``
    restart: bool = False  # start the work directory afresh instead of resuming it
    progress: bool = True
    command: str = ""
    device: str = "cpu"  # training and driving: cpu, cuda or auto (resolved by each worker)


@dataclass
class WorkState:
    """What the work directory holds: trained pairs (or failures) and driven (pair, seed) chunks."""

    plan: PopulationPlan
    trainings: dict[int, dict] = field(default_factory=dict)
    runs: dict[tuple[int, int], list[dict]] = field(default_factory=dict)
    feedback: dict[int, dict] = field(default_factory=dict)  # posed gains per trained pair
    work: Path | None = None
    remedy_trainings: dict[tuple[str, int], dict] = field(default_factory=dict)  # (remedy, pair) -> record
    remedy_runs: dict[tuple[str, int, int], list[dict]] = field(default_factory=dict)  # (remedy, pair, seed) -> rows


def run_population(plan: PopulationPlan, options: RunOptions) -> dict:
    """Train, drive and report the population ``plan`` (resuming what ``options.work`` already holds)."""
    from plm_highway.population.report import POPULATION_REPORT, publish_report
    from plm_highway.rollout.backends import make_backend

    check_target(options.out, POPULATION_REPORT, overwrite=options.overwrite)
    work = open_work(options.work, plan, options.restart)
    state = read_state(work, plan)
    backend = make_backend(options.backend, options.workers, options.address)
    try:
        _train_missing(work, state, backend, options.progress, options.device)
        _drive_missing(work, state, backend, options)
        for remedy in plan.remedies:
            _train_remedy_missing(work, state, remedy, backend, options.progress, options.device)
            _drive_missing(work, state, backend, options, remedy)
    finally:
        backend.close()
    _measure_feedback_missing(work, state, options.progress)
    return publish_report(state, options)


def open_work(work: Path, plan: PopulationPlan, restart: bool = False) -> Path:
    """A new work directory with ``plan`` in it, or an earlier one holding the same plan (or a prefix of its pairs)
    to resume; ``restart`` replaces an earlier work directory instead."""
    work = Path(work)
    if work.is_dir() and POPULATION_WORK.recognises(work) and not restart:
        earlier = read_plan(work)
        _check_continues(work, earlier, plan)
        if earlier != plan:  # more pairs or remedies: on record before anything of theirs runs
            write_json(work / "plan.json", plan.as_dict(), POPULATION_PLAN, overwrite=True)
        return work
    check_target(work, POPULATION_WORK, overwrite=restart)
    with write_output(work, POPULATION_WORK, overwrite=restart) as staged:
        (staged / "pairs").mkdir()
        (staged / "runs").mkdir()
        (staged / "plan.json").write_text(json_text(plan.as_dict(), POPULATION_PLAN), encoding="utf-8")
    return work


def read_plan(work: Path) -> PopulationPlan:
    return PopulationPlan.from_dict(_read_json(work / "plan.json", POPULATION_PLAN))


def _check_continues(work: Path, earlier: PopulationPlan, plan: PopulationPlan) -> None:
    differs = [name for name in ("recipe", "conditions", "track", "settings", "sim_seeds", "max_steps")
               if getattr(earlier, name) != getattr(plan, name)]
    if plan.pairs[:len(earlier.pairs)] != earlier.pairs:
        differs.append("pairs")
    if differs:
        raise BadInput(f"--work {str(work)!r} holds another population ({', '.join(differs)} differ); give another "
                       "--work, or pass --restart to start it afresh")


def _read_json(path: Path, kind) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise BadInput(f"{path}: not a readable {kind.describe} ({exc})") from None
    if not isinstance(data, dict) or data.get(JSON_MARKER_KEY) != kind.name:
        raise BadInput(f"{path}: not {kind.describe}")
    return data


def read_state(work: Path, plan: PopulationPlan) -> WorkState:
    """What ``work`` already holds for ``plan``."""
    state = WorkState(plan, work=work)
    for seeds in plan.pairs:
        record = work / "pairs" / pair_name(seeds.pair) / "training.json"
        if record.is_file():
            state.trainings[seeds.pair] = _read_json(record, PAIR_TRAINING)
        feedback = work / "pairs" / pair_name(seeds.pair) / "feedback.json"
        if feedback.is_file():
            state.feedback[seeds.pair] = _read_json(feedback, PAIR_FEEDBACK)["gains"]
        for seed in plan.sim_seeds:
            path = runs_path(work, seeds.pair, seed)
            if path.is_file():
                state.runs[(seeds.pair, seed)] = _read_json(path, PAIR_RUNS)["rows"]
        for remedy in plan.remedies:
            record = remedy_dir(work, seeds.pair, remedy) / "training.json"
            if record.is_file():
                state.remedy_trainings[(remedy, seeds.pair)] = _read_json(record, PAIR_TRAINING)
            for seed in plan.sim_seeds:
                path = runs_path(work, seeds.pair, seed, remedy)
                if path.is_file():
                    state.remedy_runs[(remedy, seeds.pair, seed)] = _read_json(path, PAIR_RUNS)["rows"]
    return state





def _progress(total: int, done: int, desc: str, unit: str, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=done, desc=desc, unit=unit, file=sys.stderr, disable=not enabled)


def _train_missing(work: Path, state: WorkState, backend, progress: bool, device: str = "cpu") -> None:
    plan = state.plan
    tasks = [TrainTask(plan.recipe, seeds, device) for seeds in plan.pairs if seeds.pair not in state.trainings]
    bar = _progress(len(plan.pairs), len(plan.pairs) - len(tasks), "population: train", "pair", progress)
    try:
        for _, result in backend.map_unordered(train_pair, tasks):
            state.trainings[result.pair] = _write_training(work, result)
            bar.update(1)
    finally:
        bar.close()


def _write_training(work: Path, result: PairTraining) -> dict:
    directory = work / "pairs" / pair_name(result.pair)
    directory.mkdir(parents=True, exist_ok=True)
    if result.ok:
        for model, files in result.files.items():
            with write_output(directory / model, CHECKPOINT, overwrite=True) as staged:
                for name, data in files.items():
                    (staged / name).write_bytes(data)
    record = {"pair": result.pair, "ok": result.ok, "summary": result.summary, "error": result.error}
    write_json(directory / "training.json", record, PAIR_TRAINING, overwrite=True)
    return record


def pair_files(work: Path, pair: int, remedy: str = "") -> dict[str, dict[str, bytes]]:
    """The checkpoint files a pair drives with: its BM and its TAPM, or the remedy's TAPM."""
    directory = work / "pairs" / pair_name(pair)
    tapm_dir = remedy_dir(work, pair, remedy) / "tapm" if remedy else directory / "tapm"
    return {model: {name: (model_dir / name).read_bytes() for name in ("model.pt", "model.json")}
            for model, model_dir in (("bm", directory / "bm"), ("tapm", tapm_dir))}


def _train_remedy_missing(work: Path, state: WorkState, remedy: str, backend, progress: bool,
                          device: str = "cpu") -> None:
    from plm_highway.population.remedies import RemedyTask, train_remedy

    plan = state.plan
    trained = [s for s in plan.pairs if state.trainings.get(s.pair, {}).get("ok")]
    tasks = [RemedyTask(remedy, plan.recipe, seeds, pair_files(work, seeds.pair), device) for seeds in trained
             if (remedy, seeds.pair) not in state.remedy_trainings]
    bar = _progress(len(trained), len(trained) - len(tasks), f"population: {remedy}", "pair", progress)
    try:
        for _, result in backend.map_unordered(train_remedy, tasks):
            directory = remedy_dir(work, result.pair, remedy)
            directory.mkdir(parents=True, exist_ok=True)
            if result.ok:
                with write_output(directory / "tapm", CHECKPOINT, overwrite=True) as staged:
                    for name, data in result.files["tapm"].items():
                        (staged / name).write_bytes(data)
            record = {"pair": result.pair, "remedy": remedy, "ok": result.ok, "summary": result.summary,
                      "error": result.error}
            write_json(directory / "training.json", record, PAIR_TRAINING, overwrite=True)
            state.remedy_trainings[(remedy, result.pair)] = record
            bar.update(1)
    finally:
        bar.close()


def _drive_missing(work: Path, state: WorkState, backend, options: RunOptions, remedy: str = "") -> None:
    plan = state.plan
    if remedy:
        trained = [s.pair for s in plan.pairs if state.remedy_trainings.get((remedy, s.pair), {}).get("ok")]
        done = {(pair, seed) for (r, pair, seed) in state.remedy_runs if r == remedy}
        runs_per_chunk = 1 + len(plan.latency_settings) + ("const:0" in plan.settings)
    else:
        trained = [s.pair for s in plan.pairs if state.trainings.get(s.pair, {}).get("ok")]
        done = set(state.runs)
        runs_per_chunk = 1 + 2 * len(plan.latency_settings) + ("const:0" in plan.settings)
    todo = [(pair, seed) for pair in trained for seed in plan.sim_seeds if (pair, seed) not in done]
    total = len(trained) * len(plan.sim_seeds) * runs_per_chunk
    bar = _progress(total, total - len(todo) * runs_per_chunk, f"population: drive{' ' + remedy if remedy else ''}",
                    "run", options.progress)
    files = {}
    tasks = []
    for pair, seed in todo:
        if pair not in files:
            files[pair] = pair_files(work, pair, remedy)
        tasks.append(DriveTask(plan, pair, seed, files[pair], batch_size=options.batch_size, device=options.device,
                               remedy=remedy))
    try:
        for _, result in backend.map_unordered(drive_pair_seed, tasks):
            _write_runs(work, result)
            if remedy:
                state.remedy_runs[(remedy, result.pair, result.seed)] = result.rows
            else:
                state.runs[(result.pair, result.seed)] = result.rows
            bar.update(len(result.rows))
    finally:
        bar.close()


def _write_runs(work: Path, result: DriveResult) -> None:
    path = runs_path(work, result.pair, result.seed, result.remedy)
    with write_output(path.with_suffix(".npz"), PAIR_TRACES, overwrite=True) as staged:
        staged.write_bytes(result.traces)
    write_json(path, {"pair": result.pair, "seed": result.seed, "remedy": result.remedy, "rows": result.rows},
               PAIR_RUNS, overwrite=True)


def _measure_feedback_missing(work: Path, state: WorkState, progress: bool) -> None:
    """Posed feedback gains (:func:`~plm_highway.population.drift.posed_gains`) of every trained pair that has none
    yet: cheap (a few camera frames per pair), so they run here, after the driving."""
    from plm_highway.evaluation.protocol import constant_latency_s
    from plm_highway.population.drift import posed_gains
    from plm_highway.rollout.policies import single_threaded_inference

    plan = state.plan
    latencies_s = [constant_latency_s(s) for s in plan.latency_settings if constant_latency_s(s)]
    todo = [s.pair for s in plan.pairs if state.trainings.get(s.pair, {}).get("ok") and s.pair not in state.feedback]
    bar = _progress(len(todo), 0, "population: feedback", "pair", progress and bool(todo))
    try:
        for pair in todo:
            with single_threaded_inference():
                gains = posed_gains(work / "pairs" / pair_name(pair), plan.conditions, plan.track, latencies_s)
            write_json(work / "pairs" / pair_name(pair) / "feedback.json", {"pair": pair, "gains": gains},
                       PAIR_FEEDBACK, overwrite=True)
            state.feedback[pair] = gains
            bar.update(1)
    finally:
        bar.close()

