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

import hashlib
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

from tqdm.auto import tqdm

from plm_highway.errors import BadInput
from plm_highway.evaluation.protocol import constant_latency_s
from plm_highway.io import (
    JSON_MARKER_KEY,
    check_target,
    directory_kind,
    file_kind,
    json_text,
    load_json,
    write_json,
    write_output,
)
from plm_highway.io.digests import DIGEST_KEY, content_digest, set_aside
from plm_highway.models.checkpoints import CHECKPOINT
from plm_highway.population.drift import posed_gains, run_bands
from plm_highway.population.driving import DriveTask, drive_pair, read_traces, split_seeds
from plm_highway.population.layout import read_traces as read_work_traces
from plm_highway.population.layout import remedy_dir, runs_path
from plm_highway.population.ledger import (
    LEDGER_DIR,
    differences,
    file_sha256,
    finite_or_nan,
    made_from,
    new_record,
    read_ledger,
    write_record,
)
from plm_highway.population.plan import PopulationPlan, pair_name
from plm_highway.population.remedies import RemedyTask, train_remedy
from plm_highway.population.report import POPULATION_REPORT, publish_report
from plm_highway.population.timing import StageTimes
from plm_highway.population.training import PairTraining, TrainTask, train_pair
from plm_highway.rollout.backends import make_backend
from plm_highway.rollout.policies import single_threaded_inference

POPULATION_PLAN = file_kind("population-plan", "a population plan JSON file")
PAIR_TRAINING = file_kind("population-training", "a population pair's training record")
PAIR_RUNS = file_kind("population-runs", "a population pair's runs under one seed")
PAIR_FEEDBACK = file_kind("population-feedback", "a population pair's posed feedback gains")
PAIR_TRACES = file_kind("population-traces", "a population pair's run traces (npz)", None,
                        lambda path: path.suffix == ".npz")
CHECKPOINT_FILE = file_kind("population-checkpoint-file", "a file of a checkpoint the population wrote", None,
                            lambda path: CHECKPOINT.recognises(path.parent))
# Files a run adds after the work directory was made: the kit's own, so --restart removes them with it.
POPULATION_WORK = directory_kind("population-work", "a plm-highway population work directory", owned=(
    ("pairs/*/training.json", PAIR_TRAINING), ("pairs/*/feedback.json", PAIR_FEEDBACK),
    ("pairs/*/model.*", CHECKPOINT_FILE), ("pairs/*/.plm-highway-output.json", CHECKPOINT_FILE),
    ("pairs/*/steering_balance.png", CHECKPOINT_FILE), ("runs/*.json", PAIR_RUNS), ("runs/*.npz", PAIR_TRACES)))


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
    report_only: bool = False  # render the report from the committed pairs; train and drive nothing
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
    bands: dict[tuple[int, int], dict] = field(default_factory=dict)  # (pair, seed) -> {run label: offset bands}
    stages: dict[int, dict] = field(default_factory=dict)  # pair -> driving/feedback/remedy times
    drive_cpu_s: dict[int, float] = field(default_factory=dict)  # pair -> the driving workers' CPU seconds


def run_population(plan: PopulationPlan, options: RunOptions) -> dict:
    """Train, drive and report the population ``plan``, pair by pair.

    Pairs already committed under ``options.out/pairs`` (:mod:`~plm_highway.population.ledger`) are taken as they
    are; every other pair is trained (or its checkpoints taken from ``options.work``), driven, measured and
    committed before the next one starts, and the report is rendered again from every committed pair at the end.
    """
    check_target(options.out, POPULATION_REPORT, overwrite=True)
    _check_same_study(options, plan)
    if options.restart:
        _restart(options)
    records = read_ledger(options.out, plan)
    if options.report_only:  # the committed pairs alone: no work directory is made or read
        work, state = Path(options.work), WorkState(plan, work=Path(options.work))
    else:
        work = open_work(options.work, plan, options.restart)
        state = read_state(work, plan)
    for record in records.values():
        adopt(state, record)
    todo = [seeds for seeds in plan.pairs if not record_complete(records.get(seeds.pair), plan)]
    if todo and not options.report_only:
        backend = make_backend(options.backend, options.workers, options.address)
        bar = _progress(len(plan.pairs), len(plan.pairs) - len(todo), "population: pairs", "pair", options.progress)
        try:
            for seeds in todo:
                record = records.get(seeds.pair) or new_record(plan, seeds.pair)
                _finish_pair(work, state, record, backend, options)
                write_record(options.out, record, POPULATION_REPORT)
                records[seeds.pair] = record
                bar.update(1)
        finally:
            bar.close()
            backend.close()
    return publish_report(state, options)


