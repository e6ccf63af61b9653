"""The paper's result figures, from run logs: steering over time, trajectories, trajectory comparison.

Colours follow the paper: blue the BM without latency (``reference``), green the BM with latency
(``baseline``), red PLM-Net with latency (``mitigated``). Maps are north-up and never mirrored.
Figures are written inside an output directory that :mod:`plm_highway.io` is staging.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plm_highway.evaluation.plots import draw_road
from plm_highway.evaluation.trajectory import PARTS, LaneCentre, representative_segment, start_lane_offset_m
from plm_highway.io import pyplot, save_figure_into
from plm_highway.road.geometry import segment_starts_m
from plm_highway.road.track import TrackSpec

RUN_COLOURS = {"reference": "tab:blue", "baseline": "tab:green", "mitigated": "tab:red"}
PART_TITLES = {"full": "(a) full track", "straight": "(b) straight", "left": "(c) left turn", "right": "(d) right turn"}
DPI = 100


def _pyplot():
    return pyplot()


def run_labels(latency_label: str) -> dict[str, str]:
    """Legend labels of the three runs, e.g. ``run_labels("0.20 s")``."""
    return {"reference": "BM, no latency", "baseline": f"BM, latency {latency_label}",
            "mitigated": f"PLM-Net, latency {latency_label}"}


def save_figure(fig, path: str | Path) -> Path:
    """Save ``fig`` (tagged as plm-highway's) inside a staged output directory; closes the figure."""
    path = Path(path)
    try:
        save_figure_into(fig, path, dpi=DPI)
    finally:
        pyplot().close(fig)
    return path


def plot_steering(logs: dict, latency_label: str, title: str, out, latency_trace: bool = False) -> Path:
    """Steering over time of every run (Figures 9, 12, A1, A4, A7); with ``latency_trace`` the
    requested latency and the age of the delivered frame below it (Figure 12's lower panel)."""
    plt = _pyplot()
    labels = run_labels(latency_label)
    rows = 2 if latency_trace else 1
    fig, axes = plt.subplots(rows, 1, figsize=(12, 6.5 if latency_trace else 4.2), sharex=True, squeeze=False,
                             gridspec_kw={"height_ratios": [2, 1] if latency_trace else [1]})
    ax = axes[0, 0]
    for name, log in logs.items():
        ax.plot(log.columns["t_s"], log.columns["steering"], color=RUN_COLOURS.get(name), lw=1.0,
                label=labels.get(name, name) + (" (left the road)" if log.left_road else ""))
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_ylabel("steering (normalised)\n+ = left")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=9)
    ax.grid(alpha=0.3)
    if latency_trace:
        lat_ax = axes[1, 0]
        delayed = logs.get("baseline") or next(iter(logs.values()))
        c = delayed.columns
        lat_ax.step(c["t_s"], c["latency_s"], where="post", color="k", lw=1.0, label="latency (requested)")
        lat_ax.plot(c["t_s"], c["observation_age_s"], ".", ms=2, color="tab:orange", label="age of the frame used")
        lat_ax.set_ylabel("latency [s]")
        lat_ax.legend(loc="upper right", fontsize=9)
        lat_ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    return save_figure(fig, out)


