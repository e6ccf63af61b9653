"""What one closed-loop run achieved, on the lane as well as on the steering, over the whole scored track.

A run is judged against the **reference**: the same policy's Base Model driving the same track, seed and start
without latency. Steering that follows the reference's trace closely can still let the car swing across its lane
(the offset integrates small, slow steering errors twice), so the lane is measured directly beside the steering:

- ``steering_mae_paper``: steering MAE against the reference over the reference's whole run, in the paper's unit
  (1 = 450 deg of steering wheel), every step the run missed after leaving the road counted as an error of
  :data:`~plm_highway.evaluation.protocol.OFF_ROAD_PENALTY` (normalised steering). The primary steering outcome.
- ``steering_mae_paper_common``: the same over the steps both runs reached only (secondary: it stops judging a
  run when it leaves the road).
- ``offset_rms_m`` / ``offset_max_m``: the lateral offset from the starting lane's centre over the whole scored
  track; steps missed after leaving the road count at the offset the car left with (it is off the road for the
  rest of the track, at least that far out). ``offset_rms_driven_m`` covers the driven steps only.
- ``frechet_m``: discrete Frechet distance between the run's path and the reference's path, both resampled every
  :data:`~plm_highway.evaluation.trajectory.RESAMPLE_SPACING_M` of arc length (see that module for why).
- ``left_road`` with ``left_road_t_s`` and ``left_road_arc_m``: when and where the car's centre left the road.
"""

from __future__ import annotations

import math

import numpy as np

from plm_highway.evaluation.protocol import OFF_ROAD_PENALTY, off_road_outcome, penalised_mae, to_paper_units
from plm_highway.evaluation.trajectory import RESAMPLE_SPACING_M
from plm_highway.metrics import frechet_dist, resample_by_arc_length
from plm_highway.metrics.steering import common_span, steering_mae

OUTCOMES = ("steering_mae_paper", "steering_mae_paper_common", "offset_rms_m", "offset_max_m", "offset_rms_driven_m",
            "frechet_m", "left_road", "left_road_t_s", "left_road_arc_m", "steps_driven", "steps_scored")
OUTCOME_LABELS = {
    "steering_mae_paper": "steering MAE vs reference, whole track, penalised (paper unit)",
    "steering_mae_paper_common": "steering MAE vs reference, common span (paper unit)",
    "offset_rms_m": "lateral offset RMS, whole track [m]",
    "offset_max_m": "max |lateral offset|, whole track [m]",
    "offset_rms_driven_m": "lateral offset RMS, driven steps only [m]",
    "frechet_m": "Frechet distance to the reference path [m]",
}


def run_outcomes(log, reference, track_spec, max_steering_rad: float) -> dict:
    """The outcomes (:data:`OUTCOMES`) of run ``log`` against ``reference`` (both :class:`RunLog`) on
    ``track_spec``; ``max_steering_rad`` is the front-wheel angle at normalised steering 1 under the run's
    conditions (the paper-unit conversion needs it). ``track_spec`` is kept for the geometry of later outcomes."""
    del track_spec  # both paths are in world coordinates; the reference run is the yardstick
    steering = np.asarray(log.columns["steering"], dtype=float)
    reference_steering = np.asarray(reference.columns["steering"], dtype=float)
    steps_scored = len(reference_steering)
    whole = penalised_mae(reference_steering, steering[:steps_scored], OFF_ROAD_PENALTY)
    common = steering_mae(*common_span(reference_steering, steering))
    offset_m = np.abs(np.asarray(log.columns["lateral_offset_m"], dtype=float))[:steps_scored]
    missed = steps_scored - len(offset_m)
    offset_whole_m = np.concatenate([offset_m, np.full(max(missed, 0), offset_m[-1] if len(offset_m) else 0.0)])
    off_road = off_road_outcome(log)
    return {
        "steering_mae_paper": to_paper_units(whole, "mae", max_steering_rad),
        "steering_mae_paper_common": to_paper_units(common, "mae", max_steering_rad),
        "offset_rms_m": float(np.sqrt(np.mean(offset_whole_m ** 2))),
        "offset_max_m": float(np.max(offset_whole_m)),
        "offset_rms_driven_m": float(np.sqrt(np.mean(offset_m ** 2))),
        "frechet_m": path_frechet_m(log.columns, reference.columns),
        "left_road": bool(log.left_road),
        "left_road_t_s": None if off_road is None else off_road["t_s"],
        "left_road_arc_m": None if off_road is None else off_road["arc_length_m"],
        "steps_driven": int(len(steering)),
        "steps_scored": int(steps_scored),
    }


def path_frechet_m(columns: dict, reference_columns: dict, spacing_m: float = RESAMPLE_SPACING_M) -> float:
    """Discrete Frechet distance [m] between two runs' x, y paths, each resampled every ``spacing_m``; NaN when
    either path has no length (a run stopped at its first step)."""
    paths = []
    for c in (columns, reference_columns):
        xy = np.column_stack([np.asarray(c["x_m"], dtype=float), np.asarray(c["y_m"], dtype=float)])
        if len(xy) < 2 or not np.any(np.ptp(xy, axis=0) > 0):
            return math.nan
        paths.append(resample_by_arc_length(xy, spacing_m))
    return float(frechet_dist(paths[0], paths[1]))


__all__ = ["OUTCOMES", "OUTCOME_LABELS", "path_frechet_m", "run_outcomes"]