def _restart(options: RunOptions) -> None:
    """Drop the committed pair records of ``options.out`` (the work directory is started afresh by
    :func:`open_work`): a restart trains and drives every pair again."""
    if (Path(options.out) / LEDGER_DIR).is_dir():
        with write_output(options.out, POPULATION_REPORT, update=[LEDGER_DIR]):
            pass


def _check_same_study(options: RunOptions, plan: PopulationPlan) -> None:
    """A report of another population at ``options.out`` is replaced only with ``--overwrite`` (or ``--restart``);
    one of this population (more pairs or remedies aside) is this run's to render again. What the report was made
    from is compared as stored (track contents included), and what differs is named."""
    document = Path(options.out) / "population.json"
    if options.overwrite or options.restart or not document.is_file():
        return
    try:
        data = load_json(document, what="population report")
        stored = data.get("made_from") or made_from(PopulationPlan.from_dict(data["plan"]))
    except (OSError, ValueError, KeyError, TypeError, AttributeError, BadInput):
        stored = None
    differs = ["its plan"] if not isinstance(stored, dict) else differences(stored, plan)
    if differs:
        raise BadInput(f"--out {str(options.out)!r} holds the report of another population ({', '.join(differs)} "
                       "differ); pass --overwrite to replace it, or give another --out")


def record_complete(record: dict | None, plan: PopulationPlan) -> bool:
    """Whether a committed pair holds everything ``plan`` asks of it (a failed training is complete: reported)."""
    if record is None or "training" not in record:
        return False
    if not record["training"].get("ok"):
        return True
    seeds = set(plan.sim_seeds)
    if {row["seed"] for row in record.get("runs", [])} != seeds or "feedback" not in record:
        return False
    return all({row["seed"] for row in record.get("remedies", {}).get(remedy, {}).get("runs", [])} == seeds
               for remedy in plan.remedies)


def adopt(state: WorkState, record: dict) -> None:
    """Put a committed pair's results into ``state`` (what the report reads)."""
    pair = record["pair"]
    state.trainings[pair] = record["training"]
    for seed in {row["seed"] for row in record.get("runs", [])}:
        state.runs[(pair, seed)] = [row for row in record["runs"] if row["seed"] == seed]
    for seed_text, bands in record.get("bands", {}).items():
        state.bands[(pair, int(seed_text))] = {label: {key: finite_or_nan(value) for key, value in b.items()}
                                               for label, b in bands.items()}
    if "feedback" in record:
        state.feedback[pair] = record["feedback"]
    if "stages" in record:
        state.stages[pair] = record["stages"]
    for remedy, entry in record.get("remedies", {}).items():
        state.remedy_trainings[(remedy, pair)] = entry["training"]
        for seed in {row["seed"] for row in entry.get("runs", [])}:
            state.remedy_runs[(remedy, pair, seed)] = [row for row in entry["runs"] if row["seed"] == seed]


