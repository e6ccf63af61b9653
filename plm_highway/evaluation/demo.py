"""The paper's Figure 2, a lane keeper with and without latency.

The Base Model drives when trained checkpoints are shipped; until then the expert, fed the same
delayed snapshots, plays its part. The figure shows both trajectories over the road around the
first curve (green: no latency, red: delayed) and the lateral offset over time.
"""

from __future__ import annotations

import numpy as np

from plm_highway.evaluation.plots import draw_road
from plm_highway.io import FIGURE, check_target, pyplot, save_figure
from plm_highway.road.track import resolve_track
from plm_highway.rollout.closed_loop import RunCell, drive_cell
from plm_highway.rollout.policies import make_policy


def _choose_policy(name: str):
    if name != "auto":
        return name
    try:
        make_policy("bm")
        return "bm"
    except (FileNotFoundError, ImportError):  # no checkpoints shipped (or models not installed)
        return "expert"


def zigzag(latency="const:0.25", track="test", policy="auto", seed=0, out="figures/zigzag.png",
           overwrite=False) -> dict:
    check_target(out, FIGURE, overwrite=overwrite)
    track_spec = resolve_track(track)
    # the runs described first: a bad latency is refused before any checkpoint is read
    delayed = RunCell("baseline", policy, track_spec, latency if not _is_number(latency) else f"const:{latency}", seed)
    reference = RunCell("reference", policy, track_spec, "const:0", seed)
    policy = _choose_policy(policy)
    runs = {"no latency": drive_cell(reference, make_policy(policy)),
            f"latency {delayed.latency.spec}": drive_cell(delayed, make_policy(policy))}
    _plot(track_spec, runs, policy, out, overwrite)
    return {name: log.summary() for name, log in runs.items()} | {"policy": policy, "figure": str(out)}


def _is_number(text) -> bool:
    try:
        float(text)
        return True
    except (TypeError, ValueError):
        return False


def _plot(track_spec, runs: dict, policy: str, out, overwrite: bool) -> None:
    plt = pyplot()

    colours = ["tab:green", "tab:red"]
    # 60 m of road around where the delayed run weaves most: wide enough to see the road bend, narrow
    # enough to see offsets of a few tenths of a metre.
    delayed = list(runs.values())[-1].columns
    worst_m = float(delayed["arc_length_m"][np.argmax(np.abs(delayed["lateral_offset_m"]))])
    window = (max(0.0, worst_m - 30.0), worst_m + 30.0)
    fig, (ax_map, ax_offset) = plt.subplots(2, 1, figsize=(10, 9), gridspec_kw={"height_ratios": [1, 1]})
    draw_road(ax_map, track_spec, window)
    for (name, log), colour in zip(runs.items(), colours):
        c = log.columns
        keep = (c["arc_length_m"] >= window[0]) & (c["arc_length_m"] <= window[1])
        ax_map.plot(c["x_m"][keep], c["y_m"][keep], color=colour, lw=1.6, label=name)
        ax_offset.plot(c["t_s"], c["lateral_offset_m"], color=colour, lw=1.2,
                       label=f"{name}: RMS {log.summary()['lateral_offset_rms_m']:.2f} m, "
                             f"max {log.summary()['lateral_offset_max_m']:.2f} m")
    who = "Base Model" if policy == "bm" else "expert driver (standing in for the Base Model)"
    ax_map.set_title(f"Figure 2 reproduction: {who}, 60 m of road where the delayed run weaves most")
    ax_map.legend(loc="best")
    reference = next(iter(runs.values())).columns
    in_curve = reference["segment"] != "straight"
    ax_offset.fill_between(reference["t_s"], 0, 1, where=in_curve, transform=ax_offset.get_xaxis_transform(),
                           color="0.9", label="in a curve")
    ax_offset.axhline(0.0, color="0.5", lw=0.6)
    ax_offset.set_xlabel("time [s]")
    ax_offset.set_ylabel("lateral offset from lane centre [m]\n(positive: left)")
    ax_offset.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, out, overwrite=overwrite, dpi=110)
    finally:
        plt.close(fig)
