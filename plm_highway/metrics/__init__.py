"""Trajectory, steering and lane-keeping metrics.

``curves`` holds fast drop-in replacements for similaritymeasures 1.5.0 (same names, arguments
and results) plus arc-length resampling; ``steering`` the error of a steering series; ``lane`` a
reconstruction of the DTSI lane-keeping index.
"""

from plm_highway.metrics.curves import (
    area_between_two_curves,
    curve_length_measure,
    dtw,
    frechet_dist,
    pcm,
    resample_by_arc_length,
)
from plm_highway.metrics.lane import LaneDeviation, dtsi, lane_deviation
from plm_highway.metrics.steering import mae, mse, rmse

__all__ = [
    "LaneDeviation",
    "area_between_two_curves",
    "curve_length_measure",
    "dtsi",
    "dtw",
    "frechet_dist",
    "lane_deviation",
    "mae",
    "mse",
    "pcm",
    "resample_by_arc_length",
    "rmse",
]
