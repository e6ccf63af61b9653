"""The ego car: a vehicle model from :mod:`plm_highway.vehicle.models` with a cheap lane tracker.

highway-env's ``Vehicle.on_state_update`` searches every lane of the network each simulation
step (~90% of step time once rendering is fast). A car on a track only ever moves from its
current road edge to the next one, so that is all we look at, with the scalar lane frames of
:class:`BuiltRoad` (highway-env's lane arithmetic, without numpy on two-element arrays).

The class stays a highway-env ``Vehicle`` (the env's road, top-down view and ``env.vehicle`` work
as in highway-env), but its state is held in Python floats and stepped by the model's pure step
function: numpy on scalars cost more than the physics.

Steering: the commanded front-wheel angle reaches the wheels through a first-order actuator with
time constant ``steering_time_constant_s`` (0: at once, highway-env's behaviour), integrated exactly
over each step (``delta_end = command + (delta_start - command) exp(-dt / tau)``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from highway_env.vehicle.kinematics import Vehicle

from plm_highway.road.builder import BuiltRoad
from plm_highway.vehicle.models import VEHICLE_MODELS, VehicleModel, VehicleState


class TrackCoordinates(NamedTuple):
    arc_length_m: float  # along the reference line from the track start
    lateral_m: float  # from the reference line, left positive
    heading_error_rad: float  # car heading minus road heading, wrapped to [-pi, pi)
    edge_index: int


class TrackVehicle(Vehicle):
    """A :class:`Vehicle` that follows its position along the edges of a :class:`BuiltRoad`."""

    def __init__(self, road, position, heading: float, speed: float, built: BuiltRoad, edge_index: int = 0,
                 closed: bool = False, model: VehicleModel = VEHICLE_MODELS["kinematic"], params=None,
                 steering_time_constant_s: float = 0.0):
        self.built = built
        self.edge_index = edge_index
        self.closed = closed
        self.past_end = False
        self.model = model
        self.params = model.default_params if params is None else params
        self._model_step = model.step
        self.steering_time_constant_s = float(steering_time_constant_s)
        self.steering_command_rad = 0.0  # front-wheel angle asked for
        self.steering_rad = 0.0  # front-wheel angle at the wheels now
        self._frames = built.reference_frames
        self._reference_offset_m = built.lane_offsets_m[built.reference_lane_id]
        self._lane_offsets_m = built.lane_offsets_m
        self._edges = built.edges
        # Track coordinates after the last update (see :attr:`coordinates`).
        self.arc_length_m = self.lateral_m = self.heading_error_rad = math.nan
        self.lane_id = 0
        super().__init__(road, position, float(heading), float(speed))
        self.model_state: VehicleState = model.initial_state(self.x_m, self.y_m, self.heading, 0.0, self.speed,
                                                             self.params)

    @property
    def coordinates(self) -> TrackCoordinates:
        return TrackCoordinates(self.arc_length_m, self.lateral_m, self.heading_error_rad, self.edge_index)

    # highway-env's lane attributes, derived from the tracker on demand (nothing in the step reads them).
    @property
    def lane_index(self) -> tuple[str, str, int]:
        return (*self.built.edges[self.edge_index].key, self.lane_id)

    @lane_index.setter
    def lane_index(self, value) -> None:
        """Set by highway-env's constructor from a search of every lane; the tracker decides instead."""

    @property
    def lane(self):
        start, end, lane_id = self.lane_index
        return self.road.network.graph[start][end][lane_id]

    @lane.setter
    def lane(self, value) -> None:
        """Set by highway-env's constructor; derived from :attr:`lane_index` instead."""

    # Position as two floats: the hot path reads and writes them every simulation step.
    @property
    def position(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m])

    @position.setter
    def position(self, value) -> None:
        self.x_m, self.y_m = float(value[0]), float(value[1])

    def step(self, dt: float, speed_end_mps: float | None = None) -> None:
        """Advance by one simulation step: the actuator, then the model from this step's speed to
        ``speed_end_mps`` (default: unchanged), then the track coordinates."""
        command_rad = self.steering_command_rad
        if self.steering_time_constant_s == 0.0:
            steer_start_rad = steer_end_rad = command_rad
        else:
            steer_start_rad = self.steering_rad
            steer_end_rad = command_rad + (steer_start_rad - command_rad) * math.exp(-dt / self.steering_time_constant_s)
        speed_start_mps = self.speed
        speed_end_mps = speed_start_mps if speed_end_mps is None else speed_end_mps
        state = self._model_step(self.model_state, steer_start_rad, steer_end_rad, speed_start_mps, speed_end_mps,
                                 dt, self.params)
        self.model_state = state
        self.x_m, self.y_m, self.heading = state[0], state[1], state[2]
        self.steering_rad, self.speed = steer_end_rad, speed_end_mps
        self.on_state_update()

    def on_state_update(self) -> None:
        if self.road is None:
            return
        frame = self._frames[self.edge_index]
        longitudinal_m, lateral_m = frame.local_coordinates(self.x_m, self.y_m)
        if not longitudinal_m < frame.length_m:  # rarely: the car left this edge
            longitudinal_m, lateral_m = self._advance_edge()
            frame = self._frames[self.edge_index]
        edge = self._edges[self.edge_index]
        lateral_ref_m = lateral_m + self._reference_offset_m
        self.arc_length_m = edge.start_s_m + longitudinal_m * edge.length_m / frame.length_m
        self.lateral_m = lateral_ref_m
        self.heading_error_rad = math.remainder(self.heading - frame.heading_at(longitudinal_m), 2 * math.pi)
        # The nearest lane centre; on a tie the lower index, as min() would pick.
        offsets_m = self._lane_offsets_m
        lane_id, nearest_m = 0, abs(lateral_ref_m - offsets_m[0])
        for index in range(1, len(offsets_m)):
            distance_m = abs(lateral_ref_m - offsets_m[index])
            if distance_m < nearest_m:
                lane_id, nearest_m = index, distance_m
        self.lane_id = lane_id

    def _advance_edge(self) -> tuple[float, float]:
        """Move to the edge the car is on; return its local (longitudinal, lateral) there."""
        n_edges = len(self._frames)
        for _ in range(n_edges + 1):
            frame = self._frames[self.edge_index]
            longitudinal_m, lateral_m = frame.local_coordinates(self.x_m, self.y_m)
            if longitudinal_m < frame.length_m:
                return longitudinal_m, lateral_m
            if self.edge_index == n_edges - 1 and not self.closed:
                self.past_end = True
                return longitudinal_m, lateral_m
            self.edge_index = (self.edge_index + 1) % n_edges
        return longitudinal_m, lateral_m
