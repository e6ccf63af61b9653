"""The committed part of a population: one record per finished pair, under the report directory's ``pairs/``.

A pair's record (``pairs/pair-NN.json``) holds everything the report needs of it: its seeds, how its training went
(per-stage wall and CPU time, validation losses, or why it failed), the sha256 of each checkpoint file, every run's
outcome row, the slow/fast offset bands of every run and its posed feedback gains. It is written as soon as the
pair is finished, so a study grows pair by pair: commit the record, and ``plm-highway population --pairs K``
continues from it on any machine, a fresh clone included, training and driving only the pairs that have none.

A record is reused only for the population it was made from: :func:`population_key` hashes the recipe, the
conditions, the contents of the training and test tracks, the settings, the simulator seeds, the step limit and
the kit's version. A record made from anything else is refused by name (never silently mixed in). A record whose
own contents were edited (its ``record_sha256`` no longer matches) is refused too.

Checkpoints are not committed (a paper-preset pair is ~48 MB): where a committed pair's checkpoints are needed
again (a new remedy, or posed gains to measure) and the work directory lacks them, the pair is retrained and its
files are checked against the committed hashes before anything is driven with them.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict
from pathlib import Path

from plm_highway._version import __version__
from plm_highway.errors import BadInput
from plm_highway.io import JSON_MARKER_KEY, file_kind, json_text, write_output
from plm_highway.io.bounded import JsonLimits, load_json
from plm_highway.population.plan import PopulationPlan, pair_name
from plm_highway.road.track import resolve_track

PAIR_RECORD = file_kind("population-pair", "a population's committed pair record")
RECORD_FORMAT = "plm_highway.population.pair/1"
LEDGER_DIR = "pairs"
MAX_RECORD_BYTES = 16 << 20


def track_sha256(track: str) -> str:
    """The sha256 of a track's contents (its geometry as parsed, not its name or path)."""
    spec = asdict(resolve_track(track))
    spec.pop("source", None)
    return hashlib.sha256(json.dumps(spec, sort_keys=True, default=str).encode("utf-8")).hexdigest()


def made_from(plan: PopulationPlan) -> dict:
    """What a pair's results are made from (everything but the pair's own seeds and the remedies)."""
    data = {"recipe": plan.recipe.as_dict(), "conditions": plan.conditions, "track": plan.track,
            "track_sha256": track_sha256(plan.track), "train_track_sha256": track_sha256(plan.recipe.track),
            "settings": list(plan.settings), "sim_seeds": list(plan.sim_seeds), "max_steps": plan.max_steps,
            "kit_version": __version__}
    # Only when set: results made with the conditions' own latency source keep the key they were committed under.
    return {**data, "latency_source": plan.latency_source} if plan.latency_source else data


def population_key(plan: PopulationPlan) -> str:
    return _digest(made_from(plan))


def _digest(data) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":")).encode("utf-8")).hexdigest()


def file_sha256(files: dict[str, dict[str, bytes]]) -> dict[str, str]:
    """``{"bm/model.pt": sha256, "tapm/model.pt": sha256}``: the weights of a pair's checkpoints (their
    ``model.json`` names the temporary directories it was trained in, so it is not compared)."""
    return {f"{model}/{name}": hashlib.sha256(data).hexdigest()
            for model, named in sorted(files.items()) for name, data in sorted(named.items()) if name == "model.pt"}


def record_path(out: Path, pair: int) -> Path:
    return Path(out) / LEDGER_DIR / f"{pair_name(pair)}.json"


def sealed(record: dict) -> dict:
    """``record`` with ``record_sha256``: the digest of everything else in it (so an edit is seen)."""
    body = {key: value for key, value in record.items() if key != "record_sha256"}
    return {**body, "record_sha256": _digest(json.loads(json_text(body)))}


def read_ledger(out: Path, plan: PopulationPlan) -> dict[int, dict]:
    """The committed records of ``plan``'s pairs under ``out`` (``{pair: record}``); refuses a record made from
    another population, or edited since it was written."""
    key, records = population_key(plan), {}
    for seeds in plan.pairs:
        path = record_path(out, seeds.pair)
        if not path.is_file():
            continue
        record = read_record(path)
        if record.get("population_key") != key:
            differs = differences(record.get("made_from", {}), plan)
            raise BadInput(f"{path}: this pair was made for another population ({', '.join(differs) or 'its key'} "
                           "differ); give another --out, or pass --restart to start the study afresh")
        if record.get("seeds") != asdict(seeds):
            raise BadInput(f"{path}: its seeds {record.get('seeds')} are not pair {seeds.pair}'s {asdict(seeds)}")
        records[seeds.pair] = record
    return records


def read_record(path: Path) -> dict:
    # The kit's bounded loader: size, depth and duplicate keys refused, naming the file.
    data = load_json(path, JsonLimits(max_bytes=MAX_RECORD_BYTES), what=PAIR_RECORD.describe)
    if not isinstance(data, dict) or data.get(JSON_MARKER_KEY) != PAIR_RECORD.name:
        raise BadInput(f"{path}: not {PAIR_RECORD.describe}")
    if data.get("format") != RECORD_FORMAT:
        raise BadInput(f"{path}: format {data.get('format')!r}, expected {RECORD_FORMAT!r}")
    body = {key: value for key, value in data.items() if key not in ("record_sha256", JSON_MARKER_KEY)}
    if data.get("record_sha256") != _digest(json.loads(json_text(body))):
        raise BadInput(f"{path}: its contents were changed after plm-highway wrote it (record_sha256 does not "
                       "match); restore it from git, or remove it to have the pair made again")
    return data


def differences(earlier: dict, plan: PopulationPlan) -> list[str]:
    """The names of what ``plan``'s results would be made from that differs from ``earlier`` (a stored
    :func:`made_from`): ``track_sha256`` when a track file's contents changed under the same path."""
    earlier, now = (json.loads(json_text(side)) for side in (earlier, made_from(plan)))  # as a file reads back
    # Both sides' names: a field set on one side only (a latency source) differs as much as one set differently.
    return [name for name in dict.fromkeys([*now, *earlier]) if earlier.get(name) != now.get(name)]


def write_record(out: Path, record: dict, kind) -> Path:
    """Publish one pair's record into the report directory ``out`` (the rest of ``out`` stays as it is)."""
    relative = f"{LEDGER_DIR}/{pair_name(record['pair'])}.json"
    with write_output(out, kind, update=[relative]) as staged:
        (staged / LEDGER_DIR).mkdir()
        (staged / relative).write_text(json_text(sealed(record), PAIR_RECORD), encoding="utf-8")
    return Path(out) / relative


def new_record(plan: PopulationPlan, pair: int) -> dict:
    seeds = next(s for s in plan.pairs if s.pair == pair)
    return {"format": RECORD_FORMAT, "pair": pair, "seeds": asdict(seeds), "population_key": population_key(plan),
            "made_from": made_from(plan)}


def finite_or_nan(value):
    """JSON null back to NaN for the band values (strict JSON has no NaN)."""
    return math.nan if value is None else value
