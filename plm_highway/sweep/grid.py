"""A sweep grid: conditions x latency profiles x tracks x seeds x policies, and its cells.

A grid comes from the command line or a small YAML/JSON file (Hydra-style lists of values)::
    conditions:            # name -> env settings; default: one condition "default" with none
      default: {}
      pitch8: {camera: {pitch_deg: 8}}
      fast: {env_config: {speed_mps: 25}}
    latencies: [const:0.1, const:0.25, steps:0.0-0.35:1.0]
    tracks: [test, unseen]
    seeds: 5               # a count (0..4) or a list [0, 3, 7]
    policies: [bm, plm]
    max_steps: 400         # optional: stop each run after this many policy steps

Every cell is one closed-loop run. For the steering error each policy needs its reference, the
Base Model (the expert for the expert) without latency on the same condition, track and seed: the
grid adds those cells (``const:0``) when it does not hold them already. A cell's :meth:`SweepCell.key`
names its result file; it hashes everything the run is made from, by content (the condition's settings as
typed, the step limit, the track and trace files' bytes, the checkpoint files' sha256, the kit's version:
:meth:`SweepGrid.inputs`), so a changed definition or input never resumes from a stale result. Names are
text (:func:`grid_name`): ``1`` and ``'1'`` never become one condition.
"""

from __future__ import annotations

import itertools
import re
import unicodedata
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from plm_highway.errors import BadInput
from plm_highway.io.bounded import JsonLimits, decode_utf8, parse_json, parse_yaml, read_bounded
from plm_highway.io.digests import file_sha256, json_digest, kit_version
from plm_highway.latency.profiles import check_specs
from plm_highway.road.track import load_track, track_sha256
from plm_highway.rollout.policies import MODEL_POLICIES, POLICY_NAMES, checkpoint_pair_sha256, policy_kind
from plm_highway.rollout.seeds import parse_seeds

REFERENCE_LATENCY = "const:0"
MAX_CELLS = 100_000
MAX_SEEDS = 10_000
MAX_STEPS = 10_000_000
MAX_GRID_FILE_BYTES = 1 << 20
GRID_LIMITS = JsonLimits(max_bytes=MAX_GRID_FILE_BYTES, max_depth=16, max_nodes=200_000, max_int_digits=20,
                         max_expanded_chars=4 << 20)
CONDITION_KEYS = ("camera", "env_config")
GRID_KEYS = ("conditions", "latencies", "tracks", "seeds", "policies", "max_steps")


@dataclass(frozen=True)
class SweepCell:
    condition: str
    track: str
    latency: str
    seed: int
    policy: str

    def key(self, settings: Mapping) -> str:
        """File-name-safe id: readable fields plus a digest of the cell and of everything its run is made from
        (``settings``: :meth:`SweepGrid.settings`, contents and typed values, never paths)."""
        readable = "_".join(str(v) for v in (self.policy, self.track, self.latency, f"s{self.seed}", self.condition))
        readable = re.sub(r"[^A-Za-z0-9.+-]+", "-", readable)[:80]
        return f"{readable}-{json_digest([asdict(self), settings])[:16]}"

    @property
    def reference(self) -> SweepCell:
        """The run this cell's steering is compared with."""
        return SweepCell(self.condition, self.track, REFERENCE_LATENCY, self.seed, policy_kind(self.policy).reference)