def _finish_pair(work: Path, state: WorkState, record: dict, backend, options: RunOptions) -> None:
    """Everything ``state.plan`` asks of one pair, written into ``record`` (and ``state``) as it is made."""
    plan, pair = state.plan, record["pair"]
    seeds = next(s for s in plan.pairs if s.pair == pair)
    if pair not in state.trainings or not _has_checkpoints(work, pair, state.trainings[pair]):
        training = _train(work, state, seeds, backend, options)
        if "checkpoints" in record and training.get("ok"):
            _check_same_checkpoints(work, pair, record["checkpoints"])
    training = state.trainings[pair]
    record["training"] = training
    if not training.get("ok"):
        return
    record["checkpoints"] = file_sha256(pair_files(work, pair))
    times = StageTimes()
    state.drive_cpu_s[pair] = 0.0
    with times.stage("driving"):
        driven = _drive_missing(work, state, backend, options, pairs=(pair,))
    if not driven:  # every run was on record (driven by an earlier, interrupted run): this run timed nothing
        del times.stages["driving"]
    with times.stage("feedback"):
        _measure_feedback_missing(work, state, options.progress, pairs=(pair,))
    record["runs"] = [row for seed in plan.sim_seeds for row in state.runs[(pair, seed)]]
    record["bands"] = {str(seed): state.bands[(pair, seed)] for seed in plan.sim_seeds}
    record["feedback"] = state.feedback[pair]
    remedies = record.setdefault("remedies", {})
    for remedy in plan.remedies:
        with times.stage(f"remedy {remedy}"):
            _train_remedy_missing(work, state, remedy, backend, options.progress, options.device, pairs=(pair,))
            remedy_training = state.remedy_trainings[(remedy, pair)]
            entry = {"training": remedy_training}
            if remedy_training.get("ok"):
                _drive_missing(work, state, backend, options, remedy, pairs=(pair,))
                entry["checkpoints"] = file_sha256(pair_files(work, pair, remedy))
                entry["runs"] = [row for seed in plan.sim_seeds
                                 for row in state.remedy_runs[(remedy, pair, seed)]]
            remedies[remedy] = entry
    if "driving" in times.stages:  # the work is the workers' (in-process: this process's, counted once)
        times.stages["driving"]["cpu_s"] = round(state.drive_cpu_s.get(pair, 0.0), 3)
    record["stages"] = {**record.get("stages", {}), **times.as_dict(),
                        "workers": options.workers, "backend": options.backend}
    state.stages[pair] = record["stages"]


def _has_checkpoints(work: Path, pair: int, training: dict) -> bool:
    return not training.get("ok") or _has_checkpoint_files(work, pair)  # a failed training has none to look for


def _has_checkpoint_files(work: Path, pair: int) -> bool:
    directory = work / "pairs" / pair_name(pair)
    return all((directory / model / name).is_file() for model in ("bm", "tapm") for name in ("model.pt", "model.json"))


def _check_same_checkpoints(work: Path, pair: int, committed: dict[str, str]) -> None:
    made = file_sha256(pair_files(work, pair))
    if made != committed:
        changed = sorted(name for name in committed if made.get(name) != committed[name])
        raise BadInput(f"{pair_name(pair)}: retrained to measure what its committed record lacks, its checkpoints "
                       f"differ from the committed ones ({', '.join(changed)}); this machine does not reproduce "
                       "that training bit for bit, so its new results would not belong to the committed pair. "
                       f"Put the pair's checkpoints under {work / 'pairs' / pair_name(pair)} or run where it was "
                       "trained")


def open_work(work: Path, plan: PopulationPlan, restart: bool = False) -> Path:
    """A new work directory with ``plan`` in it, or an earlier one holding the same plan (or a prefix of its pairs)
    to resume; ``restart`` replaces an earlier work directory instead."""
    work = Path(work)
    if work.is_dir() and POPULATION_WORK.recognises(work) and not restart:
        earlier = read_plan(work)
        _check_continues(work, earlier, plan)
        if earlier != plan:  # more pairs or remedies: on record before anything of theirs runs
            write_json(work / "plan.json", _plan_document(plan), POPULATION_PLAN, overwrite=True)
        return work
    check_target(work, POPULATION_WORK, overwrite=restart)
    with write_output(work, POPULATION_WORK, overwrite=restart) as staged:
        (staged / "pairs").mkdir()
        (staged / "runs").mkdir()
        (staged / "plan.json").write_text(json_text(_plan_document(plan), POPULATION_PLAN), encoding="utf-8")
    return work


def _plan_document(plan: PopulationPlan) -> dict:
    return {**plan.as_dict(), "made_from": made_from(plan)}


def read_plan(work: Path) -> PopulationPlan:
    return PopulationPlan.from_dict(_read_json(work / "plan.json", POPULATION_PLAN))


