"""The perception delay of a recording, estimated from its camera lane signal and its fast sensors.

A recording (:mod:`plm_highway.sim2real.record.recording`) may carry, beside its standard columns, what a camera
pipeline reported at each row about the lane:

========================  ========  =============================================================
column                    unit      meaning
========================  ========  =============================================================
``lane_offset``           m         the car's offset from the lane centre, left positive (empty: no frame)
``lane_heading``          rad       the car's heading minus the lane's
========================  ========  =============================================================

No capture timestamp: the row's time is when the measurement arrived. The latency estimator
(:mod:`plm_highway.latency.estimate`) aligns that late lane signal with the car's own yaw rate (the
``yaw_rate`` column, or the heading's derivative without one), speed and steering, and finds how late the
camera is. :func:`perception_delay_lines` puts that beside the diagnosis's own delays (the steering's
transport delay, a late gyro) in the sim2real report; a recording without the lane columns says so.
"""

from __future__ import annotations

import os

import numpy as np

from plm_highway.latency.estimate import LatencyEstimatorConfig
from plm_highway.latency.lane_recording import DEFAULT_ESTIMATOR, LANE_COLUMNS, estimate_recording, read_lane_recording
from plm_highway.sim2real.physics.effects import DELAY_KEY, delay_estimates


def diagnosis_delays(diagnosis) -> dict[str, float]:
    """The delays a sim2real diagnosis fitted: ``{effect/parameter: seconds}`` of its chosen model; none when no
    model was fitted (a recording found inconsistent with itself gets no physics)."""
    if diagnosis.selection is None:
        return {}
    return {f"{effect}/{DELAY_KEY}": float(delay_s)
            for effect, delay_s in delay_estimates(diagnosis.selection.winner.estimates).items()}


def perception_delay(path: str | os.PathLike, config: LatencyEstimatorConfig = DEFAULT_ESTIMATOR,
                     vehicle_params=None) -> dict:
    """The perception delay the estimator finds in a recording: its last estimable estimate and how sure it was,
    or why there is none (``{"estimated": False, "reason": ...}``)."""
    columns = read_lane_recording(path)
    if columns is None:
        return {"estimated": False, "reason": "the recording has no camera-derived lane signal (columns "
                                              f"{', '.join(LANE_COLUMNS)}), so its perception delay cannot be estimated"}
    result = estimate_recording(columns, config, vehicle_params)
    estimable = result["estimable"]
    # Where nothing was claimed, the newest estimate sure enough to use (the held value moved off the prior) is
    # still reported, as not claimed: a recording is read once, and this says what its lane signal supports.
    moved = np.flatnonzero(np.abs(result["held_s"] - config.prior_latency_s) > 1e-12)
    if not estimable.any() and not moved.size:
        return {"estimated": False, "reason": "the recording's driving never carried enough information to align "
                                              "its lane signal (not estimable)",
                "rows": int(len(estimable))}
    last = int(np.flatnonzero(estimable)[-1]) if estimable.any() else int(moved[-1])
    return {"estimated": True, "claimed": bool(estimable.any()), "latency_s": float(result["held_s"][last]),
            "std_s": float(result["std_s"][last]), "estimable_fraction": float(estimable.mean()),
            "rows": int(len(estimable)),
            "median_estimable_s": float(np.median(result["latency_s"][estimable])) if estimable.any() else None}


def perception_delay_lines(found: dict, delays: dict[str, float]) -> list[str]:
    """The sim2real report's section: the camera's perception delay beside the diagnosis's delays."""
    lines = ["## Perception delay", ""]
    if found.get("estimated") and found.get("claimed", True):
        lines.append(f"The camera's lane signal is {found['latency_s']:.3f} s +- {found['std_s']:.3f} s late "
                     f"(latency estimator, no capture timestamps; claimed on {100 * found['estimable_fraction']:.0f}% "
                     f"of {found['rows']} rows, median {found['median_estimable_s']:.3f} s).")
    elif found.get("estimated"):
        lines.append(f"The camera's lane signal is about {found['latency_s']:.3f} s +- {found['std_s']:.3f} s late "
                     f"(latency estimator, no capture timestamps): its newest sure estimate, never claimed on the "
                     f"{found['rows']} rows, because it did not hold still long enough to be.")
    else:
        lines.append(f"Not estimated: {found['reason']}.")
    if delays:
        lines.append("The diagnosis's own delays (vehicle side): "
                     + ", ".join(f"{name} {value:.3f} s" for name, value in delays.items()) + ".")
    else:
        lines.append("The diagnosis fitted no delay on the vehicle side.")
    return lines + [""]
