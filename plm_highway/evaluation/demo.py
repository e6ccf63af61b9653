"""``plm-highway demo zigzag``: the paper's Figure 2, a lane keeper with and without latency.

The Base Model drives when trained checkpoints are shipped; until then the expert, fed the same
delayed snapshots, plays its part. The figure shows both trajectories over the road around the
first curve (green: no latency, red: delayed) and the lateral offset over time.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from plm_highway.evaluation.closed_loop import drive
from plm_highway.evaluation.plots import draw_road
from plm_highway.evaluation.policies import make_policy
from plm_highway.latency import parse_profile
from plm_highway.road.track import load_track


def configure(parser) -> None:
    parser.add_argument("--latency", default="const:0.25", help="a profile spec, or seconds (e.g. 0.25)")
    parser.add_argument("--track", default="test")
    parser.add_argument("--policy", choices=["auto", "bm", "expert"], default="auto",
                        help="auto: the shipped Base Model if present, else the expert")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="figures/zigzag.png")


def _choose_policy(name: str):
    if name != "auto":
        return name
    try:
        make_policy("bm")
        return "bm"
    except (FileNotFoundError, ImportError):  # no checkpoints shipped (or models not installed)
        return "expert"


def zigzag(latency="const:0.25", track="test", policy="auto", seed=0, out="figures/zigzag.png") -> dict:
    spec = parse_profile(latency if not _is_number(latency) else f"const:{latency}").spec
    policy = _choose_policy(policy)
    track_spec = load_track(track)
    runs = {
        "no latency": drive("reference", make_policy(policy), track, "const:0", seed),
        f"latency {spec}": drive("baseline", make_policy(policy), track, spec, seed),
    }
    _plot(track_spec, runs, policy, out)
    return {name: log.summary() for name, log in runs.items()} | {"policy": policy, "figure": str(out)}


def _is_number(text) -> bool:
    try:
        float(text)
        return True
    except (TypeError, ValueError):
        return False


def _plot(track_spec, runs: dict, policy: str, out) -> None:
    os.environ.setdefault("MPLBACKEND", "Agg")
    import matplotlib.pyplot as plt

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
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(out).with_name(f".{Path(out).stem}.tmp{Path(out).suffix}")
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, out)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)


def run(args) -> int:
    result = zigzag(args.latency, args.track, args.policy, args.seed, args.out)
    print(f"policy: {result['policy']}")
    for name, summary in result.items():
        if isinstance(summary, dict):
            print(f"{name:>24}: lateral offset max {summary['lateral_offset_max_m']:.3f} m, "
                  f"RMS {summary['lateral_offset_rms_m']:.3f} m, left road: {summary['left_road']}")
    print(f"figure: {result['figure']}")
    return 0