def _check_continues(work: Path, earlier: PopulationPlan, plan: PopulationPlan) -> None:
    stored = _read_json(work / "plan.json", POPULATION_PLAN).get("made_from")
    # What the work was made from as it was then (a track file edited since under the same path is seen).
    differs = ["its plan's origin"] if not isinstance(stored, dict) else differences(stored, plan)
    if plan.pairs[:len(earlier.pairs)] != earlier.pairs:
        differs.append("pairs")
    if differs:
        raise BadInput(f"--work {str(work)!r} holds another population ({', '.join(differs)} differ); give another "
                       "--work, or pass --restart to start it afresh")


def _read_json(path: Path, kind) -> dict:
    try:
        data = load_json(path, what=kind.describe)
    except (OSError, BadInput) as exc:
        raise BadInput(f"{path}: not a readable {kind.describe} ({exc})") from None
    if not isinstance(data, dict) or data.get(JSON_MARKER_KEY) != kind.name:
        raise BadInput(f"{path}: not {kind.describe}")
    del data[JSON_MARKER_KEY]  # the file's kind, not its content: a record reads the same from any path
    return data


def read_state(work: Path, plan: PopulationPlan) -> WorkState:
    """What ``work`` already holds for ``plan``: only what is still what the kit wrote and was made from the
    checkpoints now there (anything else is moved aside by :func:`_read_sealed` and made again)."""
    state = WorkState(plan, work=work)
    for seeds in plan.pairs:
        pair = seeds.pair
        checkpoints = file_sha256(pair_files(work, pair)) if _has_checkpoint_files(work, pair) else None
        training = _read_sealed(work / "pairs" / pair_name(pair) / "training.json", PAIR_TRAINING,
                                lambda record, made=checkpoints: _made_these_checkpoints(record, made))
        if training is None:
            continue
        training.pop("checkpoints", None)
        state.trainings[pair] = training
        if not training.get("ok"):
            continue
        feedback = _read_sealed(work / "pairs" / pair_name(pair) / "feedback.json", PAIR_FEEDBACK)
        if feedback is not None:
            state.feedback[pair] = feedback["gains"]
        for seed in plan.sim_seeds:
            runs = _read_runs(work, pair, seed, "", checkpoints)
            if runs is not None:
                state.runs[(pair, seed)] = runs
                state.bands[(pair, seed)] = run_bands(read_work_traces(work, pair, seed))
        for remedy in plan.remedies:
            record = _read_sealed(remedy_dir(work, pair, remedy) / "training.json", PAIR_TRAINING,
                                  lambda made, pair=pair, remedy=remedy: _made_remedy(work, pair, remedy, made))
            if record is None:
                continue
            record.pop("checkpoints", None)
            state.remedy_trainings[(remedy, pair)] = record
            if not record.get("ok"):
                continue
            remedy_checkpoints = file_sha256(pair_files(work, pair, remedy))
            for seed in plan.sim_seeds:
                runs = _read_runs(work, pair, seed, remedy, remedy_checkpoints)
                if runs is not None:
                    state.remedy_runs[(remedy, pair, seed)] = runs
    return state


def _made_these_checkpoints(training: dict, checkpoints: dict[str, str] | None) -> str | None:
    """Why a training record no longer describes the pair's checkpoint files (their hashes ``checkpoints``, None
    when they are missing); None: it does."""
    if not training.get("ok"):
        return None
    if checkpoints is None:
        return "its checkpoints are missing"
    if training.get("checkpoints") != checkpoints:
        return "the pair's checkpoint files are not the ones this training wrote"
    return None


def _made_remedy(work: Path, pair: int, remedy: str, training: dict) -> str | None:
    """Why a remedy's training record no longer describes its TAPM file (None: it does)."""
    if not training.get("ok"):
        return None
    tapm = remedy_dir(work, pair, remedy) / "tapm"
    if not all((tapm / name).is_file() for name in ("model.pt", "model.json")):
        return "its checkpoint is missing"
    if training.get("checkpoints") != file_sha256({"tapm": {"model.pt": (tapm / "model.pt").read_bytes()}}):
        return "the remedy's checkpoint file is not the one this training wrote"
    return None