@dataclass(frozen=True)
class SweepGrid:
    latencies: tuple[str, ...] = ("const:0.1", "const:0.25")
    tracks: tuple[str, ...] = ("test",)
    seeds: tuple[int, ...] = (0,)
    policies: tuple[str, ...] = ("bm", "plm")
    conditions: Mapping[str, Mapping] = field(default_factory=lambda: {"default": {}})
    max_steps: int | None = None

    def __post_init__(self) -> None:
        check_grid(self)

    def cells(self) -> list[SweepCell]:
        """The grid's cells in a stable order, then the reference cells it lacks."""
        cells = [SweepCell(c, t, lat, s, p) for c, t, lat, s, p in
                 itertools.product(self.conditions, self.tracks, self.latencies, self.seeds, self.policies)]
        seen = set(cells)
        for cell in list(cells):
            if cell.reference not in seen:
                seen.add(cell.reference)
                cells.append(cell.reference)
        return cells

    def size(self) -> int:
        return (len(self.conditions) * len(self.tracks) * len(self.latencies) * len(self.seeds)
                * len(self.policies))

    def settings(self, cell: SweepCell, inputs: Mapping) -> dict:
        """What besides the cell's fields its run is made from (hashed into its key): the condition's settings and
        the step limit as typed, the contents of its track and latency trace files, its checkpoints' sha256 (model
        policies) and the kit's version. ``inputs``: :meth:`inputs`."""
        return {"condition": self.conditions[cell.condition], "max_steps": self.max_steps,
                "track_sha256": inputs["tracks"][cell.track], "trace_sha256": inputs["traces"].get(cell.latency),
                "checkpoints_sha256": inputs["checkpoints"] if cell.policy in MODEL_POLICIES else None,
                "kit_version": inputs["kit_version"]}

    def inputs(self, checkpoints=None) -> dict:
        """The contents the grid's runs read, as digests: every track file (a shipped track's too), every
        ``trace:`` latency file, the checkpoint pair's files (when a model policy runs) and the kit's version.
        Read once per sweep: a file changed since the last run gives its cells other keys, so they run again."""
        traces = {}
        for spec in self.latencies + (REFERENCE_LATENCY,):
            kind, _, rest = spec.strip().partition(":")
            if kind == "trace":
                traces[spec] = file_sha256(rest, f"sweep grid: latency {spec!r}: trace file")
        models = any(cell.policy in MODEL_POLICIES for cell in self.cells())
        return {"tracks": {track: track_sha256(track) for track in self.tracks}, "traces": traces,
                "checkpoints": checkpoint_pair_sha256(checkpoints) if models else None,
                "kit_version": kit_version()}

    def as_dict(self) -> dict:
        return {"conditions": {k: dict(v) for k, v in self.conditions.items()}, "latencies": list(self.latencies),
                "tracks": list(self.tracks), "seeds": list(self.seeds), "policies": list(self.policies),
                "max_steps": self.max_steps}


def check_grid(grid: SweepGrid) -> None:
    """Raise BadInput naming the field when a value is out of range, before any run starts."""
    for name in ("latencies", "tracks", "policies"):
        for index, value in enumerate(getattr(grid, name)):
            grid_name(value, f"sweep grid: {name}[{index}]")
    for name in grid.conditions:
        grid_name(name, "sweep grid: condition name")
    for name in ("latencies", "tracks", "seeds", "policies"):
        values = getattr(grid, name)
        if not values:
            raise BadInput(f"sweep grid: '{name}' is empty; give at least one value")
        if len(set(values)) != len(values):
            raise BadInput(f"sweep grid: '{name}' lists a value twice: {list(values)}")
    if not grid.conditions:
        raise BadInput("sweep grid: 'conditions' is empty; give at least one (e.g. default: {})")
    for policy in grid.policies:
        if policy not in POLICY_NAMES:
            raise BadInput(f"sweep grid: policy {policy!r} is not one of {list(POLICY_NAMES)}")
    for seed in grid.seeds:
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
            raise BadInput(f"sweep grid: seed {seed!r} must be an integer in [0, 2**32-1]")
    for spec in grid.latencies:
        check_specs([spec], f"sweep grid: latency {spec!r}")
    for track in grid.tracks:
        try:
            load_track(track)
        except (ValueError, OSError) as exc:
            raise BadInput(f"sweep grid: track {track!r}: {exc}") from None
    for name, condition in grid.conditions.items():
        if not isinstance(condition, Mapping) or set(condition) - set(CONDITION_KEYS):
            raise BadInput(f"sweep grid: condition {name!r} must be a mapping with keys among {list(CONDITION_KEYS)}, "
                           f"got {condition!r}")
        for key in CONDITION_KEYS:
            if not isinstance(condition.get(key, {}), Mapping):
                raise BadInput(f"sweep grid: condition {name!r}: '{key}' must be a mapping")
    if grid.max_steps is not None and (isinstance(grid.max_steps, bool) or not isinstance(grid.max_steps, int)
                                       or not 1 <= grid.max_steps <= MAX_STEPS):
        raise BadInput(f"sweep grid: max_steps {grid.max_steps!r} must be an integer in [1, {MAX_STEPS:,}]")
    if grid.size() > MAX_CELLS:
        raise BadInput(f"sweep grid: {grid.size():,} cells; at most {MAX_CELLS:,} per sweep")


