"""Small synthetic demonstration datasets, for tests and the CI fast path (no simulator needed).

Each episode steers along a sinusoid sampled at the 20 Hz policy rate; each frame draws two
bright lane lines whose position and slant follow the current steering, so a model can learn
the mapping in a few epochs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plm_highway.data.dataset import write_dataset

POLICY_PERIOD_S = 0.05
SPEED_MPS = 16.7


def synthetic_steering(n_steps: int, rng: np.random.Generator) -> np.ndarray:
    """One episode's expert steering: a sinusoid with random amplitude, period and phase."""
    t_s = np.arange(n_steps) * POLICY_PERIOD_S
    amplitude = rng.uniform(0.2, 0.8)
    period_s = rng.uniform(1.5, 5.0)
    phase = rng.uniform(0, 2 * np.pi)
    return (amplitude * np.sin(2 * np.pi * t_s / period_s + phase)).astype(np.float32)


def render_lane_frames(
    steering: np.ndarray, image_size_px: tuple[int, int], rng: np.random.Generator
) -> np.ndarray:
    """uint8 (N, H, W): noisy background with two lane lines shifted and slanted by the steering."""
    height, width = image_size_px
    rows = np.arange(height)[None, :, None]
    cols = np.arange(width)[None, None, :]
    s = steering[:, None, None]
    # Lines converge towards the top of the image; steering shifts and bends them sideways.
    centre = width / 2 - s * width * 0.25 * (1 - rows / height)
    half_gap = width * (0.15 + 0.25 * rows / height)
    on_line = (np.abs(cols - (centre - half_gap)) < 2) | (np.abs(cols - (centre + half_gap)) < 2)
    frames = rng.normal(70, 12, size=(len(steering), height, width)) + 150 * on_line
    return np.clip(frames, 0, 255).astype(np.uint8)


def make_synthetic_dataset(
    out_dir: str | Path,
    n_episodes: int = 6,
    steps_per_episode: int = 40,
    image_size_px: tuple[int, int] = (66, 200),
    seed: int = 0,
) -> Path:
    rng = np.random.default_rng(seed)
    steering = np.concatenate([synthetic_steering(steps_per_episode, rng) for _ in range(n_episodes)])
    n_rows = len(steering)
    step_index = np.tile(np.arange(steps_per_episode), n_episodes)
    heading_rad = np.cumsum(steering * 0.02)
    steps = {
        "episode_id": np.repeat(np.arange(n_episodes), steps_per_episode),
        # Episodes restart their clock: the look-up by time must not mix them up.
        "t_s": step_index * POLICY_PERIOD_S,
        "speed_mps": np.full(n_rows, SPEED_MPS),
        "steering": steering,
        "executed_steering": steering,
        "x_m": np.cumsum(np.cos(heading_rad)) * SPEED_MPS * POLICY_PERIOD_S,
        "y_m": np.cumsum(np.sin(heading_rad)) * SPEED_MPS * POLICY_PERIOD_S,
        "heading_rad": heading_rad,
        "lateral_offset_m": np.zeros(n_rows),
        "perturbed": np.zeros(n_rows, dtype=bool),
    }
    manifest = {
        "track": "synthetic",
        "speed_mps": SPEED_MPS,
        "simulation_frequency": round(1 / POLICY_PERIOD_S),
        "policy_frequency": round(1 / POLICY_PERIOD_S),
        "seed": seed,
        "camera": {"height_px": image_size_px[0], "width_px": image_size_px[1]},
        "collector": {"name": "plm_highway.training.synthetic"},
    }
    return write_dataset(out_dir, render_lane_frames(steering, image_size_px, rng), steps, manifest)