def _read_runs(work: Path, pair: int, seed: int, remedy: str, checkpoints: dict[str, str]) -> list[dict] | None:
    """One chunk's rows if they and their traces are as written and were driven with ``checkpoints``."""
    path = runs_path(work, pair, seed, remedy)
    traces = path.with_suffix(".npz")

    def still_valid(record: dict) -> str | None:
        if not traces.is_file() or record.get("traces_sha256") != _sha256(traces.read_bytes()):
            return f"its traces {traces.name} are missing or not the ones it was written with"
        if record.get("checkpoints") != checkpoints:
            return "it was driven with other checkpoints than the pair's now"
        return None

    record = _read_sealed(path, PAIR_RUNS, still_valid)
    return None if record is None else record["rows"]


def _sealed(record: dict) -> dict:
    """``record`` as strict JSON reads it back, with the digest of its content (an edit is seen)."""
    record = json.loads(json_text(record))
    return {**record, DIGEST_KEY: content_digest(record)}


def _read_sealed(path: Path, kind, still_valid=None) -> dict | None:
    """A work file's record (without its digest), or None: absent, or moved aside to ``NAME.edited`` (kept,
    never overwritten) because its content no longer matches its digest or ``still_valid(record)`` says why it
    no longer holds; then what it held is made again."""
    if not path.is_file():
        return None
    record = _read_json(path, kind)
    why = None
    if record.get(DIGEST_KEY) != content_digest(record):
        why = "its content does not match the digest it was written with (edited since, or written by an older kit)"
    elif still_valid is not None:
        why = still_valid(record)
    if why is None:
        del record[DIGEST_KEY]
        return record
    set_aside(path, why, "made again")
    return None


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _progress(total: int, done: int, desc: str, unit: str, enabled: bool):
    return tqdm(total=total, initial=done, desc=desc, unit=unit, file=sys.stderr, disable=not enabled)


def _train(work: Path, state: WorkState, seeds, backend, options: RunOptions) -> dict:
    """Train one pair on ``backend`` (its record in ``state`` and the work directory); returns the record."""
    task = TrainTask(state.plan.recipe, seeds, options.device)
    for _, result in backend.map_unordered(train_pair, [task]):
        state.trainings[result.pair] = _write_training(work, result)
    return state.trainings[seeds.pair]


def _write_training(work: Path, result: PairTraining) -> dict:
    directory = work / "pairs" / pair_name(result.pair)
    directory.mkdir(parents=True, exist_ok=True)
    if result.ok:
        for model, files in result.files.items():
            with write_output(directory / model, CHECKPOINT, overwrite=True) as staged:
                for name, data in files.items():
                    (staged / name).write_bytes(data)
    record = {"pair": result.pair, "ok": result.ok, "summary": result.summary, "error": result.error}
    made = {"checkpoints": file_sha256(result.files)} if result.ok else {}
    write_json(directory / "training.json", _sealed({**record, **made}), PAIR_TRAINING, overwrite=True)
    return record


def pair_files(work: Path, pair: int, remedy: str = "") -> dict[str, dict[str, bytes]]:
    """The checkpoint files a pair drives with: its BM and its TAPM, or the remedy's TAPM."""
    directory = work / "pairs" / pair_name(pair)
    tapm_dir = remedy_dir(work, pair, remedy) / "tapm" if remedy else directory / "tapm"
    return {model: {name: (model_dir / name).read_bytes() for name in ("model.pt", "model.json")}
            for model, model_dir in (("bm", directory / "bm"), ("tapm", tapm_dir))}


def _train_remedy_missing(work: Path, state: WorkState, remedy: str, backend, progress: bool,
                          device: str = "cpu", pairs: tuple[int, ...] | None = None) -> None:
    plan = state.plan
    trained = [s for s in plan.pairs if state.trainings.get(s.pair, {}).get("ok") and (pairs is None or s.pair in pairs)]
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
            made = {"checkpoints": file_sha256(result.files)} if result.ok else {}
            write_json(directory / "training.json", _sealed({**record, **made}), PAIR_TRAINING, overwrite=True)
            state.remedy_trainings[(remedy, result.pair)] = record
            bar.update(1)
    finally:
        bar.close()


