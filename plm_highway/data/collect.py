"""``plm-highway collect``: record expert demonstrations, with recovery, for imitation learning.

A policy trained only on perfect driving has never seen the car off-centre, so it drifts off
once its own errors accumulate. Most episodes therefore start displaced (lateral offset and
heading error drawn at random) and record the expert bringing the car back; each frame is
labelled with the expert's action for that frame's true state, and the car executes that same
action. Every displacement starts a new episode, so future-action labels never span a jump.

Who drives and how the car is set up follow ``conditions`` (``--conditions``): ``ideal`` records the
noise-free expert at 20 Hz with the default camera; ``paper`` records the human-like demonstrator
(:mod:`plm_highway.expert.human`) at the paper's 30 Hz loop, with its steering actuator and the original
camera. ``--camera`` and ``--demonstrator`` override either choice. The label is what the driver's hand
did at that frame, and the car executes it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import gymnasium
import numpy as np
from tqdm import tqdm

from plm_highway.camera.pinhole import PAPER_CAMERA
from plm_highway.data.dataset import STEP_COLUMNS
from plm_highway.errors import BadInput
from plm_highway.expert import ExpertPolicy, HumanDemonstrator
from plm_highway.expert.controller import ExpertParams
from plm_highway.expert.human import HumanParams
from plm_highway.models.config_checks import check_choice, check_int, check_number
from plm_highway.rollout.conditions import CONDITIONS

DEMONSTRATOR_STREAM = 13  # the human demonstrator draws from np.random.default_rng([seed, DEMONSTRATOR_STREAM])
RECOVERY_WINDOW_S = 2.0  # frames this soon after a displaced start are flagged `perturbed`
MAX_EPISODES = 100_000
MAX_EPISODE_S = 3600.0
MAX_SPEED_MPS = 70.0
MAX_HEADING_ERROR_DEG = 45.0
MAX_SEED = 2**63 - 1
# Frames are held in memory until the dataset is written (about 13 kB each at 66x200 px).
MAX_FRAMES_BYTES = 8 * 1024**3


@dataclass(frozen=True)
class CollectConfig:
    """What ``collect`` records; bounds are checked here (named as the command line spells them).

    ``episodes`` in [1, 100000], ``episode_seconds`` in (0, 3600], ``displaced_fraction`` in [0, 1],
    ``max_offset_m`` >= 0 and small enough that the car starts on the road (checked against the
    track: at most the road half width minus the start lane's offset), ``max_heading_error_deg`` in
    [0, 45], ``speed_mps`` in (0, 70], ``seed`` in [0, 2**63 - 1]; the frames of the whole run
    (episodes x steps x frame size) at most :data:`MAX_FRAMES_BYTES`.
    """

    episodes: int = 200
    episode_seconds: float = 8.0
    displaced_fraction: float = 0.7
    max_offset_m: float = 1.5
    max_heading_error_deg: float = 6.0
    speed_mps: float = 16.7
    conditions: str = "ideal"
    camera: str | None = None  # None: the conditions' camera (ideal: default, paper: the original's)
    demonstrator: str | None = None  # None: the conditions' demonstrator (ideal: expert, paper: human)
    seed: int = 0

    def __post_init__(self) -> None:
        check_int("--episodes", self.episodes, 1, MAX_EPISODES)
        check_number("--episode-seconds", self.episode_seconds, 0.0, MAX_EPISODE_S, low_open=True)
        check_number("--displaced-fraction", self.displaced_fraction, 0.0, 1.0)
        check_number("--max-offset-m", self.max_offset_m, 0.0, math.inf, high_open=True)
        check_number("--max-heading-error-deg", self.max_heading_error_deg, 0.0, MAX_HEADING_ERROR_DEG)
        check_number("--speed-mps", self.speed_mps, 0.0, MAX_SPEED_MPS, low_open=True)
        check_choice("--conditions", self.conditions, tuple(CONDITIONS))
        if self.camera is not None:
            check_choice("--camera", self.camera, CAMERAS)
        if self.demonstrator is not None:
            check_choice("--demonstrator", self.demonstrator, DEMONSTRATORS)
        check_int("--seed", self.seed, 0, MAX_SEED)


CAMERAS = ("default", "paper")
DEMONSTRATORS = ("expert", "human")


def recording_setup(config: CollectConfig) -> tuple[dict, str]:
    """(env config, demonstrator name) that ``config`` records with: the loop rates and steering actuator of
    its conditions, its camera and demonstrator unless overridden. The processing delay of the conditions is
    left out: it belongs to the trained model's pipeline, not to the driver at the wheel."""
    conditions = CONDITIONS[config.conditions]
    camera_name = config.camera or ("paper" if conditions.camera else "default")
    env_config = {"speed_mps": config.speed_mps, "camera": dict(PAPER_CAMERA) if camera_name == "paper" else {},
                  "policy_frequency": conditions.policy_frequency_hz,
                  "simulation_frequency": conditions.simulation_frequency_hz,
                  "steering_time_constant_s": conditions.steering_time_constant_s,
                  "max_steering_rad": conditions.max_steering_rad, "vehicle_model": conditions.vehicle_model,
                  "vehicle_params": dict(conditions.vehicle_params)}
    return env_config, config.demonstrator or conditions.demonstrator


def make_demonstrator(name: str, policy_frequency_hz: float, rng: np.random.Generator, max_steering_rad: float = 0.2):
    """The demonstrator, told the car's steering range (its commands are fractions of it)."""
    if name == "human":
        return HumanDemonstrator(policy_frequency_hz, replace(HumanParams(), max_steering_rad=max_steering_rad), rng)
    return ExpertPolicy(ExpertParams(max_steering_rad=max_steering_rad))


def collect(track: str = "train", progress: bool = True, config: CollectConfig | None = None,
            **fields) -> tuple[np.ndarray, dict, dict]:
    """Drive the expert episodes of ``config`` (its fields may be given as keywords); return
    (frames, step columns, manifest). Every argument is checked before the first episode."""
    config = replace(config or CollectConfig(), **fields)
    env_config, demonstrator_name = recording_setup(config)
    env = gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": track, **env_config})
    unwrapped = env.unwrapped
    env.reset(seed=config.seed)
    rng = np.random.default_rng(config.seed)
    # Its own stream: the episode starts drawn from `rng` stay those of an expert recording with this seed.
    expert = make_demonstrator(demonstrator_name, unwrapped.config["policy_frequency"],
                               np.random.default_rng([config.seed, DEMONSTRATOR_STREAM]),
                               unwrapped.config["max_steering_rad"])
    track_spec = unwrapped.track
    steps_per_episode = int(round(config.episode_seconds * unwrapped.config["policy_frequency"]))
    frame_shape = env.observation_space.shape
    _check_against_track(config, track, track_spec, unwrapped.start_lane_offset_m)
    max_rows = config.episodes * steps_per_episode
    if max_rows * int(np.prod(frame_shape)) > MAX_FRAMES_BYTES:
        raise BadInput(
            f"--episodes {config.episodes} x --episode-seconds {config.episode_seconds:g}: {max_rows} frames of "
            f"{frame_shape[0]}x{frame_shape[1]} px exceed the {MAX_FRAMES_BYTES / 1024**3:g} GiB a dataset may hold"
        )
    usable_length_m = track_spec.length_m - config.speed_mps * config.episode_seconds
    # Filled in place (not a list stacked at the end): the peak memory is the dataset's own size.
    frames = np.empty((max_rows, *frame_shape), dtype=np.uint8)
    n_rows = 0
    columns: dict[str, list] = {name: [] for name in STEP_COLUMNS}
    for episode_id in tqdm(range(config.episodes), desc="collect", unit="episode", disable=not progress):
        displaced = rng.random() < config.displaced_fraction
        options = {
            # Open tracks: start early enough to drive the whole episode before the end of the road.
            "start_arc_length_m": float(rng.uniform(
                0.0, track_spec.length_m if track_spec.closed else usable_length_m)),
            "start_offset_m": float(rng.uniform(-config.max_offset_m, config.max_offset_m)) if displaced else 0.0,
            "start_heading_error_rad": float(np.radians(
                rng.uniform(-config.max_heading_error_deg, config.max_heading_error_deg))) if displaced else 0.0,
        }
        obs, info = env.reset(options=options)
        expert.reset()
        for _ in range(steps_per_episode):
            label = expert(obs, info)
            frames[n_rows] = obs
            n_rows += 1
            _append_step(columns, episode_id, info, label, displaced and info["time_s"] < RECOVERY_WINDOW_S)
            obs, _, terminated, truncated, info = env.step(np.array([label], dtype=np.float32))
            if terminated or truncated:
                break
    manifest = {
        "track": track, "speed_mps": config.speed_mps,
        "simulation_frequency": unwrapped.config["simulation_frequency"],
        "policy_frequency": unwrapped.config["policy_frequency"],
        "max_steering_rad": unwrapped.config["max_steering_rad"],
        "seed": config.seed, "camera": dict(vars(unwrapped.camera_config)),
        "conditions": config.conditions, "demonstrator": demonstrator_name,
        "steering_time_constant_s": unwrapped.config["steering_time_constant_s"],
        "collector": {"episodes": config.episodes, "episode_seconds": config.episode_seconds,
                      "displaced_fraction": config.displaced_fraction, "max_offset_m": config.max_offset_m,
                      "max_heading_error_deg": config.max_heading_error_deg, "expert": asdict(expert.params)},
    }
    steps = {name: np.asarray(values, dtype=STEP_COLUMNS[name]) for name, values in columns.items()}
    return frames[:n_rows], steps, manifest


def _check_against_track(config: CollectConfig, track: str, track_spec, start_lane_offset_m: float) -> None:
    """Bounds that depend on the track: episodes fit on an open road, displaced starts stay on it."""
    episode_length_m = config.speed_mps * config.episode_seconds
    if not track_spec.closed and track_spec.length_m - episode_length_m <= 0:
        raise BadInput(f"track {track!r} ({track_spec.length_m:.0f} m) is shorter than one episode "
                         f"({episode_length_m:.0f} m at --speed-mps {config.speed_mps:g})")
    # The car's centre must start on the road, on either side of the start lane's centre.
    room_m = track_spec.road_half_width_m - abs(start_lane_offset_m)
    if config.max_offset_m > room_m:
        raise BadInput(f"--max-offset-m {config.max_offset_m:g} would start the car off the road of track "
                         f"{track!r}: at most {room_m:g} m from the start lane's centre to the road edge")


def _append_step(columns: dict, episode_id: int, info: dict, label: float, perturbed: bool) -> None:
    row = {
        "episode_id": episode_id, "t_s": info["time_s"], "speed_mps": info["speed_mps"], "steering": label,
        "executed_steering": label, "x_m": info["x_m"], "y_m": info["y_m"], "heading_rad": info["heading_rad"],
        "lateral_offset_m": info["lateral_offset_m"], "perturbed": perturbed,
    }
    for name, value in row.items():
        columns[name].append(value)