def plot_trajectories_by_steering(logs: dict, track: TrackSpec, latency_label: str, title: str, out) -> Path:
    """Each run's path coloured by its steering, one panel per run (Figures 10, 13, A2, A5, A8)."""
    plt = _pyplot()
    from matplotlib.collections import LineCollection  # lazy: matplotlib only when a figure is drawn
    from matplotlib.colors import Normalize

    labels = run_labels(latency_label)
    names = list(logs)
    limit = max(0.05, max(float(np.max(np.abs(log.columns["steering"]))) for log in logs.values()))
    norm = Normalize(-limit, limit)
    x_span, y_span = (float(np.ptp(np.concatenate([log.columns[k] for log in logs.values()])) + 2 * track.road_half_width_m)
                      for k in ("x_m", "y_m"))
    wide = x_span >= y_span  # stack wide tracks in rows, tall ones in columns
    shape = (len(names), 1) if wide else (1, len(names))
    panel_in = (12.0, 12.0 * y_span / x_span + 0.9) if wide else (6.0 * x_span / y_span + 0.9, 6.0)
    fig, axes = plt.subplots(*shape, squeeze=False, figsize=(panel_in[0] * shape[1] + 1.5, panel_in[1] * shape[0] + 0.8))
    axes = axes.reshape(1, -1)
    mappable = None
    for ax, name in zip(axes[0], names):
        c = logs[name].columns
        draw_road(ax, track)
        points = np.column_stack([c["x_m"], c["y_m"]])
        segments = np.stack([points[:-1], points[1:]], axis=1) if len(points) > 1 else np.zeros((0, 2, 2))
        lines = LineCollection(segments, cmap="coolwarm_r", norm=norm, linewidths=2.2, zorder=3)
        lines.set_array(np.asarray(c["steering"][:-1], dtype=float))
        mappable = ax.add_collection(lines)
        ax.plot(c["x_m"][:1], c["y_m"][:1], "o", color="k", ms=4, zorder=4)
        status = "left the road" if logs[name].left_road else f"{100 * logs[name].completed_fraction:.0f}% driven"
        ax.set_title(f"({'abc'[names.index(name)]}) {labels.get(name, name)}\n{status}", fontsize=10)
    fig.suptitle(title)
    fig.tight_layout()
    if mappable is not None:
        bar = fig.colorbar(mappable, ax=list(axes[0]), shrink=0.8, pad=0.01)
        bar.set_label("steering (normalised), + = left (blue), - = right (red)")
    return save_figure(fig, out)


def _window(track: TrackSpec, part: str) -> tuple[float, float] | None:
    if part == "full":
        return None
    index = representative_segment(track, part)
    if index is None:
        return None
    starts = segment_starts_m(track)
    return float(starts[index]), float(starts[index + 1])


def plot_trajectory_comparison(logs: dict, track: TrackSpec, latency_label: str, title: str, out,
                               start_lane: int | None = None) -> Path:
    """Runs against the lane centre on the full track, a straight, a left and a right turn
    (Figures 11, 14, A3, A6, A9): maps of the four parts, and below them the offset from the lane
    centre along each part (the same paths, with the lateral scale stretched so that it shows)."""
    plt = _pyplot()
    labels = run_labels(latency_label)
    centre = LaneCentre(track, start_lane_offset_m(track, start_lane))
    fig = plt.figure(figsize=(18, 13))
    grid = fig.add_gridspec(3, 12, height_ratios=[1.3, 1.5, 0.9])
    map_axes = {"full": fig.add_subplot(grid[0, :]), "straight": fig.add_subplot(grid[1, 0:4]),
                "left": fig.add_subplot(grid[1, 4:8]), "right": fig.add_subplot(grid[1, 8:12])}
    offset_axes = {part: fig.add_subplot(grid[2, 3 * i:3 * i + 3]) for i, part in enumerate(PARTS)}
    for part in PARTS:
        map_ax, offset_ax = map_axes[part], offset_axes[part]
        window = _window(track, part)
        if part != "full" and window is None:
            for ax in (map_ax, offset_ax):
                ax.set_title(f"{PART_TITLES[part]}: none on this track", fontsize=10)
                ax.axis("off")
            continue
        draw_road(map_ax, track, window)
        lo, hi = window if window is not None else (0.0, track.length_m)
        keep_centre = (centre.s_m >= lo) & (centre.s_m <= hi)
        map_ax.plot(centre.xy[keep_centre, 0], centre.xy[keep_centre, 1], color="k", lw=0.8, ls="--",
                    label="lane centre", zorder=2)
        largest_m = 0.0
        for name, log in logs.items():
            c = log.columns
            keep = (c["arc_length_m"] >= lo) & (c["arc_length_m"] <= hi)
            if keep.any():
                largest_m = max(largest_m, float(np.max(np.abs(c["lateral_offset_m"][keep]))))
            label = labels.get(name, name) + (" (left the road)" if log.left_road else "")
            map_ax.plot(c["x_m"][keep], c["y_m"][keep], color=RUN_COLOURS.get(name), lw=1.3, label=label, zorder=3)
            offset_ax.plot(c["arc_length_m"][keep] - lo, c["lateral_offset_m"][keep], color=RUN_COLOURS.get(name),
                           lw=1.0, label=label)
        where = "" if window is None else f": segment {representative_segment(track, part)}, {lo:.0f}-{hi:.0f} m"
        map_ax.set_title(PART_TITLES[part] + where, fontsize=10)
        offset_ax.set_title(PART_TITLES[part], fontsize=10)
        half_lane_m = track.lane_width_m / 2
        offset_ax.axhline(0.0, color="k", lw=0.8, ls="--")
        for edge in (-half_lane_m, half_lane_m):
            offset_ax.axhline(edge, color="0.5", lw=0.8, ls=(0, (4, 4)))
        # scaled to the deviations (lane edges show when they are within reach)
        limit_m = min(max(0.25, 1.15 * largest_m), track.road_half_width_m + 0.5)
        offset_ax.set_ylim(-limit_m, limit_m)
        offset_ax.set_xlabel("arc length along the part [m]")
        offset_ax.grid(alpha=0.3)
    offset_axes["full"].set_ylabel("offset from the lane centre [m]\n(+ = left; grey: lane edges)")
    map_axes["full"].legend(loc="upper right", fontsize=9)
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, out)


