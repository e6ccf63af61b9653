"""Build a :class:`TrackSpec` into a highway-env ``RoadNetwork``.

Each segment becomes one road edge (arcs of more than 170 degrees are split, because
``CircularLane.local_coordinates`` wraps at pi) holding ``lanes`` parallel lanes. Lane 0 is the
leftmost lane. In this project's y-up world a left arc is highway-env's ``clockwise=True``
(the phase grows, which is counter-clockwise when y points up), and a lane's positive lateral
coordinate points to the driver's left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from highway_env.road.lane import CircularLane, LineType, StraightLane
from highway_env.road.road import RoadNetwork

from plm_highway.road.track import Segment, TrackSpec, advance_pose

MAX_ARC_PIECE_RAD = math.radians(170.0)


@dataclass(frozen=True)
class Edge:
    """One road edge of the network and where it sits on the track."""

    key: tuple[str, str]
    segment_index: int
    start_s_m: float  # arc length of the reference line where the edge starts
    length_m: float  # along the reference line


@dataclass(frozen=True)
class BuiltRoad:
    network: RoadNetwork
    edges: tuple[Edge, ...]
    lane_offsets_m: tuple[float, ...]  # lateral position of each lane's centre, left positive


def lane_offsets_m(track: TrackSpec) -> tuple[float, ...]:
    return tuple(track.road_half_width_m - (i + 0.5) * track.lane_width_m for i in range(track.lanes))


def build_road(track: TrackSpec) -> BuiltRoad:
    network = RoadNetwork()
    offsets_m = lane_offsets_m(track)
    pieces = [(index, piece) for index, seg in enumerate(track.segments) for piece in _split_arc(seg)]
    edges: list[Edge] = []
    pose = (0.0, 0.0, 0.0)
    s_m = 0.0
    for n, (seg_index, piece) in enumerate(pieces):
        end_node = "n0" if (track.closed and n == len(pieces) - 1) else f"n{n + 1}"
        key = (f"n{n}", end_node)
        for lane_id, offset_m in enumerate(offsets_m):
            network.add_lane(*key, _lane(pose, piece, offset_m, track, lane_id))
        edges.append(Edge(key, seg_index, s_m, piece.length_m))
        pose = advance_pose(pose, piece)
        s_m += piece.length_m
    return BuiltRoad(network, tuple(edges), offsets_m)


def _split_arc(seg: Segment) -> list[Segment]:
    if seg.kind == "straight" or seg.angle_rad < MAX_ARC_PIECE_RAD:
        return [seg]
    n = math.ceil(seg.angle_rad / MAX_ARC_PIECE_RAD)
    angle = seg.angle_rad / n
    return [Segment("arc", seg.radius_m * angle, seg.radius_m, angle, seg.direction)] * n


def _line_types(track: TrackSpec, lane_id: int) -> list[LineType]:
    # highway-env's side 0 is lateral -width/2, i.e. the lane's right-hand side here.
    right = LineType.CONTINUOUS_LINE if lane_id == track.lanes - 1 else LineType.STRIPED
    left = LineType.CONTINUOUS_LINE if lane_id == 0 else LineType.NONE
    return [right, left]


def _lane(pose, seg: Segment, offset_m: float, track: TrackSpec, lane_id: int):
    x_m, y_m, heading_rad = pose
    normal = (-math.sin(heading_rad), math.cos(heading_rad))
    line_types = _line_types(track, lane_id)
    if seg.kind == "straight":
        start = (x_m + offset_m * normal[0], y_m + offset_m * normal[1])
        end = (start[0] + seg.length_m * math.cos(heading_rad), start[1] + seg.length_m * math.sin(heading_rad))
        return StraightLane(start, end, width=track.lane_width_m, line_types=line_types)
    sign = 1.0 if seg.direction == "left" else -1.0
    centre = (x_m + sign * seg.radius_m * normal[0], y_m + sign * seg.radius_m * normal[1])
    start_phase = heading_rad - sign * math.pi / 2
    return CircularLane(
        centre,
        seg.radius_m - sign * offset_m,
        start_phase,
        start_phase + sign * seg.angle_rad,
        clockwise=seg.direction == "left",
        width=track.lane_width_m,
        line_types=line_types,
    )
