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
names its result file; it hashes everything that changes the run (the condition's settings, the
checkpoints, the step limit), so a changed definition never resumes from a stale result.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from plm_highway.errors import BadInput
from plm_highway.io.bounded import JsonLimits
from plm_highway.rollout.policies import POLICY_NAMES
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
        """File-name-safe id: readable fields plus a hash of the cell and every setting of its run."""
        readable = "_".join(str(v) for v in (self.policy, self.track, self.latency, f"s{self.seed}", self.condition))
        readable = re.sub(r"[^A-Za-z0-9.+-]+", "-", readable)[:80]
        digest = hashlib.sha1(json.dumps([asdict(self), settings], sort_keys=True, default=str).encode()).hexdigest()
        return f"{readable}-{digest[:12]}"

    @property
    def reference(self) -> SweepCell:
        """The run this cell's steering is compared with."""
        base = "expert" if self.policy == "expert" else "bm"
        return SweepCell(self.condition, self.track, REFERENCE_LATENCY, self.seed, base)


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

    def settings(self, condition: str, checkpoints) -> dict:
        """What besides the cell's fields changes its run (hashed into its key)."""
        return {"condition": dict(self.conditions[condition]), "max_steps": self.max_steps,
                "checkpoints": None if checkpoints is None else str(Path(checkpoints).resolve())}

    def as_dict(self) -> dict:
        return {"conditions": {k: dict(v) for k, v in self.conditions.items()}, "latencies": list(self.latencies),
                "tracks": list(self.tracks), "seeds": list(self.seeds), "policies": list(self.policies),
                "max_steps": self.max_steps}


def check_grid(grid: SweepGrid) -> None:
    """Raise BadInput naming the field when a value is out of range, before any run starts."""
    from plm_highway.latency import parse_profile
    from plm_highway.road.track import load_track

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
        try:
            parse_profile(spec)
        except ValueError as exc:
            raise BadInput(f"sweep grid: latency {spec!r}: {exc}") from None
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
            values[name] = tuple(str(v) for v in raw)
    if "seeds" in data:
        values["seeds"] = tuple(parse_seeds(data["seeds"], limit=MAX_SEEDS, what="sweep grid: seeds"))
    if "conditions" in data:
        values["conditions"] = data["conditions"] if data["conditions"] is not None else {}
    if "max_steps" in data:
        values["max_steps"] = data["max_steps"]
    return SweepGrid(**{name: values.get(name, getattr(defaults, name)) for name in GRID_KEYS})


def load_grid(path: str | Path) -> SweepGrid:
    """A grid from a YAML (.yaml/.yml) or JSON file, read within :data:`GRID_LIMITS` (aliases counted
    after expansion, no key twice, no integer longer than 20 digits)."""
    from plm_highway.io.bounded import decode_utf8, parse_json, parse_yaml, read_bounded

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
