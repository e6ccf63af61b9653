"""Track specifications: a road described as data, validated before anything is built.

A track is a JSON object::

    {"name": "test", "lanes": 3, "lane_width_m": 4.0, "closed": false,
     "segments": [{"type": "straight", "length_m": 150},
                  {"type": "arc", "radius_m": 120, "angle_deg": 60, "direction": "left"}]}

Coordinates: x east, y north (y up, as in the figures). The reference line is the centre of the
middle of the road; it starts at the origin heading east. ``radius_m`` is measured on that line.
"left"/"right" are as the driver sees them: a left arc raises the heading.

Bounds, checked before anything is built (every error names the file or source, the segment and
the field, and the accepted range):

==========================  =====================================================================
file                        at most ``MAX_TRACK_FILE_BYTES`` (1 MiB) of UTF-8 JSON, no byte-order
                            mark, brackets nested at most ``MAX_NESTING_DEPTH`` (16) deep, at
                            most ``MAX_JSON_VALUES`` (20,000) values, integers of at most 20
                            digits, no key twice in one object (plm_highway.io.bounded)
``name``                    a string of 1 to ``MAX_NAME_CHARS`` (100) characters
``lanes``                   an integer from 1 to 6
``lane_width_m``            from 2 to 8 m
``segments``                1 to ``MAX_SEGMENTS`` (1,000)
straight ``length_m``       (0, ``MAX_SEGMENT_LENGTH_M``] = (0, 10,000] m
arc ``radius_m``            [half the road + one lane, ``MAX_RADIUS_M``] = [.., 50,000] m
arc ``angle_deg``           (0, 360]
total length                at most ``MAX_TRACK_LENGTH_M`` (20,000 m)
the road itself             must not overlap itself (e.g. a 360-degree arc on an open track):
                            no two points of the reference line more than half a circle of the
                            tightest allowed radius apart along the road may be closer than the
                            road's width
==========================  =====================================================================

The camera's ground map adds one more bound, on its pixel count (see ``camera/ground_map.py``):
a track that spans too large an area (e.g. a closed circle of 1.5 km radius) is refused there.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from plm_highway.errors import BadInput
from plm_highway.io.bounded import JsonLimits, parse_json
from plm_highway.road.geometry import sample_reference
from plm_highway.road.spec import Segment, TrackSpec, end_pose

TRACK_KEYS = {"name", "lanes", "lane_width_m", "segments", "closed"}
SEGMENT_KEYS = {
    "straight": {"type", "length_m"},
    "arc": {"type", "radius_m", "angle_deg", "direction"},
}
SHIPPED_TRACKS = ("train", "test", "unseen")
MAX_TRACK_FILE_BYTES = 1 << 20
MAX_NESTING_DEPTH = 16
MAX_NAME_CHARS = 100
LANE_WIDTH_RANGE_M = (2.0, 8.0)
MAX_SEGMENTS = 1_000
MAX_SEGMENT_LENGTH_M = 10_000.0
MAX_RADIUS_M = 50_000.0
MAX_TRACK_LENGTH_M = 20_000.0
OVERLAP_SAMPLE_SPACING_M = 1.0
# Every value of a track file counts (1,000 segments of 4 fields and the top level fit well within).
MAX_JSON_VALUES = 20_000
TRACK_JSON_LIMITS = JsonLimits(max_bytes=MAX_TRACK_FILE_BYTES, max_depth=MAX_NESTING_DEPTH,
                               max_nodes=MAX_JSON_VALUES, max_int_digits=20)
# A closed track must come back to its start within these tolerances.
CLOSE_POSITION_TOL_M = 0.5
CLOSE_HEADING_TOL_RAD = math.radians(1.0)


def load_track(name_or_path: str | Path) -> TrackSpec:
    """Load a shipped track by name (``train``, ``test``, ``unseen``) or a spec file by path."""
    text_name = str(name_or_path)
    if text_name in SHIPPED_TRACKS:
        data = resources.files("plm_highway.road").joinpath("tracks", f"{text_name}.json").read_bytes()
        source = f"track '{text_name}'"
    else:
        path = Path(name_or_path)
        source = str(path)
        data = _track_bytes(path, text_name)
    return parse_track(_json_of(data, source), source=source)


def _track_bytes(path: Path, text_name: str) -> bytes:
    if not path.is_file():
        raise FileNotFoundError(
            f"track {text_name!r}: neither a shipped track {list(SHIPPED_TRACKS)} nor an existing file"
        )
    source = str(path)
    size = path.stat().st_size
    if size > MAX_TRACK_FILE_BYTES:
        raise BadInput(f"{source}: {size:,} bytes is larger than a track file may be "
                       f"({MAX_TRACK_FILE_BYTES:,} bytes)")
    with open(path, "rb") as handle:
        data = handle.read(MAX_TRACK_FILE_BYTES + 1)  # the file may have grown since stat
    if len(data) > MAX_TRACK_FILE_BYTES:
        raise BadInput(f"{source}: more bytes than a track file may hold ({MAX_TRACK_FILE_BYTES:,} bytes)")
    return data


def track_sha256(name_or_path: str | Path) -> str:
    """The sha256 of the bytes a track is read from (a shipped track's resource, or the file): what a result
    made on it is keyed by (two files called ``t.json`` in two directories are two tracks)."""
    text_name = str(name_or_path)
    if text_name in SHIPPED_TRACKS:
        data = resources.files("plm_highway.road").joinpath("tracks", f"{text_name}.json").read_bytes()
    else:
        data = _track_bytes(Path(name_or_path), text_name)
    return hashlib.sha256(data).hexdigest()


def resolve_track(track: TrackSpec | Mapping | str | Path, source: str = "track") -> TrackSpec:
    """The one boundary a track crosses: a :class:`TrackSpec` as it is, a mapping validated by
    :func:`parse_track` (``source`` names it in errors), a shipped name or a file path loaded by
    :func:`load_track`. Everything past it takes the ``TrackSpec``."""
    if isinstance(track, TrackSpec):
        return track
    if isinstance(track, Mapping):
        return parse_track(dict(track), source=source)
    if not isinstance(track, (str, Path)):
        raise BadInput(f"{source} = {track!r:.60}: must be a shipped track's name, a path to a track JSON file or a "
                       "track dict")
    return load_track(track)


def _json_of(data: bytes, source: str):
    """The track's JSON, read by the kit's bounded loader (linear time; depth, values, integer length and
    duplicate keys checked, each refusal naming the file and the field)."""
    return parse_json(data, source, TRACK_JSON_LIMITS, bom="refuse")


def parse_track(spec: dict, source: str = "<dict>") -> TrackSpec:
    """Validate a track dict; every error names the source, segment and field."""
    if not isinstance(spec, dict):
        raise BadInput(f"{source}: a track spec must be a JSON object, got {type(spec).__name__}")
    unknown = sorted(set(spec) - TRACK_KEYS)
    if unknown:
        raise BadInput(f"{source}: unknown keys {unknown}; allowed: {sorted(TRACK_KEYS)}")
    missing = sorted({"name", "segments"} - set(spec))
    if missing:
        raise BadInput(f"{source}: missing keys {missing}")
    name = spec["name"]
    if not isinstance(name, str) or not 1 <= len(name) <= MAX_NAME_CHARS:
        raise BadInput(f"{source}: field 'name' must be a string of 1 to {MAX_NAME_CHARS} characters, "
                         f"got {_short(name)}")
    lanes = spec.get("lanes", 3)
    if not isinstance(lanes, int) or isinstance(lanes, bool) or not 1 <= lanes <= 6:
        raise BadInput(f"{source}: field 'lanes' must be an integer from 1 to 6, got {_short(lanes)}")
    lane_width_m = _number_in(spec.get("lane_width_m", 4.0), f"{source}: field 'lane_width_m'", *LANE_WIDTH_RANGE_M)
    closed = spec.get("closed", False)
    if not isinstance(closed, bool):
        raise BadInput(f"{source}: field 'closed' must be true or false, got {closed!r}")
    raw_segments = spec["segments"]
    if not isinstance(raw_segments, list) or not raw_segments:
        raise BadInput(f"{source}: field 'segments' must be a non-empty list")
    if len(raw_segments) > MAX_SEGMENTS:
        raise BadInput(f"{source}: {len(raw_segments):,} segments exceed the limit of {MAX_SEGMENTS:,}")
    half_width_m = lanes * lane_width_m / 2.0
    segments = tuple(
        _parse_segment(raw, f"{source}: segment {index}", half_width_m, lane_width_m)
        for index, raw in enumerate(raw_segments)
    )
    track = TrackSpec(name, lanes, lane_width_m, segments, closed, source)
    if track.length_m > MAX_TRACK_LENGTH_M:
        raise BadInput(f"{source}: total length {track.length_m:,.0f} m exceeds the limit of "
                         f"{MAX_TRACK_LENGTH_M:,.0f} m")
    if closed:
        _check_closes(track)
    _check_no_overlap(track)
    return track


def _parse_segment(raw: dict, where: str, half_width_m: float, lane_width_m: float) -> Segment:
    if not isinstance(raw, dict):
        raise BadInput(f"{where}: must be an object, got {raw!r}")
    kind = raw.get("type")
    if kind not in SEGMENT_KEYS:
        raise BadInput(f"{where}: field 'type' must be 'straight' or 'arc', got {kind!r}")
    unknown = sorted(set(raw) - SEGMENT_KEYS[kind])
    missing = sorted(SEGMENT_KEYS[kind] - set(raw))
    if unknown:
        raise BadInput(f"{where} ({kind}): unknown keys {unknown}; allowed: {sorted(SEGMENT_KEYS[kind])}")
    if missing:
        raise BadInput(f"{where} ({kind}): missing keys {missing}")
    if kind == "straight":
        return Segment("straight", _number_in(raw["length_m"], f"{where}: field 'length_m'", 0.0,
                                              MAX_SEGMENT_LENGTH_M, open_low=True))
    radius_m = _number_in(raw["radius_m"], f"{where}: field 'radius_m'", 0.0, MAX_RADIUS_M, open_low=True)
    # The inner road edge must stay at least one lane width away from the arc's centre.
    min_radius_m = half_width_m + lane_width_m
    if radius_m < min_radius_m:
        raise BadInput(
            f"{where}: field 'radius_m' = {radius_m} is too tight for the road width; "
            f"it must be at least {min_radius_m} m (half the road plus one lane of {lane_width_m} m)"
        )
    angle_deg = _number_in(raw["angle_deg"], f"{where}: field 'angle_deg'", 0.0, 360.0, open_low=True)
    direction = raw["direction"]
    if direction not in ("left", "right"):
        raise BadInput(f"{where}: field 'direction' must be 'left' or 'right', got {_short(direction)}")
    angle_rad = math.radians(angle_deg)
    return Segment("arc", radius_m * angle_rad, radius_m, angle_rad, direction)


def _number_in(value, where: str, low: float, high: float, open_low: bool = False) -> float:
    """``value`` as a float in [low, high] ((low, high] with ``open_low``); a clear error otherwise."""
    number = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
    inside = (low < number if open_low else low <= number) and number <= high  # False for NaN
    if not inside:
        bracket = "(" if open_low else "["
        raise BadInput(f"{where} must be a number in {bracket}{low:g}, {high:g}], got {_short(value)}")
    return number


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_no_overlap(track: TrackSpec) -> None:
    """Refuse a road that runs over itself: two reference points far apart along the road (more than
    half a circle of the tightest allowed radius) yet closer than the road is wide."""
    ref = sample_reference(track, spacing_m=OVERLAP_SAMPLE_SPACING_M)
    road_width_m = 2.0 * track.road_half_width_m
    min_separation_m = math.pi * (track.road_half_width_m + track.lane_width_m)
    pairs = cKDTree(np.column_stack([ref.x_m, ref.y_m])).query_pairs(road_width_m - 1e-6, output_type="ndarray")
    if len(pairs) == 0:
        return
    along_m = np.abs(ref.s_m[pairs[:, 0]] - ref.s_m[pairs[:, 1]])
    if track.closed:
        along_m = np.minimum(along_m, track.length_m - along_m)
    far = np.flatnonzero(along_m > min_separation_m)
    if len(far):
        i, j = sorted(pairs[far[0]])
        raise BadInput(
            f"{track.source}: the road overlaps itself: at {ref.s_m[i]:.0f} m (segment {ref.segment_index[i]}) and "
            f"{ref.s_m[j]:.0f} m (segment {ref.segment_index[j]}) along it, its centre lines are "
            f"{math.hypot(ref.x_m[i] - ref.x_m[j], ref.y_m[i] - ref.y_m[j]):.1f} m apart, less than the road's "
            f"{road_width_m:g} m width (a closed loop needs 'closed': true)"
        )


def _check_closes(track: TrackSpec) -> None:
    x_m, y_m, heading_rad = end_pose(track)
    gap_m = math.hypot(x_m, y_m)
    heading_gap_rad = abs(math.remainder(heading_rad, 2 * math.pi))
    if gap_m > CLOSE_POSITION_TOL_M or heading_gap_rad > CLOSE_HEADING_TOL_RAD:
        raise BadInput(
            f"{track.source}: field 'closed' is true but the last segment ends {gap_m:.2f} m and "
            f"{math.degrees(heading_gap_rad):.1f} deg away from the start"
        )
