"""Demonstrations on the states a late policy visits: PLM-Net drives with a late camera, the demonstrator labels.

``collect`` records the demonstrator driving the car itself: every state it visits is one the demonstrator
corrected at once, so the future actions a TAPM learns from (the steering ``delta`` later) assume that the car
was being corrected during ``delta``. Under latency it was not: the steering in that time came from frames
that were already old. This collector records the states of that loop instead (DAgger-style, once): a policy
(PLM-Net, told the latency) drives the deployment plant of the conditions, loop rate, actuator, processing delay
and image noise included, seeing each frame ``latency`` late; the human-like demonstrator watches the true state
at every step, and what its hand would do is the label of that step's (fresh, noise-free) frame. The car executes
the policy's steering (``executed_steering``).

Episodes start at random places of the track, centred and aligned as evaluation runs start, and cycle through
the given latencies (one per episode) so that each of the TAPM's horizons gets its share.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gymnasium
import numpy as np
from tqdm import tqdm

from plm_highway.camera.pinhole import PAPER_CAMERA
from plm_highway.data.collect import make_demonstrator
from plm_highway.data.dataset import STEP_COLUMNS
from plm_highway.envs import ENV_ID
from plm_highway.errors import BadInput
from plm_highway.latency.wrapper import served_steps
from plm_highway.rollout.closed_loop import add_image_noise
from plm_highway.rollout.conditions import CONDITIONS

ON_POLICY_STREAM = 17  # the demonstrator and the image noise draw from default_rng([seed, ON_POLICY_STREAM, k])


@dataclass(frozen=True)
class OnPolicyConfig:
    episodes: int = 100
    episode_seconds: float = 8.0
    latencies_s: tuple[float, ...] = (0.15, 0.2, 0.25, 0.3, 0.35)
    seed: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.episodes, int) and 1 <= self.episodes <= 100_000):
            raise BadInput(f"on-policy episodes {self.episodes!r}: expected an integer in [1, 100000]")
        if not 0 < self.episode_seconds <= 3600:
            raise BadInput(f"on-policy episode_seconds {self.episode_seconds!r}: expected (0, 3600]")
        if not self.latencies_s or any(not 0 <= lat <= 1.0 for lat in self.latencies_s):
            raise BadInput(f"on-policy latencies {self.latencies_s!r}: expected 1 or more values in [0, 1] s")


def collect_on_policy(policy, conditions_name: str, track: str = "train", config: OnPolicyConfig = OnPolicyConfig(),
                      progress: bool = False) -> tuple[np.ndarray, dict, dict]:
    """(frames, step columns, manifest) of ``policy`` driving late under ``conditions_name``, labelled by the
    conditions' demonstrator; ``policy(frame, speed_mps, latency_s) -> steering`` (a models.inference policy)."""
    conditions = CONDITIONS[conditions_name]
    camera = dict(PAPER_CAMERA) if conditions.camera else {}
    env = gymnasium.make(ENV_ID, config={"track": track, "camera": camera, **conditions.env_config()})
    unwrapped = env.unwrapped
    env.reset(seed=config.seed)
    rate_hz = unwrapped.config["policy_frequency"]
    steps_per_episode = int(round(config.episode_seconds * rate_hz))
    track_spec = unwrapped.track
    usable_m = track_spec.length_m - conditions.speed_mps * config.episode_seconds
    if not track_spec.closed and usable_m <= 0:
        raise BadInput(f"track {track!r} is shorter than one on-policy episode")
    rng = np.random.default_rng([config.seed, ON_POLICY_STREAM])
    frames = np.empty((config.episodes * steps_per_episode, *env.observation_space.shape), dtype=np.uint8)
    columns: dict[str, list] = {name: [] for name in STEP_COLUMNS}
    n_rows = 0
    try:
        for episode in tqdm(range(config.episodes), desc="on-policy", unit="episode", disable=not progress):
            latency_s = config.latencies_s[episode % len(config.latencies_s)]
            lag_steps = served_steps(latency_s, 1.0 / rate_hz)
            episode_rng = np.random.default_rng([config.seed, ON_POLICY_STREAM, episode])
            demonstrator = make_demonstrator(conditions.demonstrator, rate_hz, episode_rng, conditions.max_steering_rad)
            demonstrator.reset()
            start_m = float(rng.uniform(0.0, track_spec.length_m if track_spec.closed else usable_m))
            obs, info = env.reset(options={"start_arc_length_m": start_m, "start_offset_m": 0.0,
                                           "start_heading_error_rad": 0.0})
            seen: list[np.ndarray] = []
            for _ in range(steps_per_episode):
                seen.append(add_image_noise(obs, conditions.image_noise_std, episode_rng)
                            if conditions.image_noise_std > 0 else np.array(obs))
                late_frame = seen[max(0, len(seen) - 1 - lag_steps)]
                steering = float(policy(late_frame, info["speed_mps"], latency_s))
                label = float(demonstrator(obs, info))
                frames[n_rows] = obs
                n_rows += 1
                for name, value in (("episode_id", episode), ("t_s", info["time_s"]), ("speed_mps", info["speed_mps"]),
                                    ("steering", label), ("executed_steering", steering), ("x_m", info["x_m"]),
                                    ("y_m", info["y_m"]), ("heading_rad", info["heading_rad"]),
                                    ("lateral_offset_m", info["lateral_offset_m"]), ("perturbed", True)):
                    columns[name].append(value)
                obs, _, terminated, truncated, info = env.step(np.array([steering], dtype=np.float32))
                if terminated or truncated:
                    break
    finally:
        env.close()
    manifest = {"track": track, "speed_mps": conditions.speed_mps,
                "simulation_frequency": unwrapped.config["simulation_frequency"], "policy_frequency": rate_hz,
                "max_steering_rad": conditions.max_steering_rad, "seed": config.seed,
                "camera": dict(vars(unwrapped.camera_config)), "conditions": conditions_name,
                "demonstrator": conditions.demonstrator,
                "collector": {"kind": "on-policy", "episodes": config.episodes,
                              "episode_seconds": config.episode_seconds, "latencies_s": list(config.latencies_s)}}
    steps = {name: np.asarray(values, dtype=STEP_COLUMNS[name]) for name, values in columns.items()}
    return frames[:n_rows], steps, manifest


def concatenate(parts: Sequence[tuple[np.ndarray, dict]]) -> tuple[np.ndarray, dict]:
    """Frames and step columns of several recordings as one (episode ids renumbered so none is shared)."""
    frames = np.concatenate([f for f, _ in parts])
    steps: dict[str, list] = {name: [] for name in STEP_COLUMNS}
    next_episode = 0
    for _, part in parts:
        for name in STEP_COLUMNS:
            values = np.asarray(part[name])
            steps[name].append(values + next_episode if name == "episode_id" else values)
        if len(part["episode_id"]):
            next_episode += int(np.max(part["episode_id"])) + 1
    return frames, {name: np.concatenate(values).astype(STEP_COLUMNS[name]) for name, values in steps.items()}
