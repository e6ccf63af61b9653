"""Trajectory, steering and lane-keeping metrics.

* ``similarity``: the drop-in replacement for similaritymeasures 1.5.0, its whole public API with
  the same results and errors (``import plm_highway.metrics.similarity as similaritymeasures``);
* ``curves`` (exported here): the same curve metrics, strict about their input, plus arc-length
  resampling;
* ``steering``: the error of a steering series against a reference one (``steering_mae`` ...);
* ``lane``: a reconstruction of the DTSI lane-keeping index.
"""

from plm_highway.metrics import similarity
from plm_highway.metrics.curves import (
    area_between_two_curves,
    curve_length_measure,
    dtw,
    frechet_dist,
    pcm,
    resample_by_arc_length,
)
from plm_highway.metrics.lane import LaneDeviation, dtsi, lane_deviation
from plm_highway.metrics.steering import (
    common_span,
    reduction_pct,
    steering_errors,
    steering_mae,
    steering_mse,
    steering_rmse,
)

__all__ = [
    "LaneDeviation",
    "area_between_two_curves",
    "common_span",
    "curve_length_measure",
    "dtsi",
    "dtw",
    "frechet_dist",
    "lane_deviation",
    "pcm",
    "reduction_pct",
    "resample_by_arc_length",
    "similarity",
    "steering_errors",
    "steering_mae",
    "steering_mse",
    "steering_rmse",
]
