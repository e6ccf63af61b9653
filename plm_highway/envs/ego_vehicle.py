"""The ego car: highway-env's kinematic bicycle with a cheap lane tracker.

highway-env's ``Vehicle.on_state_update`` searches every lane of the network each simulation
step (~90% of step time once rendering is fast). A car on a track only ever moves from its
current road edge to the next one, so that is all we look at.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from highway_env.vehicle.kinematics import Vehicle

from plm_highway.road.builder import BuiltRoad


@dataclass(frozen=True)
class TrackCoordinates:
    arc_length_m: float  # along the reference line from the track start
    lateral_m: float  # from the reference line, left positive
    heading_error_rad: float  # car heading minus road heading, wrapped to [-pi, pi)
    edge_index: int


class TrackVehicle(Vehicle):
    """A :class:`Vehicle` that follows its position along the edges of a :class:`BuiltRoad`."""

    def __init__(self, road, position, heading: float, speed: float, built: BuiltRoad, edge_index: int = 0,
                 closed: bool = False):
        self.built = built
        self.edge_index = edge_index
        self.closed = closed
        self.past_end = False
        self.coordinates: TrackCoordinates | None = None
        offsets = built.lane_offsets_m
        self._reference_lane_id = min(range(len(offsets)), key=lambda i: abs(offsets[i]))
        super().__init__(road, position, heading, speed)

    def on_state_update(self) -> None:
        if self.road is None:
            return
        longitudinal_m, lateral_m = self._advance_edge()
        edge = self.built.edges[self.edge_index]
        lane = self._lane_of_edge(self._reference_lane_id)
        offsets = self.built.lane_offsets_m
        lateral_ref_m = lateral_m + offsets[self._reference_lane_id]
        road_heading = lane.heading_at(longitudinal_m)
        self.coordinates = TrackCoordinates(
            arc_length_m=edge.start_s_m + longitudinal_m * edge.length_m / lane.length,
            lateral_m=lateral_ref_m,
            heading_error_rad=math.remainder(self.heading - road_heading, 2 * math.pi),
            edge_index=self.edge_index,
        )
        lane_id = min(range(len(offsets)), key=lambda i: abs(lateral_ref_m - offsets[i]))
        self.lane_index = (*edge.key, lane_id)
        self.lane = self.road.network.get_lane(self.lane_index)

    def _lane_of_edge(self, lane_id: int):
        return self.road.network.graph[self.built.edges[self.edge_index].key[0]][
            self.built.edges[self.edge_index].key[1]][lane_id]

    def _advance_edge(self) -> tuple[float, float]:
        """Move to the edge the car is on; return its local (longitudinal, lateral) there."""
        n_edges = len(self.built.edges)
        for _ in range(n_edges + 1):
            lane = self._lane_of_edge(self._reference_lane_id)
            longitudinal_m, lateral_m = lane.local_coordinates(self.position)
            if longitudinal_m < lane.length:
                return longitudinal_m, lateral_m
            if self.edge_index == n_edges - 1 and not self.closed:
                self.past_end = True
                return longitudinal_m, lateral_m
            self.edge_index = (self.edge_index + 1) % n_edges
        return longitudinal_m, lateral_m
