"""Track specifications: a road described as data, validated before anything is built.

A track is a JSON object::

    {"name": "test", "lanes": 3, "lane_width_m": 4.0, "closed": false,
     "segments": [{"type": "straight", "length_m": 150},
                  {"type": "arc", "radius_m": 120, "angle_deg": 60, "direction": "left"}]}

Coordinates: x east, y north (y up, as in the figures). The reference line is the centre of the
middle of the road; it starts at the origin heading east. ``radius_m`` is measured on that line.
"left"/"right" are as the driver sees them: a left arc raises the heading.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

TRACK_KEYS = {"name", "lanes", "lane_width_m", "segments", "closed"}
SEGMENT_KEYS = {
    "straight": {"type", "length_m"},
    "arc": {"type", "radius_m", "angle_deg", "direction"},
}
SHIPPED_TRACKS = ("train", "test", "unseen")
# A closed track must come back to its start within these tolerances.
CLOSE_POSITION_TOL_M = 0.5
CLOSE_HEADING_TOL_RAD = math.radians(1.0)


@dataclass(frozen=True)
class Segment:
    kind: str  # "straight" | "arc"
    length_m: float  # along the reference line
    radius_m: float = math.inf
    angle_rad: float = 0.0
    direction: str = "straight"  # "straight" | "left" | "right"

    @property
    def curvature_1pm(self) -> float:
        """Signed curvature of the reference line; positive turns left."""
        if self.kind == "straight":
            return 0.0
        return (1.0 if self.direction == "left" else -1.0) / self.radius_m


@dataclass(frozen=True)
class TrackSpec:
    name: str
    lanes: int
    lane_width_m: float
    segments: tuple[Segment, ...]
    closed: bool
    source: str = "<dict>"

    @property
    def road_half_width_m(self) -> float:
        return self.lanes * self.lane_width_m / 2.0

    @property
    def length_m(self) -> float:
        return sum(seg.length_m for seg in self.segments)


def load_track(name_or_path: str | Path) -> TrackSpec:
    """Load a shipped track by name (``train``, ``test``, ``unseen``) or a spec file by path."""
    text_name = str(name_or_path)
    if text_name in SHIPPED_TRACKS:
        text = resources.files("plm_highway.road").joinpath("tracks", f"{text_name}.json").read_text()
        source = f"track '{text_name}'"
    else:
        path = Path(name_or_path)
        if not path.is_file():
            raise FileNotFoundError(
                f"track {text_name!r}: neither a shipped track {list(SHIPPED_TRACKS)} nor an existing file"
            )
        text = path.read_text()
        source = str(path)
    try:
        spec = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{source}: not valid JSON ({exc})") from None
    return parse_track(spec, source=source)


def parse_track(spec: dict, source: str = "<dict>") -> TrackSpec:
    """Validate a track dict; every error names the source, segment and field."""
    if not isinstance(spec, dict):
        raise ValueError(f"{source}: a track spec must be a JSON object, got {type(spec).__name__}")
    unknown = sorted(set(spec) - TRACK_KEYS)
    if unknown:
        raise ValueError(f"{source}: unknown keys {unknown}; allowed: {sorted(TRACK_KEYS)}")
    missing = sorted({"name", "segments"} - set(spec))
    if missing:
        raise ValueError(f"{source}: missing keys {missing}")
    lanes = spec.get("lanes", 3)
    if not isinstance(lanes, int) or isinstance(lanes, bool) or not 1 <= lanes <= 6:
        raise ValueError(f"{source}: field 'lanes' must be an integer from 1 to 6, got {lanes!r}")
    lane_width_m = _positive_number(spec.get("lane_width_m", 4.0), f"{source}: field 'lane_width_m'")
    closed = spec.get("closed", False)
    if not isinstance(closed, bool):
        raise ValueError(f"{source}: field 'closed' must be true or false, got {closed!r}")
    raw_segments = spec["segments"]
    if not isinstance(raw_segments, list) or not raw_segments:
        raise ValueError(f"{source}: field 'segments' must be a non-empty list")
    half_width_m = lanes * lane_width_m / 2.0
    segments = tuple(
        _parse_segment(raw, f"{source}: segment {index}", half_width_m, lane_width_m)
        for index, raw in enumerate(raw_segments)
    )
    track = TrackSpec(str(spec["name"]), lanes, lane_width_m, segments, closed, source)
    if closed:
        _check_closes(track)
    return track


def _parse_segment(raw: dict, where: str, half_width_m: float, lane_width_m: float) -> Segment:
    if not isinstance(raw, dict):
        raise ValueError(f"{where}: must be an object, got {raw!r}")
    kind = raw.get("type")
    if kind not in SEGMENT_KEYS:
        raise ValueError(f"{where}: field 'type' must be 'straight' or 'arc', got {kind!r}")
    unknown = sorted(set(raw) - SEGMENT_KEYS[kind])
    missing = sorted(SEGMENT_KEYS[kind] - set(raw))
    if unknown:
        raise ValueError(f"{where} ({kind}): unknown keys {unknown}; allowed: {sorted(SEGMENT_KEYS[kind])}")
    if missing:
        raise ValueError(f"{where} ({kind}): missing keys {missing}")
    if kind == "straight":
        return Segment("straight", _positive_number(raw["length_m"], f"{where}: field 'length_m'"))
    radius_m = _positive_number(raw["radius_m"], f"{where}: field 'radius_m'")
    # The inner road edge must stay at least one lane width away from the arc's centre.
    min_radius_m = half_width_m + lane_width_m
    if radius_m < min_radius_m:
        raise ValueError(
            f"{where}: field 'radius_m' = {radius_m} is too tight for the road width; "
            f"it must be at least {min_radius_m} m (half the road plus one lane of {lane_width_m} m)"
        )
    angle_deg = _positive_number(raw["angle_deg"], f"{where}: field 'angle_deg'")
    if angle_deg > 360:
        raise ValueError(f"{where}: field 'angle_deg' = {angle_deg} exceeds 360")
    direction = raw["direction"]
    if direction not in ("left", "right"):
        raise ValueError(f"{where}: field 'direction' must be 'left' or 'right', got {direction!r}")
    angle_rad = math.radians(angle_deg)
    return Segment("arc", radius_m * angle_rad, radius_m, angle_rad, direction)


def _positive_number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{where} must be a positive number, got {value!r}")
    return float(value)


def _check_closes(track: TrackSpec) -> None:
    x_m, y_m, heading_rad = end_pose(track)
    gap_m = math.hypot(x_m, y_m)
    heading_gap_rad = abs(math.remainder(heading_rad, 2 * math.pi))
    if gap_m > CLOSE_POSITION_TOL_M or heading_gap_rad > CLOSE_HEADING_TOL_RAD:
        raise ValueError(
            f"{track.source}: field 'closed' is true but the last segment ends {gap_m:.2f} m and "
            f"{math.degrees(heading_gap_rad):.1f} deg away from the start"
        )


def advance_pose(pose: tuple[float, float, float], segment: Segment) -> tuple[float, float, float]:
    """Pose (x, y, heading) of the reference line at the end of ``segment`` started at ``pose``."""
    x_m, y_m, heading_rad = pose
    if segment.kind == "straight":
        return (x_m + segment.length_m * math.cos(heading_rad),
                y_m + segment.length_m * math.sin(heading_rad), heading_rad)
    sign = 1.0 if segment.direction == "left" else -1.0
    centre_x = x_m - sign * segment.radius_m * math.sin(heading_rad)
    centre_y = y_m + sign * segment.radius_m * math.cos(heading_rad)
    new_heading = heading_rad + sign * segment.angle_rad
    return (centre_x + sign * segment.radius_m * math.sin(new_heading),
            centre_y - sign * segment.radius_m * math.cos(new_heading), new_heading)


def end_pose(track: TrackSpec) -> tuple[float, float, float]:
    pose = (0.0, 0.0, 0.0)
    for segment in track.segments:
        pose = advance_pose(pose, segment)
    return pose
