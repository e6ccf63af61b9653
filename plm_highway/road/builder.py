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

from plm_highway.road.spec import Segment, TrackSpec, advance_pose

MAX_ARC_PIECE_RAD = math.radians(170.0)


@dataclass(frozen=True)
class Edge:
    """One road edge of the network and where it sits on the track."""

    key: tuple[str, str]
    segment_index: int
    start_s_m: float  # arc length of the reference line where the edge starts
    length_m: float  # along the reference line


@dataclass(frozen=True, slots=True)
class StraightFrame:
    """Local coordinates on one straight lane in scalar arithmetic, operation for operation as
    highway-env's ``StraightLane`` (its numpy ops on two-element arrays cost more than the maths)."""

    start_x_m: float
    start_y_m: float
    direction_x: float
    direction_y: float
    heading_rad: float
    length_m: float

    @classmethod
    def of(cls, lane: StraightLane) -> StraightFrame:
        return cls(float(lane.start[0]), float(lane.start[1]), float(lane.direction[0]), float(lane.direction[1]),
                   float(lane.heading), float(lane.length))

    def local_coordinates(self, x_m: float, y_m: float) -> tuple[float, float]:
        dx, dy = x_m - self.start_x_m, y_m - self.start_y_m
        return dx * self.direction_x + dy * self.direction_y, dx * -self.direction_y + dy * self.direction_x

    def heading_at(self, longitudinal_m: float) -> float:
        return self.heading_rad


@dataclass(frozen=True, slots=True)
class ArcFrame:
    """Local coordinates on one circular lane, operation for operation as highway-env's ``CircularLane``."""

    centre_x_m: float
    centre_y_m: float
    radius_m: float
    start_phase_rad: float
    direction: int  # +1: the phase grows along the lane (a left turn here), -1: it shrinks
    length_m: float

    @classmethod
    def of(cls, lane: CircularLane) -> ArcFrame:
        return cls(float(lane.center[0]), float(lane.center[1]), float(lane.radius), float(lane.start_phase),
                   int(lane.direction), float(lane.length))

    def local_coordinates(self, x_m: float, y_m: float) -> tuple[float, float]:
        dx, dy = x_m - self.centre_x_m, y_m - self.centre_y_m
        phase_rad = self.start_phase_rad + (((math.atan2(dy, dx) - self.start_phase_rad) + math.pi)
                                            % (2 * math.pi) - math.pi)
        r_m = math.sqrt(dx * dx + dy * dy)
        return self.direction * (phase_rad - self.start_phase_rad) * self.radius_m, self.direction * (self.radius_m - r_m)

    def heading_at(self, longitudinal_m: float) -> float:
        return (self.direction * longitudinal_m / self.radius_m + self.start_phase_rad) + math.pi / 2 * self.direction


@dataclass(frozen=True)
class BuiltRoad:
    network: RoadNetwork
    edges: tuple[Edge, ...]
    lane_offsets_m: tuple[float, ...]  # lateral position of each lane's centre, left positive
    # The lane the car's track coordinates are measured on (the one nearest the reference line) and
    # its scalar local-coordinate frame on every edge.
    reference_lane_id: int = 0
    reference_frames: tuple[StraightFrame | ArcFrame, ...] = ()


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
    reference_lane_id = min(range(len(offsets_m)), key=lambda i: abs(offsets_m[i]))
    frames = tuple(_frame_of(network.graph[edge.key[0]][edge.key[1]][reference_lane_id]) for edge in edges)
    return BuiltRoad(network, tuple(edges), offsets_m, reference_lane_id, frames)


def _frame_of(lane) -> StraightFrame | ArcFrame:
    return StraightFrame.of(lane) if isinstance(lane, StraightLane) else ArcFrame.of(lane)


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
