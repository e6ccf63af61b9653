"""Training labels from a demonstration dataset: future actions by time, and histogram balancing.

Future actions (D_TAPM, paper eq. in Section 3.3): for a row at time t of episode e, the label
for latency delta is the expert's steering at time t + delta *of the same episode*, found by
linear interpolation in ``t_s`` between that episode's samples. At the 20 Hz policy rate the grid
0.15 ... 0.35 s falls on samples, so the interpolation returns the sample's label (up to the
rounding of the timestamps); it only blends when a collector runs at another rate or drops a
frame. Rows whose t + max(delta) lies beyond their episode's last sample are dropped, never
padded: there is no truthful label for them. The original built labels by frame offsets, which
breaks as soon as the frame rate varies.

Labels are the expert's ``steering`` column (what the expert wanted in that state), never
``executed_steering`` (which includes the collector's recovery perturbations).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.io import save_figure_into

# Timestamps are sums of float steps: t + 0.15 may land a few ulps past the episode's last sample.
TIME_TOLERANCE_S = 1e-6
BALANCE_BINS = 35
STEERING_RANGE = (-1.0, 1.0)


def future_steering_labels(
    episode_id: np.ndarray, t_s: np.ndarray, steering: np.ndarray, horizons_s: tuple[float, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the steering at t + each horizon within the row's episode.

    Returns ``(labels (n_rows, n_horizons) float32, has_future (n_rows,) bool)``; rows without a
    future for every horizon have NaN labels and ``has_future`` False. Rows need not be grouped by
    episode, but each episode's rows must be in strictly increasing time order.
    """
    horizons = np.asarray(horizons_s, dtype=np.float64)
    labels = np.full((len(t_s), len(horizons)), np.nan, dtype=np.float32)
    for episode in np.unique(episode_id):
        rows = np.flatnonzero(episode_id == episode)
        labels[rows] = _episode_future_labels(t_s[rows], steering[rows], horizons, episode)
    return labels, ~np.isnan(labels).any(axis=1)


def _episode_future_labels(
    t_s: np.ndarray, steering: np.ndarray, horizons_s: np.ndarray, episode: int
) -> np.ndarray:
    if np.any(np.diff(t_s) <= 0):
        row = int(np.flatnonzero(np.diff(t_s) <= 0)[0]) + 1
        raise BadInput(f"episode {episode}: t_s is not strictly increasing at its row {row}")
    target_t_s = t_s[:, None] + horizons_s[None, :]
    beyond_end = target_t_s > t_s[-1] + TIME_TOLERANCE_S
    labels = np.interp(np.minimum(target_t_s, t_s[-1]), t_s, steering.astype(np.float64))
    labels[beyond_end] = np.nan
    return labels


def steering_bin_edges(n_bins: int = BALANCE_BINS) -> np.ndarray:
    return np.linspace(*STEERING_RANGE, n_bins + 1)


def balance_by_histogram(
    steering: np.ndarray, max_per_bin: int, rng: np.random.Generator, n_bins: int = BALANCE_BINS
) -> np.ndarray:
    """Row indices (sorted) keeping at most ``max_per_bin`` rows per steering bin, chosen at random.

    The paper's balancing: a 35-bin histogram over [-1, 1] with a cap per bin, which thins the
    near-zero steering of straight roads and keeps every curve sample.
    """
    if max_per_bin < 1:
        raise BadInput(f"max_per_bin: must be >= 1, got {max_per_bin}")
    bins = np.clip(np.digitize(steering, steering_bin_edges(n_bins)[1:-1]), 0, n_bins - 1)
    kept = []
    for b in range(n_bins):
        rows = np.flatnonzero(bins == b)
        if len(rows) > max_per_bin:
            rows = rng.choice(rows, size=max_per_bin, replace=False)
        kept.append(rows)
    return np.sort(np.concatenate(kept))


def save_balance_figure(
    before: np.ndarray, after: np.ndarray, path: str | Path, n_bins: int = BALANCE_BINS
) -> Path:
    """Steering histograms before (left) and after (right) balancing, like the paper's Figure 8."""
    # lazy: matplotlib only when the figure is drawn; no pyplot: no global state, no GUI backend needed
    from matplotlib.figure import Figure

    edges = steering_bin_edges(n_bins)
    figure = Figure(figsize=(11, 4.2), layout="constrained")
    axes = figure.subplots(1, 2, sharex=True)
    for ax, values, title in ((axes[0], before, "before balancing"), (axes[1], after, "after balancing")):
        ax.hist(values, bins=edges, color="tab:blue", edgecolor="white")
        ax.set_title(f"Steering {title} ({len(values):,} samples)", fontsize=12)
        ax.set_xlabel("normalised steering (positive = left)", fontsize=11)
        ax.set_ylabel("samples per bin", fontsize=11)
        ax.grid(axis="y", alpha=0.3)
    figure.suptitle(f"Histogram balancing of steering labels ({n_bins} bins)", fontsize=13)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure_into(figure, path)  # inside the checkpoint directory being staged
    return path
