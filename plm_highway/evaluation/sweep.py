"""Beyond the paper: how BM and PLM-Net degrade with latency, and with a wrong latency estimate.

- **Latency sweep**: constant latency from 0 to 0.5 s in 0.05 s steps (the paper stops at 0.35 s,
  where its BM left the track), for the BM and for PLM-Net told the measured latency. For each
  run: steering MAE against the BM without latency (step by step over the run's length) and the
  RMS lateral offset from the lane centre; the first latency at which each policy leaves the road
  is marked. Above 0.35 s PLM-Net uses its last TAPM head (the grid ends there).
- **Latency it was not told about**: PLM-Net fed a latency estimate that is off by a constant bias
  (``-0.05`` and ``+0.05`` s by default; the estimate is clipped at 0), at the sweep latencies up to
  the end of the TAPM grid (beyond it a biased estimate selects the same last head as the true one).

Every run uses the same track and seed as the no-latency reference, which is driven once.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from plm_highway.io import write_csv_into
from plm_highway.metrics.steering import common_span, steering_mae
from plm_highway.rollout.cells import run_cells
from plm_highway.rollout.closed_loop import RunCell, RunLog
from plm_highway.rollout.policies import VisionPolicy, biased

SWEEP_MAX_S = 0.5
SWEEP_STEP_S = 0.05
LATENCY_BIASES_S = (-0.05, 0.05)
SWEEP_COLUMNS = ("policy", "latency_s", "bias_s", "steering_mae", "lateral_offset_rms_m", "lateral_offset_max_m",
                 "left_road", "completed_fraction", "steps", "latency_clamped_steps")


def sweep_latencies(max_s: float = SWEEP_MAX_S, step_s: float = SWEEP_STEP_S) -> list[float]:
    if not (step_s > 0 and max_s >= 0):
        raise ValueError(f"sweep: step ({step_s}) must be > 0 and maximum ({max_s}) >= 0")
    return [round(k * step_s, 6) for k in range(round(max_s / step_s) + 1)]


def planned_runs(latencies: list[float], biases: tuple[float, ...], grid_max_s: float) -> list[tuple[str, float, float]]:
    """(policy key, latency, bias) of every run the sweep drives, the BM at 0 s excluded (the reference)."""
    runs = [("bm", lat, 0.0) for lat in latencies if lat > 0]
    runs += [("plm", lat, 0.0) for lat in latencies]
    for bias in biases:
        # at latency 0 a negative bias is clipped back to the true estimate, 0: nothing new to drive
        runs += [(bias_key(bias), lat, bias) for lat in latencies
                 if lat <= grid_max_s + 1e-6 and not (bias < 0 and lat <= 1e-9)]
    return runs


def bias_key(bias_s: float) -> str:
    return f"plm_bias{bias_s:+.2f}"


def latency_sweep(track, bm_policy, plm_policy: VisionPolicy, reference: RunLog, seed: int = 0,
                  max_steps: int | None = None, latencies: list[float] | None = None,
                  biases: tuple[float, ...] = LATENCY_BIASES_S, grid_max_s: float = 0.35,
                  drive_runs: Callable[[list[tuple[str, float, float]]], list[RunLog]] | None = None) -> dict:
    """Drive the sweep; returns ``{"rows": [...], "leaves_road_at_s": {policy: latency or None}, ...}``.

    ``drive_runs`` takes the :func:`planned_runs` (policy key, latency, bias) and returns their logs in order
    (``reproduce`` drives them batched, on its pool); by default they are driven one at a time
    (:func:`~plm_highway.rollout.cells.run_cells`, ``serial``) with the given policies.
    """
    latencies = sweep_latencies() if latencies is None else latencies
    reference_steering = reference.columns["steering"]
    rows = [_row("bm", 0.0, 0.0, reference, reference_steering)]
    runs = planned_runs(latencies, biases, grid_max_s)
    if drive_runs is None:
        logs = run_cells([RunCell(f"sweep: {key} {latency_s:.2f} s", bm_policy if key == "bm" else biased(plm_policy, bias_s),
                                  track, f"const:{latency_s:g}", seed, max_steps=max_steps)
                          for key, latency_s, bias_s in runs], serial=True)
    else:
        logs = drive_runs(runs)
    for (key, latency_s, bias_s), log in zip(runs, logs):
        rows.append(_row(key, latency_s, bias_s, log, reference_steering))
    policies = ["bm", "plm", *(bias_key(b) for b in biases)]
    leaves = {}
    for key in policies:
        off = sorted(r["latency_s"] for r in rows if r["policy"] == key and r["left_road"])
        leaves[key] = off[0] if off else None
    return {"latencies_s": latencies, "biases_s": list(biases), "tapm_grid_max_s": grid_max_s,
            "rows": rows, "leaves_road_at_s": leaves}


def _row(key: str, latency_s: float, bias_s: float, log: RunLog, reference_steering: np.ndarray) -> dict:
    summary = log.summary()
    return {"policy": key, "latency_s": latency_s, "bias_s": bias_s,
            "steering_mae": steering_mae(*common_span(reference_steering, log.columns["steering"])),
            "lateral_offset_rms_m": summary["lateral_offset_rms_m"],
            "lateral_offset_max_m": summary["lateral_offset_max_m"], "left_road": summary["left_road"],
            "completed_fraction": summary["completed_fraction"], "steps": summary["steps"],
            "latency_clamped_steps": summary.get("latency_clamped_steps", 0)}


def write_sweep_csv(sweep: dict, path: str | Path) -> None:
    """The sweep table, inside a report directory being staged."""
    write_csv_into(Path(path), SWEEP_COLUMNS, [[row[c] for c in SWEEP_COLUMNS] for row in sweep["rows"]])


def sweep_markdown(sweep: dict) -> list[str]:
    """Report lines: the sweep table, where each policy leaves the road, and the bias table."""
    by = {(r["policy"], round(r["latency_s"], 6)): r for r in sweep["rows"]}
    lines = ["| latency [s] | BM steering MAE | BM offset RMS [m] | PLM-Net steering MAE | PLM-Net offset RMS [m] |",
             "|---|---|---|---|---|"]
    for lat in sweep["latencies_s"]:
        cells = []
        for key in ("bm", "plm"):
            row = by.get((key, round(lat, 6)))
            if row is None:
                cells += ["—", "—"]
                continue
            off = " (left the road)" if row["left_road"] else ""
            cells += [f"{row['steering_mae']:.4f}{off}", f"{row['lateral_offset_rms_m']:.3f}"]
        lines.append(f"| {lat:.2f} | " + " | ".join(cells) + " |")
    lines.append("")
    for key, label in (("bm", "BM"), ("plm", "PLM-Net")):
        first = sweep["leaves_road_at_s"].get(key)
        lines.append(f"- {label} leaves the road first at **{first:.2f} s**." if first is not None
                     else f"- {label} stays on the road at every latency up to {max(sweep['latencies_s']):.2f} s.")
    biases = sweep["biases_s"]
    if biases:
        lines += ["", ("PLM-Net told a wrong latency (estimate = measured latency + bias, clipped at 0): steering MAE "
                  "against the BM without latency, and the offset RMS."), ""]
        header = "| latency [s] | told the measured latency | " + " | ".join(f"bias {b:+.2f} s" for b in biases) + " |"
        lines += [header, "|---" * (2 + len(biases)) + "|"]
        for lat in sweep["latencies_s"]:
            if not any((bias_key(b), round(lat, 6)) in by for b in biases):
                continue
            cells = []
            for key in ("plm", *(bias_key(b) for b in biases)):
                row = by.get((key, round(lat, 6)))
                cells.append("—" if row is None else f"{row['steering_mae']:.4f} / {row['lateral_offset_rms_m']:.3f} m"
                             + (" (left the road)" if row["left_road"] else ""))
            lines.append(f"| {lat:.2f} | " + " | ".join(cells) + " |")
        for bias in biases:
            first = sweep["leaves_road_at_s"].get(bias_key(bias))
            if first is not None:
                lines.append(f"- With bias {bias:+.2f} s PLM-Net leaves the road first at {first:.2f} s.")
    return lines
