"""The sweep's one results table (tidy: one row per run) and its figures.

Columns (:data:`TABLE_COLUMNS`): the cell (condition, track, latency, seed, policy), the run's
summary (steps, left_road, completed_fraction, lateral offset RMS and max [m], latency-clamped
steps, mean observation age [s]) and ``steering_mae``: the mean absolute steering difference,
step by step over the common span, against the cell's reference (same condition, track and seed;
the BM, or the expert for the expert, without latency; see :class:`~plm_highway.sweep.grid.SweepCell`).

Figures: per condition and track, the steering MAE and the offset RMS of each policy at each
latency profile, mean over the seeds with a 95% t-interval on the log scale (both are errors, never negative:
:func:`~plm_highway.metrics.intervals.mean_ci` with ``scale="positive"``); no bar with fewer than 3 seeds.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from plm_highway.io import file_kind, pyplot, save_figure_into, unique_file_names
from plm_highway.metrics.intervals import MIN_INTERVAL_VALUES, mean_ci, too_few
from plm_highway.metrics.steering import common_span, steering_mae
from plm_highway.sweep.grid import SweepCell, SweepGrid

CELL_COLUMNS = ("condition", "track", "latency", "seed", "policy")
SUMMARY_COLUMNS = ("steps", "left_road", "completed_fraction", "lateral_offset_rms_m", "lateral_offset_max_m",
                   "latency_clamped_steps", "mean_observation_age_s")
TABLE_COLUMNS = (*CELL_COLUMNS, *SUMMARY_COLUMNS, "steering_mae")
SWEEP_TABLE = file_kind("sweep-table", "a sweep results table (CSV)", TABLE_COLUMNS)


def cell_result(log) -> dict:
    """What a finished run keeps: its summary and its steering trace (for the errors against references)."""
    summary = log.summary()
    return {**{column: summary.get(column, 0) for column in SUMMARY_COLUMNS[:-1]},
            "mean_observation_age_s": float(np.mean(log.columns["observation_age_s"])),
            "steering": [float(v) for v in log.columns["steering"]]}


def table_rows(cells: list[SweepCell], results: dict[SweepCell, dict]) -> list[dict]:
    rows = []
    for cell in cells:
        result = results[cell]
        reference = results.get(cell.reference)
        mae = math.nan
        if reference is not None:
            mae = steering_mae(*common_span(np.asarray(reference["steering"]), np.asarray(result["steering"])))
        rows.append({"condition": cell.condition, "track": cell.track, "latency": cell.latency, "seed": cell.seed,
                     "policy": cell.policy, **{c: result[c] for c in SUMMARY_COLUMNS}, "steering_mae": mae})
    return rows


def mean_and_interval(values) -> tuple[float, float, float]:
    """A figure's point and error bar of an error (never negative): the mean over the values that are defined and
    its 95% Student-t interval on the log scale (:func:`~plm_highway.metrics.intervals.mean_ci`,
    ``scale="positive"``), so the bar never reaches below 0; the interval is NaN with fewer than 3 defined values,
    all three with none."""
    defined = [v for v in values if math.isfinite(v)]
    if not defined:
        return math.nan, math.nan, math.nan
    estimate = mean_ci(defined, scale="positive")
    if estimate.low is None:
        return estimate.mean, math.nan, math.nan
    return estimate.mean, estimate.low, estimate.high


def error_bars(means, lows, highs) -> np.ndarray:
    """``errorbar``'s ``yerr`` (2 x N, below and above each mean) for intervals that need not be symmetric; no bar
    (0) where the interval is undefined, and a bar never crossing its mean (with many strongly skewed seeds the
    arithmetic mean can lie above the log-scale interval: the bar then ends at the mean)."""
    means, lows, highs = (np.asarray(v, dtype=float) for v in (means, lows, highs))
    return np.nan_to_num(np.vstack([np.maximum(means - lows, 0.0), np.maximum(highs - means, 0.0)]))


def figure_names(grid: SweepGrid) -> list[tuple[str, str, str]]:
    """(condition, track, file name) of each figure: one name per condition and track, even for two
    tracks with one file name in different folders."""
    pairs = [(c, t) for c in grid.conditions for t in grid.tracks]
    names = unique_file_names([f"sweep_{c}_{Path(t).stem}" for c, t in pairs],
                              [json.dumps([c, t]) for c, t in pairs], ".png")
    return [(c, t, name) for (c, t), name in zip(pairs, names)]


def save_figures(rows: list[dict], grid: SweepGrid, directory: Path) -> list[Path]:
    """One figure per condition and track, written into ``directory`` (being published by the caller)."""
    plt = pyplot()
    paths = []
    latencies = list(grid.latencies)
    for condition, track, name in figure_names(grid):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
        for policy in grid.policies:
            for ax, metric in zip(axes, ("steering_mae", "lateral_offset_rms_m")):
                stats = [mean_and_interval([r[metric] for r in rows if (r["condition"], r["track"], r["latency"],
                                  r["policy"]) == (condition, track, latency, policy)]) for latency in latencies]
                means, lows, highs = zip(*stats)
                ax.errorbar(range(len(latencies)), means, yerr=error_bars(means, lows, highs), marker="o", capsize=3,
                            label=policy)
        for ax, label in zip(axes, ("steering MAE vs no latency (normalised)", "lateral offset RMS [m]")):
            ax.set_xticks(range(len(latencies)), latencies, rotation=20)
            ax.set_xlabel("latency profile")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
            ax.legend(title="policy")
        interval = "95% CI" if len(grid.seeds) >= MIN_INTERVAL_VALUES else too_few()
        fig.suptitle(f"condition {condition}, track {track}: mean over {len(grid.seeds)} seed(s), {interval}")
        path = directory / name
        save_figure_into(fig, path)
        plt.close(fig)
        paths.append(path)
    return paths
