"""A track as data: its segments and the pose algebra of the reference line.

:class:`TrackSpec` is the one type a track has once resolved (:func:`plm_highway.road.track.resolve_track`
builds it from a shipped name, a file path or a mapping, validated); everything past that boundary takes a
``TrackSpec``. This module holds no parsing, so the geometry can build on it and the parser on both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


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