def grid_from_mapping(data: Mapping, source: str = "grid") -> SweepGrid:
    if not isinstance(data, Mapping):
        raise BadInput(f"{source}: expected a mapping with keys among {list(GRID_KEYS)}")
    unknown = sorted(set(data) - set(GRID_KEYS))
    if unknown:
        raise BadInput(f"{source}: unknown keys {unknown}; accepted: {list(GRID_KEYS)}")
    defaults = SweepGrid()
    values = {}
    for name in ("latencies", "tracks", "policies"):
        if name in data:
            raw = data[name]
            if isinstance(raw, str) or not isinstance(raw, Sequence):
                raise BadInput(f"{source}: '{name}' must be a list, got {raw!r}")
            values[name] = tuple(grid_name(v, f"{source}: {name}[{i}]") for i, v in enumerate(raw))
    if "seeds" in data:
        values["seeds"] = tuple(parse_seeds(data["seeds"], limit=MAX_SEEDS, what="sweep grid: seeds"))
    if "conditions" in data:
        conditions = data["conditions"] if data["conditions"] is not None else {}
        if not isinstance(conditions, Mapping):
            raise BadInput(f"{source}: 'conditions' must be a mapping of names to settings, got {conditions!r}")
        values["conditions"] = {grid_name(name, f"{source}: conditions name"): value
                                for name, value in conditions.items()}
        _refuse_merged(list(conditions), list(values["conditions"]), f"{source}: conditions")
    if "max_steps" in data:
        values["max_steps"] = data["max_steps"]
    return SweepGrid(**{name: values.get(name, getattr(defaults, name)) for name in GRID_KEYS})


def grid_name(value, where: str) -> str:
    """A name in a grid (a condition, track, latency spec or policy) as it is typed: text only.

    A number is refused rather than turned into text: ``1`` and ``'1'`` are different YAML values that would
    become one name (one condition in grid.json, its rows labelled alike). Surrounding spaces and characters
    that Unicode normalisation (NFC) would change are refused too, so two names never differ invisibly.
    """
    if not isinstance(value, str):
        raise BadInput(f"{where} {value!r} is a {type(value).__name__}; names are text: write it in quotes "
                       f"('{value}') if that is the name you mean")
    if not value or value != value.strip():
        raise BadInput(f"{where} {value!r}: a name is non-empty text without surrounding spaces")
    if any(unicodedata.category(char).startswith("C") for char in value):
        raise BadInput(f"{where} {value!r}: holds a control or invisible character")
    if unicodedata.normalize("NFC", value) != value:
        raise BadInput(f"{where} {value!r}: not in Unicode NFC form (it would compare unequal to the same name "
                       "typed elsewhere); retype it")
    return value


def _refuse_merged(raw: list, names: list[str], where: str) -> None:
    if len(set(names)) != len(names):
        raise BadInput(f"{where}: {raw!r} name one thing twice")


def load_grid(path: str | Path) -> SweepGrid:
    """A grid from a YAML (.yaml/.yml) or JSON file, read within :data:`GRID_LIMITS` (aliases counted
    after expansion, no key twice, no integer longer than 20 digits)."""

    path = Path(path)
    source = f"--grid {str(path)!r}"
    if not path.is_file():
        raise BadInput(f"{source}: no such file")
    data = read_bounded(path, MAX_GRID_FILE_BYTES, "grid file")
    if path.suffix.lower() in (".yaml", ".yml"):
        document = parse_yaml(decode_utf8(data, source), source, GRID_LIMITS)
    else:
        document = parse_json(data, source, GRID_LIMITS)
    return grid_from_mapping(document, source)