def plot_sweep(sweep: dict, title: str, out) -> Path:
    """Steering MAE and lateral-offset RMS against latency for each policy; crosses where a run
    left the road and a dotted line at the first latency where each policy does."""
    plt = _pyplot()
    fig, (mae_ax, rms_ax) = plt.subplots(1, 2, figsize=(13, 4.8))
    styles = {"bm": ("tab:green", "-", "BM"), "plm": ("tab:red", "-", "PLM-Net (told the measured latency)")}
    for bias in sweep.get("biases_s", []):
        key = f"plm_bias{bias:+.2f}"
        styles[key] = ("tab:purple" if bias < 0 else "tab:orange", "--",
                       f"PLM-Net told latency {bias:+.2f} s off")
    for key, (colour, ls, label) in styles.items():
        rows = [r for r in sweep["rows"] if r["policy"] == key]
        if not rows:
            continue
        lat = np.array([r["latency_s"] for r in rows])
        for ax, field in ((mae_ax, "steering_mae"), (rms_ax, "lateral_offset_rms_m")):
            ax.plot(lat, [r[field] for r in rows], ls, marker="o", ms=3.5, color=colour, label=label)
            off = [r for r in rows if r["left_road"]]
            if off:
                ax.plot([r["latency_s"] for r in off], [r[field] for r in off], "x", ms=10, mew=2, color=colour)
            first = sweep["leaves_road_at_s"].get(key)
            if first is not None:
                ax.axvline(first, color=colour, ls=":", lw=1.2)
    grid_max_s = sweep.get("tapm_grid_max_s", 0.35)
    last_s = max(r["latency_s"] for r in sweep["rows"])
    for ax, ylabel in ((mae_ax, "steering MAE vs BM without latency"), (rms_ax, "lateral offset RMS [m]")):
        if last_s > grid_max_s:
            ax.axvspan(grid_max_s, last_s + 0.01, color="0.92", zorder=0, label="beyond the TAPM grid (last head used)")
        ax.set_xlabel("latency [s]")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    mae_ax.legend(fontsize=8, loc="upper left")
    rms_ax.set_title("x: the run left the road; dotted: first latency at which it does", fontsize=9)
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, out)
