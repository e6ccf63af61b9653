"""The sweep's one results table (tidy: one row per run) and its figures.

Columns (:data:`TABLE_COLUMNS`): the cell (condition, track, latency, seed, policy), the run's
summary (steps, left_road, completed_fraction, lateral offset RMS and max [m], latency-clamped
steps, mean observation age [s]) and ``steering_mae``: the mean absolute steering difference,
step by step over the common span, against the cell's reference (same condition, track and seed;
the BM, or the expert for the expert, without latency; see :class:`~plm_highway.sweep.grid.SweepCell`).

Figures: per condition and track, the steering MAE and the offset RMS of each policy at each
latency profile, mean over the seeds with a 95% t-interval (none for a single seed).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from plm_highway.io import file_kind, pyplot, save_figure_into, unique_file_names
from plm_highway.metrics.intervals import mean_ci
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


def mean_and_half_width(values) -> tuple[float, float]:
    """A figure's point and error bar: the mean over the values that are defined and the half-width of its 95%
    Student-t interval (:func:`~plm_highway.metrics.intervals.mean_ci`); NaN where undefined (no value, or one)."""
    defined = [v for v in values if math.isfinite(v)]
    if not defined:
        return math.nan, math.nan
    estimate = mean_ci(defined)
    return estimate.mean, math.nan if estimate.half_width is None else estimate.half_width


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
                stats = [mean_and_half_width([r[metric] for r in rows if (r["condition"], r["track"], r["latency"],
                                    r["policy"]) == (condition, track, latency, policy)]) for latency in latencies]
                means, halves = zip(*stats)
                ax.errorbar(range(len(latencies)), means, yerr=np.nan_to_num(halves), marker="o", capsize=3,
                            label=policy)
        for ax, label in zip(axes, ("steering MAE vs no latency (normalised)", "lateral offset RMS [m]")):
            ax.set_xticks(range(len(latencies)), latencies, rotation=20)
            ax.set_xlabel("latency profile")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
            ax.legend(title="policy")
        fig.suptitle(f"condition {condition}, track {track}: mean over {len(grid.seeds)} seed(s), 95% CI")
        path = directory / name
        save_figure_into(fig, path)
        plt.close(fig)
        paths.append(path)
    return paths
