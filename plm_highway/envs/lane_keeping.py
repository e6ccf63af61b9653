"""``plm_highway/LaneKeeping-v0``: keep a car in its lane on a curved track, seeing only a dashcam.

Built like highway-env's own environments: ``default_config`` declares every setting,
``_reset`` calls ``_make_road`` then ``_make_vehicles``. What differs:

- The observation is a grayscale dashcam frame from :class:`PinholeCamera`, taken *after* the
  step (highway-env's lane-keeping-v0 observes before simulating, which is one step stale).
- After every simulation step the env records a :class:`Snapshot` (frame + privileged state).
  The latency wrapper serves old snapshots from these; without it, the newest is observed.
- Speed is constant; the action is normalised steering in [-1, 1], positive turns left,
  mapped linearly to the front-wheel angle range +-``max_steering_rad``.

Default rates: simulation 20 Hz and policy 20 Hz, so every latency that is a multiple of
0.05 s falls exactly on a recorded snapshot (ages are then exact); other latencies are served
by the next older snapshot, at most one simulation step (0.05 s) older than asked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.action import ContinuousAction
from highway_env.envs.common.observation import ObservationType
from highway_env.road.road import Road

from plm_highway.camera.ground_map import ground_map
from plm_highway.camera.pinhole import CameraConfig, PinholeCamera
from plm_highway.camera.topdown import TopDownView
from plm_highway.envs.ego_vehicle import TrackVehicle
from plm_highway.road.builder import BuiltRoad, build_road
from plm_highway.road.geometry import reference_pose_at, segment_lookup
from plm_highway.road.track import TrackSpec, load_track, parse_track

PAPER_CAMERA = {"height_px": 160, "width_px": 160}  # the original PLM-Net input size
START_KEYS = ("start_arc_length_m", "start_offset_m", "start_heading_error_rad")  # per-episode reset options


@dataclass(frozen=True)
class Snapshot:
    """What a policy may observe at one instant: the camera frame and the privileged state."""

    time_s: float
    frame: np.ndarray
    state: dict


class DashCameraObservation(ObservationType):
    """The newest camera frame the env recorded."""

    def __init__(self, env: LaneKeepingCameraEnv) -> None:
        super().__init__(env)
        camera = env.camera_config
        self.shape = (camera.height_px, camera.width_px)

    def space(self) -> spaces.Space:
        return spaces.Box(low=0, high=255, shape=self.shape, dtype=np.uint8)

    def observe(self) -> np.ndarray:
        return self.env.latest_snapshot.frame


class LaneKeepingCameraEnv(AbstractEnv):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update({
            # The observation and action types are fixed by this env (see define_spaces).
            "observation": {"type": "DashCamera"},
            "action": {"type": "ContinuousAction", "lateral": True, "longitudinal": False},
            "track": "test",  # shipped name, path to a JSON spec, or a spec dict
            "start_lane": None,  # lane index (0 = leftmost); None = the middle lane
            "speed_mps": 16.7,  # about 60 km/h, the paper's test speed
            "max_steering_rad": 0.2,  # front-wheel angle at action +-1
            "simulation_frequency": 20,  # [Hz]
            "policy_frequency": 20,  # [Hz]
            "camera": {},  # overrides of CameraConfig fields, e.g. {"pitch_deg": 8}
            "map_px_per_m": 10.0,
            "duration_s": None,  # None: until the end of an open track
            "curvature_preview_s": 0.0,  # look-ahead of the privileged curvature preview (0: none; best for the expert)
            # Start pose; reset(options={...}) may override each for one episode.
            "start_arc_length_m": 0.0,
            "start_offset_m": 0.0,
            "start_heading_error_rad": 0.0,
            "screen_width": 480,
            "screen_height": 360,
            "scaling": 4.0,  # top-down render, pixels per metre
        })
        return config

    # -- gymnasium API ---------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._start_overrides = {k: v for k, v in (options or {}).items() if k in START_KEYS}
        unknown = sorted(set(options or {}) - set(self._start_overrides) - {"config"})
        if unknown:
            raise ValueError(f"reset options: unknown keys {unknown}")
        return super().reset(seed=seed, options=options)

    def define_spaces(self) -> None:
        self.camera_config = CameraConfig.from_dict(self.config["camera"])
        self.observation_type = DashCameraObservation(self)
        max_steer = float(self.config["max_steering_rad"])
        self.action_type = ContinuousAction(
            self, longitudinal=False, lateral=True, steering_range=(-max_steer, max_steer), clip=True
        )
        self.observation_space = self.observation_type.space()
        self.action_space = self.action_type.space()

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if getattr(self, "_top_down", None) is None or self._top_down.ground is not self.ground:
            self._top_down = TopDownView(
                self.ground, self.config["screen_width"], self.config["screen_height"], self.config["scaling"]
            )
        vehicle = self.vehicle
        return self._top_down.render(vehicle.position[0], vehicle.position[1], vehicle.heading)

    # -- scene -----------------------------------------------------------------------------------

    def _reset(self) -> None:
        self._check_rates()
        self._make_road()
        self._make_vehicles()
        self.new_snapshots: list[Snapshot] = []
        self._record_snapshot()

    def _make_road(self) -> None:
        track = self._track_from_config()
        if getattr(self, "track", None) != track:
            self.track: TrackSpec = track
            self.built: BuiltRoad = build_road(track)
            self.ground = ground_map(track, float(self.config["map_px_per_m"]))
        camera_config = CameraConfig.from_dict(self.config["camera"])
        if getattr(self, "camera", None) is None or self.camera.config != camera_config \
                or self.camera.ground is not self.ground:
            self.camera = PinholeCamera(self.ground, camera_config)
        self.road = Road(network=self.built.network, np_random=self.np_random, record_history=False)

    def _make_vehicles(self) -> None:
        start = {key: self.config[key] for key in START_KEYS}
        start.update(self._start_overrides)
        arc_length_m = float(start["start_arc_length_m"])
        x_m, y_m, road_heading = reference_pose_at(self.track, arc_length_m)
        lateral_m = self.start_lane_offset_m + float(start["start_offset_m"])
        position = np.array([x_m - lateral_m * math.sin(road_heading), y_m + lateral_m * math.cos(road_heading)])
        edge_index = max(i for i, edge in enumerate(self.built.edges) if edge.start_s_m <= arc_length_m + 1e-9)
        vehicle = TrackVehicle(
            self.road, position, road_heading + float(start["start_heading_error_rad"]),
            float(self.config["speed_mps"]), self.built, edge_index, self.track.closed,
        )
        vehicle.on_state_update()
        self.road.vehicles.append(vehicle)
        self.vehicle = vehicle

    def _track_from_config(self) -> TrackSpec:
        track = self.config["track"]
        if isinstance(track, TrackSpec):
            return track
        if isinstance(track, dict):
            return parse_track(track, source="config['track']")
        return load_track(track)

    def _check_rates(self) -> None:
        sim_hz, policy_hz = self.config["simulation_frequency"], self.config["policy_frequency"]
        if not (isinstance(sim_hz, int) and isinstance(policy_hz, int) and sim_hz > 0 and policy_hz > 0
                and sim_hz % policy_hz == 0):
            raise ValueError(
                f"simulation_frequency={sim_hz!r} must be a positive integer multiple of policy_frequency={policy_hz!r}"
            )

    @property
    def start_lane(self) -> int:
        lane = self.config["start_lane"]
        return self.track.lanes // 2 if lane is None else int(lane)

    @property
    def start_lane_offset_m(self) -> float:
        return self.built.lane_offsets_m[self.start_lane]

    @property
    def simulation_dt_s(self) -> float:
        return 1.0 / self.config["simulation_frequency"]

    # -- stepping --------------------------------------------------------------------------------

    def _simulate(self, action=None) -> None:
        frames = self.config["simulation_frequency"] // self.config["policy_frequency"]
        self.new_snapshots = []
        for frame in range(frames):
            if action is not None and frame == 0:
                self.action_type.act(action)
            self.road.act()
            self.road.step(self.simulation_dt_s)
            self.steps += 1
            self._record_snapshot()

    def _record_snapshot(self) -> None:
        snapshot = Snapshot(self.steps / self.config["simulation_frequency"], self._render_camera(), self.state())
        self.latest_snapshot = snapshot
        self.new_snapshots.append(snapshot)

    def _render_camera(self) -> np.ndarray:
        vehicle = self.vehicle
        return self.camera.render(vehicle.position[0], vehicle.position[1], vehicle.heading)

    def state(self) -> dict:
        """The privileged state of the ego car now, relative to the centre of its starting lane."""
        vehicle = self.vehicle
        coords = vehicle.coordinates
        speed_mps = float(vehicle.speed)
        steering_rad = float(vehicle.action.get("steering", 0.0))
        lane_offset_m = self.start_lane_offset_m
        lookup = segment_lookup(self.track)
        segment_index = lookup.segment_index(coords.arc_length_m)
        preview_s_m = coords.arc_length_m + speed_mps * self.config["curvature_preview_s"]
        return {
            "time_s": self.steps / self.config["simulation_frequency"],
            "x_m": float(vehicle.position[0]),
            "y_m": float(vehicle.position[1]),
            "heading_rad": float(vehicle.heading),
            "speed_mps": speed_mps,
            "steering": steering_rad / self.config["max_steering_rad"],
            "arc_length_m": coords.arc_length_m,
            "lateral_offset_m": coords.lateral_m - lane_offset_m,
            "heading_error_rad": coords.heading_error_rad,
            # The bicycle's velocity points at heading + beta: tracking this course angle, not the
            # heading, is what leaves no steady offset in curves.
            "course_error_rad": coords.heading_error_rad + math.atan(0.5 * math.tan(steering_rad)),
            "curvature_1pm": _lane_curvature(lookup.curvature(coords.arc_length_m), lane_offset_m),
            "curvature_preview_1pm": _lane_curvature(lookup.curvature(preview_s_m), lane_offset_m),
            "segment": self.track.segments[segment_index].direction,
            "segment_index": segment_index,
            "lane_index": int(vehicle.lane_index[2]),
            "on_road": abs(coords.lateral_m) <= self.track.road_half_width_m,
        }

    # -- task ------------------------------------------------------------------------------------

    def _rewards(self, action) -> dict[str, float]:
        state = self.latest_snapshot.state
        half_lane_m = self.track.lane_width_m / 2
        centring = max(0.0, 1.0 - (state["lateral_offset_m"] / half_lane_m) ** 2) if state["on_road"] else 0.0
        return {"lane_centering": centring, "on_road": float(state["on_road"])}

    def _reward(self, action) -> float:
        return self._rewards(action)["lane_centering"]

    def _is_terminated(self) -> bool:
        return not self.latest_snapshot.state["on_road"]

    def _is_truncated(self) -> bool:
        duration_s = self.config["duration_s"]
        timed_out = duration_s is not None and self.latest_snapshot.time_s >= duration_s - 1e-9
        return bool(self.vehicle.past_end or timed_out)

    def _info(self, obs, action=None) -> dict:
        state = self.latest_snapshot.state
        info = dict(state)
        info.update({
            "position": np.array([state["x_m"], state["y_m"]]),
            "time": state["time_s"],
            "speed": state["speed_mps"],
            "completed_fraction": min(1.0, state["arc_length_m"] / self.track.length_m),
            "rewards": self._rewards(action),
        })
        return info


def _lane_curvature(reference_curvature_1pm: float, lane_offset_m: float) -> float:
    """Curvature of a line ``lane_offset_m`` to the left of a reference line of the given curvature."""
    return reference_curvature_1pm / (1.0 - reference_curvature_1pm * lane_offset_m)