def _drive_missing(work: Path, state: WorkState, backend, options: RunOptions, remedy: str = "",
                   pairs: tuple[int, ...] | None = None) -> int:
    """Drive every run of ``pairs`` (all) not on record; how many seeds' chunks were driven."""
    plan = state.plan
    if remedy:
        trained = [s.pair for s in plan.pairs if state.remedy_trainings.get((remedy, s.pair), {}).get("ok")]
        done = {(pair, seed) for (r, pair, seed) in state.remedy_runs if r == remedy}
        runs_per_chunk = 1 + len(plan.latency_settings) + ("const:0" in plan.settings)
    else:
        trained = [s.pair for s in plan.pairs if state.trainings.get(s.pair, {}).get("ok")]
        done = set(state.runs)
        runs_per_chunk = 1 + 2 * len(plan.latency_settings) + ("const:0" in plan.settings)
    trained = [pair for pair in trained if pairs is None or pair in pairs]
    todo = [(pair, seed) for pair in trained for seed in plan.sim_seeds if (pair, seed) not in done]
    total = len(trained) * len(plan.sim_seeds) * runs_per_chunk
    bar = _progress(total, total - len(todo) * runs_per_chunk, f"population: drive{' ' + remedy if remedy else ''}",
                    "run", options.progress)
    files, hashes = {}, {}
    tasks = []
    chunks = max(1, options.workers or 1)
    for pair in dict.fromkeys(pair for pair, _ in todo):
        files[pair] = pair_files(work, pair, remedy)
        hashes[pair] = file_sha256(files[pair])
        missing = [seed for p, seed in todo if p == pair]
        # A pair's runs split evenly over the workers: whole seeds per task, as many tasks as workers.
        for seeds in split_seeds(missing, chunks):
            tasks.append(DriveTask(plan, pair, seeds, files[pair], batch_size=options.batch_size,
                                   device=options.device, remedy=remedy))
    try:
        for _, result in backend.map_unordered(drive_pair, tasks):
            state.drive_cpu_s[result.pair] = state.drive_cpu_s.get(result.pair, 0.0) + result.cpu_s
            for seed, rows in result.rows.items():
                _write_runs(work, result.pair, seed, rows, result.traces[seed], hashes[result.pair], result.remedy)
                if remedy:
                    state.remedy_runs[(remedy, result.pair, seed)] = rows
                else:
                    state.runs[(result.pair, seed)] = rows
                    state.bands[(result.pair, seed)] = run_bands(read_traces(result.traces[seed]))
                bar.update(len(rows))
    finally:
        bar.close()
    return len(todo)


def _write_runs(work: Path, pair: int, seed: int, rows: list[dict], traces: bytes, checkpoints: dict[str, str],
                remedy: str = "") -> None:
    path = runs_path(work, pair, seed, remedy)
    with write_output(path.with_suffix(".npz"), PAIR_TRACES, overwrite=True) as staged:
        staged.write_bytes(traces)
    record = {"pair": pair, "seed": seed, "remedy": remedy, "rows": rows, "traces_sha256": _sha256(traces),
              "checkpoints": checkpoints}
    write_json(path, _sealed(record), PAIR_RUNS, overwrite=True)


def _measure_feedback_missing(work: Path, state: WorkState, progress: bool,
                              pairs: tuple[int, ...] | None = None) -> None:
    """Posed feedback gains (:func:`~plm_highway.population.drift.posed_gains`) of every trained pair that has none
    yet: cheap (a few camera frames per pair), so they run here, after the driving."""
    plan = state.plan
    latencies_s = [constant_latency_s(s) for s in plan.latency_settings if constant_latency_s(s)]
    todo = [s.pair for s in plan.pairs if state.trainings.get(s.pair, {}).get("ok") and s.pair not in state.feedback
            and (pairs is None or s.pair in pairs)]
    bar = _progress(len(todo), 0, "population: feedback", "pair", progress and bool(todo))
    try:
        for pair in todo:
            with single_threaded_inference():
                gains = posed_gains(work / "pairs" / pair_name(pair), plan.conditions, plan.track, latencies_s)
            write_json(work / "pairs" / pair_name(pair) / "feedback.json", _sealed({"pair": pair, "gains": gains}),
                       PAIR_FEEDBACK, overwrite=True)
            state.feedback[pair] = gains
            bar.update(1)
    finally:
        bar.close()

