"""Record expert demonstrations, with recovery, for imitation learning.

A policy trained only on perfect driving has never seen the car off-centre, so it drifts off
once its own errors accumulate. Most episodes therefore start displaced (lateral offset and
heading error drawn at random) and record the expert bringing the car back; each frame is
labelled with the expert's action for that frame's true state, and the car executes that same
action. Every displacement starts a new episode, so future-action labels never span a jump.
"""

from __future__ import annotations

import gymnasium
import numpy as np
from tqdm import tqdm

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.data.dataset import STEP_COLUMNS
from plm_highway.envs.lane_keeping import PAPER_CAMERA
from plm_highway.expert import ExpertPolicy

RECOVERY_WINDOW_S = 2.0  # frames this soon after a displaced start are flagged `perturbed`


def collect(track: str = "train", episodes: int = 200, episode_seconds: float = 8.0, displaced_fraction: float = 0.7,
            max_offset_m: float = 1.5, max_heading_error_deg: float = 6.0, speed_mps: float = 16.7,
            camera: str = "default", seed: int = 0, progress: bool = True) -> tuple[np.ndarray, dict, dict]:
    """Drive ``episodes`` expert episodes; return (frames, step columns, manifest)."""
    if episodes < 1 or episode_seconds <= 0:
        raise ValueError(f"--episodes ({episodes}) must be >= 1 and --episode-seconds ({episode_seconds}) > 0")
    if not 0.0 <= displaced_fraction <= 1.0:
        raise ValueError(f"--displaced-fraction {displaced_fraction} must lie in [0, 1]")
    config = {"track": track, "speed_mps": speed_mps, "camera": PAPER_CAMERA if camera == "paper" else {}}
    env = gymnasium.make("plm_highway/LaneKeeping-v0", config=config)
    unwrapped = env.unwrapped
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    expert = ExpertPolicy()
    usable_length_m = unwrapped.track.length_m - speed_mps * episode_seconds
    if usable_length_m <= 0 and not unwrapped.track.closed:
        raise ValueError(f"track {track!r} ({unwrapped.track.length_m:.0f} m) is shorter than one episode")
    frames: list[np.ndarray] = []
    columns: dict[str, list] = {name: [] for name in STEP_COLUMNS}
    for episode_id in tqdm(range(episodes), desc="collect", unit="episode", disable=not progress):
        displaced = rng.random() < displaced_fraction
        options = {
            # Open tracks: start early enough to drive the whole episode before the end of the road.
            "start_arc_length_m": float(rng.uniform(
                0.0, unwrapped.track.length_m if unwrapped.track.closed else usable_length_m)),
            "start_offset_m": float(rng.uniform(-max_offset_m, max_offset_m)) if displaced else 0.0,
            "start_heading_error_rad": float(np.radians(rng.uniform(-max_heading_error_deg, max_heading_error_deg)))
            if displaced else 0.0,
        }
        obs, info = env.reset(options=options)
        for _ in range(int(round(episode_seconds * unwrapped.config["policy_frequency"]))):
            label = expert(obs, info)
            frames.append(obs)
            _append_step(columns, episode_id, info, label, displaced and info["time_s"] < RECOVERY_WINDOW_S)
            obs, _, terminated, truncated, info = env.step(np.array([label], dtype=np.float32))
            if terminated or truncated:
                break
    manifest = {
        "track": track, "speed_mps": speed_mps,
        "simulation_frequency": unwrapped.config["simulation_frequency"],
        "policy_frequency": unwrapped.config["policy_frequency"],
        "max_steering_rad": unwrapped.config["max_steering_rad"],
        "seed": seed, "camera": dict(vars(unwrapped.camera_config)),
        "collector": {"episodes": episodes, "episode_seconds": episode_seconds,
                      "displaced_fraction": displaced_fraction, "max_offset_m": max_offset_m,
                      "max_heading_error_deg": max_heading_error_deg, "expert": vars(expert.params)},
    }
    steps = {name: np.asarray(values, dtype=STEP_COLUMNS[name]) for name, values in columns.items()}
    return np.stack(frames), steps, manifest


def _append_step(columns: dict, episode_id: int, info: dict, label: float, perturbed: bool) -> None:
    row = {
        "episode_id": episode_id, "t_s": info["time_s"], "speed_mps": info["speed_mps"], "steering": label,
        "executed_steering": label, "x_m": info["x_m"], "y_m": info["y_m"], "heading_rad": info["heading_rad"],
        "lateral_offset_m": info["lateral_offset_m"], "perturbed": perturbed,
    }
    for name, value in row.items():
        columns[name].append(value)
