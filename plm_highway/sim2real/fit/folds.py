"""Held-out data: the recording split in time for cross-validation.

Alternating blocks in time (``split="blocks"``, the default): fit on the even blocks and predict
the odd ones, then the other way round, so every usable sample gets an out-of-fold prediction and
both folds see every kind of driving. ``split="halves"``: fit on the first half, score the second.
"""

from __future__ import annotations

import math

import numpy as np

SPLITS = ("blocks", "halves")
MIN_BLOCKS = 4  # alternating blocks the recording must hold (two per fold)


def default_block_s(duration_s: float, dt_s: float = 0.02) -> float:
    """duration/16 within 2.5-8 s, and at least 25 samples."""
    return float(max(np.clip(duration_s / 16.0, 2.5, 8.0), 25 * dt_s))


def check_block_s(block_s: float, usable_duration_s: float) -> None:
    """Refuse blocks too long for cross-validation: the recording must hold ``MIN_BLOCKS`` of them."""
    if not (math.isfinite(block_s) and block_s > 0):
        raise ValueError(f"--block-s must be a positive number of seconds (got {block_s!r})")
    if MIN_BLOCKS * block_s > usable_duration_s:
        raise ValueError(f"--block-s {block_s:g} s is too long: the {usable_duration_s:.1f} s recording holds fewer "
                         f"than {MIN_BLOCKS} alternating blocks (two per fold); use at most "
                         f"{usable_duration_s / MIN_BLOCKS:.1f} s")


def make_folds(t_s: np.ndarray, usable: np.ndarray, split: str = "blocks", block_s: float = 8.0
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(train, held-out) mask pairs; held-out masks are disjoint."""
    if split == "blocks":
        block = np.floor((t_s - t_s[0]) / block_s).astype(int)
        even = block % 2 == 0
        return [(even & usable, ~even & usable), (~even & usable, even & usable)]
    if split == "halves":
        first = t_s < t_s[0] + 0.5 * (t_s[-1] - t_s[0])
        return [(first & usable, ~first & usable)]
    raise ValueError(f"unknown split {split!r}; known: {', '.join(SPLITS)}")
