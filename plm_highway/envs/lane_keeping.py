"""``plm_highway/LaneKeeping-v0``: keep a car in its lane on a curved track, seeing only a dashcam.

Built like highway-env's own environments: ``default_config`` declares every setting,
``_reset`` calls ``_make_road`` then ``_make_vehicles``. What differs:

- The observation is a grayscale dashcam frame from :class:`PinholeCamera`, taken *after* the
  step (highway-env's lane-keeping-v0 observes before simulating, which is one step stale).
- After every simulation step the env records a :class:`Snapshot` (frame + privileged state).
  The latency wrapper serves old snapshots from these; without it, the newest is observed.
- The ego car is a model from the vehicle-model table (``vehicle_model``: ``kinematic``, highway-env's
  bicycle and the default, ``dynamic``, a single-track car with linear tires, or ``saturating``, with tires that
  reach a friction limit; ``vehicle_params`` overrides fields of its parameter set). Its speed is a constant
  or a schedule (``speed_mps``, see :mod:`plm_highway.envs.speed`). The action is normalised steering in [-1, 1], positive turns left,
  mapped linearly to a front-wheel angle command in +-``max_steering_rad`` that reaches the wheels
  through a first-order actuator (``steering_time_constant_s``, 0 = at once).
- ``info`` and ``state()`` carry what a car's sensors measure (yaw rate, lateral acceleration,
  front-wheel steering angle, speed) besides the privileged lane coordinates.

Default rates: simulation 20 Hz and policy 20 Hz, so every latency that is a multiple of
0.05 s falls exactly on a recorded snapshot (ages are then exact); other latencies are served
by the next older snapshot, at most one simulation step (0.05 s) older than asked.

The step is written for speed without changing what it computes (``tests/test_env_golden.py``):
the vehicle, the lane tracker and the action mapping work on Python floats, frames and state
dicts are made only when read, and track look-ups are built once per track.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np
from gymnasium import spaces
from highway_env import utils
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.action import ContinuousAction
from highway_env.envs.common.observation import ObservationType
from highway_env.road.road import Road

from plm_highway.camera.ground_map import DEFAULT_MAP_PX_PER_M, ground_map
from plm_highway.camera.pinhole import PAPER_CAMERA, CameraConfig, PinholeCamera  # noqa: F401 (PAPER_CAMERA re-exported)
from plm_highway.camera.topdown import TopDownView
from plm_highway.envs.config import check_env_config, check_fixed_settings, check_start, check_unknown_keys
from plm_highway.envs.ego_vehicle import TrackVehicle
from plm_highway.envs.speed import SharpTurnBraking, SpeedSchedule, parse_sharp_turn_braking, parse_speed
from plm_highway.errors import BadInput
from plm_highway.road.builder import BuiltRoad, build_road
from plm_highway.road.geometry import SegmentLookup, reference_pose_at
from plm_highway.road.track import TrackSpec, resolve_track
from plm_highway.vehicle.models import checked_params, vehicle_model

ACTION_RANGE = (-1, 1)  # normalised steering
START_KEYS = ("start_arc_length_m", "start_offset_m", "start_heading_error_rad")  # per-episode reset options


class Snapshot:
    """What a policy may observe at one instant: the camera frame and the privileged state.

    Both are made on first access and kept: a snapshot the latency wrapper never delivers costs no
    warp, and a state dict is built once however often it is read.
    """

    __slots__ = ("time_s", "values", "_episode", "_frame", "_state")

    def __init__(self, time_s: float, values: CarValues, episode: EpisodeContext):
        self.time_s = time_s
        self.values = values
        self._episode = episode
        self._frame: np.ndarray | None = None
        self._state: dict | None = None

    @property
    def frame(self) -> np.ndarray:
        if self._frame is None:
            values = self.values
            self._frame = self._episode.camera.render(values.x_m, values.y_m, values.heading_rad)
        return self._frame

    @property
    def state(self) -> dict:
        if self._state is None:
            self._state = self._episode.state_dict(self.time_s, self.values)
        return self._state


class CarValues(NamedTuple):
    """The car at one simulation step, as the simulation left it (the inputs of a :class:`Snapshot`)."""

    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    steering_rad: float  # front-wheel angle at the wheels
    arc_length_m: float
    lateral_reference_m: float  # from the reference line, left positive
    heading_error_rad: float
    lane_index: int
    steering_command_rad: float
    lateral_velocity_mps: float  # body frame
    yaw_rate_radps: float


class EpisodeContext:
    """What turns :class:`CarValues` into a frame and a state dict; fixed for one episode."""

    def __init__(self, env: LaneKeepingCameraEnv):
        config = env.config
        self.camera = env.camera
        self.lookup = env.segment_lookup
        self.lane_offset_m = env.start_lane_offset_m
        self.max_steering_rad = float(config["max_steering_rad"])
        self.curvature_preview_s = config["curvature_preview_s"]
        self.road_half_width_m = env.track.road_half_width_m
        self.vehicle_model, self.vehicle_params = env._ego.model, env._ego.params
        self.segment_directions = [segment.direction for segment in env.track.segments]
        # The starting lane's curvature per segment (the same function of the same numbers, once).
        self.lane_curvatures_1pm = [_lane_curvature(k, self.lane_offset_m) for k in self.lookup.curvatures_1pm]

    def lane_curvature_1pm(self, s_m: float, segment_index: int | None = None) -> float:
        """Curvature of the starting lane at arc length ``s_m`` (zero off the ends of an open track)."""
        lookup = self.lookup
        if not lookup.closed and not 0.0 <= s_m <= lookup.length_m:
            return _lane_curvature(0.0, self.lane_offset_m)
        return self.lane_curvatures_1pm[lookup.segment_index(s_m) if segment_index is None else segment_index]

    def state_dict(self, time_s: float, car: CarValues) -> dict:
        # CarValues has VehicleState's fields by name: the sensor model reads it as the state.
        sensors = self.vehicle_model.sensors(car, car.steering_rad, car.speed_mps, self.vehicle_params)
        segment_index = self.lookup.segment_index(car.arc_length_m)
        curvature_1pm = self.lane_curvature_1pm(car.arc_length_m, segment_index)
        if self.curvature_preview_s == 0:
            curvature_preview_1pm = curvature_1pm
        else:
            curvature_preview_1pm = self.lane_curvature_1pm(car.arc_length_m + car.speed_mps * self.curvature_preview_s)
        return {
            "time_s": time_s,
            "x_m": car.x_m,
            "y_m": car.y_m,
            "heading_rad": car.heading_rad,
            "speed_mps": car.speed_mps,
            "steering": car.steering_rad / self.max_steering_rad,
            "arc_length_m": car.arc_length_m,
            "lateral_offset_m": car.lateral_reference_m - self.lane_offset_m,
            "heading_error_rad": car.heading_error_rad,
            # The car's velocity points at heading + slip angle: tracking this course angle, not the
            # heading, is what leaves no steady offset in curves.
            "course_error_rad": car.heading_error_rad + sensors.slip_angle_rad,
            "curvature_1pm": curvature_1pm,
            "curvature_preview_1pm": curvature_preview_1pm,
            "segment": self.segment_directions[segment_index],
            "segment_index": segment_index,
            "lane_index": car.lane_index,
            "on_road": abs(car.lateral_reference_m) <= self.road_half_width_m,
            # What the car's own sensors read (IMU at the reference point, steering-angle sensor).
            "steering_command": car.steering_command_rad / self.max_steering_rad,
            "steering_angle_rad": car.steering_rad,
            "yaw_rate_radps": sensors.yaw_rate_radps,
            "lateral_acceleration_mps2": sensors.lateral_acceleration_mps2,
            "lateral_velocity_mps": car.lateral_velocity_mps,
        }


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
            "speed_mps": 16.7,  # about 60 km/h, the paper's test speed; or [[time_s, speed_mps], ...]
            # None: the speed follows speed_mps. A dict of SharpTurnBraking fields ({}: the original's values): the
            # original run scripts' throttle-and-brake logic, starting at speed_mps (a number).
            "sharp_turn_braking": None,
            "max_steering_rad": 0.2,  # front-wheel angle at action +-1
            "steering_time_constant_s": 0.0,  # first-order steering actuator; 0 = the wheels follow at once
            # Policy steps between an action and the actuator receiving it (the original pipeline's 1-2 frames of
            # processing); the car holds the previous command meanwhile. 0 = the action is applied at once.
            "processing_delay_steps": 0,
            "vehicle_model": "kinematic",  # a name in plm_highway.vehicle.models.VEHICLE_MODELS
            "vehicle_params": {},  # overrides of the model's default parameters, e.g. {"mass_kg": 1600}
            "simulation_frequency": 20,  # [Hz]
            "policy_frequency": 20,  # [Hz]
            "camera": {},  # overrides of CameraConfig fields, e.g. {"pitch_deg": 8}
            "map_px_per_m": DEFAULT_MAP_PX_PER_M,  # ground map resolution (see camera/ground_map.py)
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

    def configure(self, config: dict) -> None:
        if config is not None and not isinstance(config, dict):
            raise BadInput(f"config: must be a dict of settings, got {type(config).__name__}")
        super().configure(config)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if options is not None and not isinstance(options, dict):
            raise BadInput(f"reset options: must be a dict, got {type(options).__name__}")
        if options and "config" in options and not isinstance(options["config"], dict):
            raise BadInput(f"reset options['config']: must be a dict of settings, got "
                           f"{type(options['config']).__name__}")
        self._start_overrides = {k: v for k, v in (options or {}).items() if k in START_KEYS}
        unknown = sorted(set(options or {}) - set(self._start_overrides) - {"config"})
        if unknown:
            raise BadInput(f"reset options: unknown keys {unknown}")
        return super().reset(seed=seed, options=options)

    def define_spaces(self) -> None:
        # Called by highway-env before every reset builds anything: the place to refuse bad settings.
        defaults = self.default_config()
        check_unknown_keys(self.config, defaults)
        check_fixed_settings(self.config, defaults)
        check_env_config(self.config)
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
        self._make_road()
        self._make_vehicles()
        self._sim_hz = self.config["simulation_frequency"]
        self._substeps = self._sim_hz // self.config["policy_frequency"]
        self._simulation_dt_s = 1.0 / self._sim_hz
        self._policy_dt_s = 1 / self.config["policy_frequency"]
        self._duration_s = self.config["duration_s"]
        self._half_lane_m = self.track.lane_width_m / 2
        self._max_steering_rad = float(self.config["max_steering_rad"])
        self._steering_range_rad = [-self._max_steering_rad, self._max_steering_rad]
        self._pending_commands_rad = deque([0.0] * self.config["processing_delay_steps"])
        self._episode = EpisodeContext(self)
        self.new_snapshots: list[Snapshot] = []
        self._record_snapshot()

    def _make_road(self) -> None:
        track = self._track_from_config()
        if getattr(self, "track", None) != track:
            self.track: TrackSpec = track
            self.built: BuiltRoad = build_road(track)
            self.segment_lookup = SegmentLookup(track)
            self.track_length_m = track.length_m
            self.ground = ground_map(track, float(self.config["map_px_per_m"]))
        camera_config = CameraConfig.from_dict(self.config["camera"])
        if getattr(self, "camera", None) is None or self.camera.config != camera_config \
                or self.camera.ground is not self.ground:
            self.camera = PinholeCamera(self.ground, camera_config)
        self.road = Road(network=self.built.network, np_random=self.np_random, record_history=False)

    def _make_vehicles(self) -> None:
        start = {key: self.config[key] for key in START_KEYS}
        start.update(self._start_overrides)
        check_start(start, self.track, self.built.lane_offsets_m, self.config["start_lane"], self._start_overrides)
        arc_length_m = float(start["start_arc_length_m"])
        x_m, y_m, road_heading = reference_pose_at(self.track, arc_length_m)
        lateral_m = self.start_lane_offset_m + float(start["start_offset_m"])
        position = np.array([x_m - lateral_m * math.sin(road_heading), y_m + lateral_m * math.cos(road_heading)])
        edge_index = max(i for i, edge in enumerate(self.built.edges) if edge.start_s_m <= arc_length_m + 1e-9)
        self.speed_schedule: SpeedSchedule = parse_speed(self.config["speed_mps"])
        self.sharp_turn_braking: SharpTurnBraking | None = parse_sharp_turn_braking(self.config["sharp_turn_braking"])
        if self.sharp_turn_braking is not None and not self.speed_schedule.constant:
            raise BadInput("config['sharp_turn_braking']: needs a constant speed_mps (the start speed), not a schedule")
        self._braking_until_s = -math.inf
        model = vehicle_model(self.config["vehicle_model"])
        vehicle = TrackVehicle(
            self.road, position, road_heading + float(start["start_heading_error_rad"]),
            self.speed_schedule.speed_at(0.0), self.built, edge_index, self.track.closed, model,
            checked_params(model, self.config["vehicle_params"], "config['vehicle_params']"), float(self.config["steering_time_constant_s"]),
        )
        vehicle.on_state_update()
        self.road.vehicles.append(vehicle)
        self.vehicle = vehicle
        self._ego = vehicle  # the same car, without highway-env's property lookup in the hot path

    def _track_from_config(self) -> TrackSpec:
        return resolve_track(self.config["track"], source="config['track']")

    @property
    def start_lane(self) -> int:
        lane = self.config["start_lane"]
        return self.track.lanes // 2 if lane is None else lane

    @property
    def start_lane_offset_m(self) -> float:
        return self.built.lane_offsets_m[self.start_lane]

    @property
    def simulation_dt_s(self) -> float:
        return 1.0 / self.config["simulation_frequency"]

    # -- stepping --------------------------------------------------------------------------------

    def step(self, action):
        """One policy step: map the action to a steering angle, simulate, observe the newest frame."""
        steering_rad = self._steering_command_rad(action)
        if self._pending_commands_rad:
            self._pending_commands_rad.append(steering_rad)
            steering_rad = self._pending_commands_rad.popleft()
        if self.sharp_turn_braking is not None:
            self._braking_until_s = self.sharp_turn_braking.decide(self._braking_until_s, self.time,
                                                                   self._ego.speed, steering_rad)
        self.time += self._policy_dt_s
        self._simulate(steering_rad)
        snapshot = self.latest_snapshot
        obs = snapshot.frame
        rewards = self._rewards(action)
        info = self._info(obs, action, rewards)
        return obs, rewards["lane_centering"], not info["on_road"], self._is_truncated(), info

    def _steering_command_rad(self, action) -> float:
        """Front-wheel angle for a normalised action, as highway-env's ``ContinuousAction`` maps it:
        clipped to [-1, 1] and mapped linearly in the action's own dtype (float32 actions give
        float32-rounded angles, exactly as before). Anything but one finite number is refused: a
        policy that produces NaN must stop the run, and a (1, 1) or (2,) action is a bug upstream.

        The action space is a float Box: a NumPy array must hold floats (an integer array, uint8 above all, would
        wrap around in the mapping); a plain list or tuple of Python numbers is read as float64, as gymnasium's
        ``Box.contains`` reads it."""
        array = np.asarray(action)
        if array.shape != (1,) or array.dtype.kind not in "fiu":
            raise BadInput(f"action {_short(action)}: expected one number (normalised steering in [-1, 1]) in "
                             f"an array of shape (1,), got shape {array.shape} and dtype {array.dtype}")
        if array.dtype.kind in "iu":
            if isinstance(action, np.ndarray):
                raise BadInput(f"action {_short(action)}: the action space is Box(-1, 1, (1,), float32); got an "
                               f"integer array of dtype {array.dtype}. Pass floats, e.g. np.array([0.0], np.float32) "
                               f"or action.astype(np.float32)")
            array = array.astype(np.float64)
        value = array[0]
        if not math.isfinite(value):
            raise BadInput(f"action {_short(action)}: steering must be finite; the policy produced {value}")
        if value < -1:
            value = value.dtype.type(-1)
        elif value > 1:
            value = value.dtype.type(1)
        return float(utils.lmap(value, ACTION_RANGE, self._steering_range_rad))

    def _simulate(self, steering_rad: float | None = None) -> None:
        vehicle = self._ego
        dt_s = self._simulation_dt_s
        self.new_snapshots = []
        if steering_rad is not None:  # held over the policy step
            vehicle.steering_command_rad = steering_rad
        schedule = None if self.speed_schedule.constant else self.speed_schedule
        braking_logic = self.sharp_turn_braking
        for _ in range(self._substeps):
            if braking_logic is not None:
                braking = self.steps / self._sim_hz < self._braking_until_s
                vehicle.step(dt_s, braking_logic.speed_after(vehicle.speed, braking, dt_s))
            else:
                vehicle.step(dt_s, None if schedule is None else schedule.speed_at((self.steps + 1) / self._sim_hz))
            self.steps += 1
            self._record_snapshot()

    def _record_snapshot(self) -> None:
        v = self._ego
        state = v.model_state
        snapshot = Snapshot(self.steps / self._sim_hz, CarValues(
            v.x_m, v.y_m, v.heading, v.speed, v.steering_rad, v.arc_length_m, v.lateral_m, v.heading_error_rad, v.lane_id,
            v.steering_command_rad, state[3], state[4],
        ), self._episode)
        self.latest_snapshot = snapshot
        self.new_snapshots.append(snapshot)

    def _render_camera(self) -> np.ndarray:
        return self.latest_snapshot.frame

    def state(self) -> dict:
        """The privileged state of the ego car now, relative to the centre of its starting lane."""
        return dict(self.latest_snapshot.state)

    # -- task ------------------------------------------------------------------------------------

    def _rewards(self, action) -> dict[str, float]:
        # From the car's values, as the state dict computes them (the dict itself is built only for info).
        car, episode = self.latest_snapshot.values, self._episode
        on_road = abs(car.lateral_reference_m) <= episode.road_half_width_m
        lateral_offset_m = car.lateral_reference_m - episode.lane_offset_m
        centring = max(0.0, 1.0 - (lateral_offset_m / self._half_lane_m) ** 2) if on_road else 0.0
        return {"lane_centering": centring, "on_road": float(on_road)}

    def _reward(self, action) -> float:
        return self._rewards(action)["lane_centering"]

    def _is_terminated(self) -> bool:
        car = self.latest_snapshot.values
        return not abs(car.lateral_reference_m) <= self._episode.road_half_width_m

    def _is_truncated(self) -> bool:
        duration_s = self._duration_s
        timed_out = duration_s is not None and self.latest_snapshot.time_s >= duration_s - 1e-9
        return bool(self._ego.past_end or timed_out)

    def _info(self, obs, action=None, rewards: dict | None = None) -> dict:
        """The state now plus highway-env's usual keys; a new dict (the snapshot's own state dict is
        built only if something asks for it, e.g. the latency wrapper delivering this snapshot later)."""
        snapshot = self.latest_snapshot
        car = snapshot.values
        info = self._episode.state_dict(snapshot.time_s, car)
        info["position"] = np.array([car.x_m, car.y_m])
        info["time"] = snapshot.time_s
        info["speed"] = car.speed_mps
        info["completed_fraction"] = min(1.0, car.arc_length_m / self.track_length_m)
        info["rewards"] = self._rewards(action) if rewards is None else rewards
        return info


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _lane_curvature(reference_curvature_1pm: float, lane_offset_m: float) -> float:
    """Curvature of a line ``lane_offset_m`` to the left of a reference line of the given curvature."""
    return reference_curvature_1pm / (1.0 - reference_curvature_1pm * lane_offset_m)
