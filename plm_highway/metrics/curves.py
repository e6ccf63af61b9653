"""Strict curve metrics: similaritymeasures' measures for clean curves, errors that name the culprit.

``frechet_dist``, ``dtw``, ``area_between_two_curves``, ``curve_length_measure`` and ``pcm`` take
the arguments of their similaritymeasures 1.5.0 namesakes and return the same values (they call
the drop-in :mod:`plm_highway.metrics.similarity`), as Python floats, but refuse what the drop-in,
like the original, answers with NaN, an IndexError or an arbitrary value:

* curves must be finite 2-D arrays of >= 2 points, read as float64 (so an integer curve is not
  truncated where ``area_between_two_curves`` inserts points, as it is in the original);
* the x-y metrics (``pcm``, ``area_between_two_curves``, ``curve_length_measure``) take exactly 2
  columns (the original ignores extra ones), the others the same number of columns in both;
* the Minkowski ``p`` must be > 0 (scipy returns inf or a non-norm for p <= 0);
* ``pcm`` refuses an ``exp_data`` with zero x or y range and ``curve_length_measure`` one of zero
  length (all points coincide), where the original returns NaN.

All of these raise ValueError naming the argument. ``dtw`` also takes ``return_matrix=False`` to
return the distance alone without allocating the (M, P) matrix. ``resample_by_arc_length``
resamples a polyline at a fixed arc-length spacing.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import distance

from plm_highway.metrics import _kernels, similarity
from plm_highway.metrics._validation import as_curve

__all__ = [
    "area_between_two_curves",
    "curve_length_measure",
    "dtw",
    "frechet_dist",
    "pcm",
    "resample_by_arc_length",
]

_MAX_RESAMPLED_POINTS = 10_000_000


def _curve_pair(exp_data, num_data, n_dims: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    exp = as_curve(exp_data, "exp_data", n_dims)
    num = as_curve(num_data, "num_data", n_dims)
    if exp.shape[1] != num.shape[1]:
        raise ValueError(
            f"exp_data and num_data: different numbers of columns ({exp.shape[1]} vs {num.shape[1]})"
        )
    return exp, num


def _check_minkowski_p(p) -> float:
    p = float(p)
    if not p > 0:
        raise ValueError(f"p: the Minkowski p-norm needs p > 0, got {p}")
    return p


def frechet_dist(exp_data, num_data, p=2) -> float:
    """Discrete Frechet distance between (M, N) and (P, N) curves, Minkowski p-norm points."""
    exp, num = _curve_pair(exp_data, num_data)
    return float(similarity.frechet_dist(exp, num, _check_minkowski_p(p)))


def dtw(exp_data, num_data, metric="euclidean", *, return_matrix=True, **kwargs):
    """Dynamic Time Warping distance; ``metric`` and ``**kwargs`` as scipy's cdist.

    Returns ``(distance, cumulative_cost_matrix)`` like similaritymeasures, or only the float
    distance with ``return_matrix=False``, which also avoids the (M, P) allocations.
    """
    exp, num = _curve_pair(exp_data, num_data)
    if isinstance(metric, str) and metric.lower() in ("minkowski", "mi", "m", "pnorm") and "p" in kwargs:
        kwargs["p"] = _check_minkowski_p(kwargs["p"])
    if return_matrix:
        value, matrix = similarity.dtw(exp, num, metric, **kwargs)
        return float(value), matrix
    inline = _kernels.inline_metric(metric, kwargs)
    if inline is None:
        return float(_kernels.dtw_distance_from_cost(distance.cdist(exp, num, metric=metric, **kwargs)))
    return float(_kernels.dtw_distance(exp, np.ascontiguousarray(num.T), *inline))


def area_between_two_curves(exp_data, num_data) -> float:
    """Area between two x-y curves by quadrilaterals (Jekel et al. 2018), as similaritymeasures.

    Like the original, the shorter curve is densified first by repeatedly splitting its longest
    segment at the x midpoint until both curves have the same number of points.
    """
    exp, num = _curve_pair(exp_data, num_data, n_dims=2)
    return float(similarity.area_between_two_curves(exp, num))


def curve_length_measure(exp_data, num_data) -> float:
    """Curve length measure (Andrade-Campos et al. 2012, OF2 form), as similaritymeasures.

    Like the original it divides by the mean x and y of exp_data, so it is NaN or inf when those
    are zero or negative: use coordinates with a positive origin.
    """
    exp, num = _curve_pair(exp_data, num_data, n_dims=2)
    if np.all(exp == exp[0]):
        raise ValueError("exp_data: curve has zero length (all points coincide)")
    return float(similarity.curve_length_measure(exp, num))


def pcm(exp_data, num_data, norm_seg_length=False) -> float:
    """Partial Curve Mapping area (Witowski and Stander 2012), as similaritymeasures."""
    exp, num = _curve_pair(exp_data, num_data, n_dims=2)
    span = np.ptp(exp, axis=0)
    for axis, label in enumerate("xy"):
        if span[axis] == 0:
            raise ValueError(f"exp_data: {label} range is zero; pcm normalises both curves by it")
    # num_data collapsed to one point gives 0/0 in the length scaling; np.interp then returns that
    # point, as in the original, so the result is still its distance to exp_data
    with np.errstate(invalid="ignore"):
        return float(similarity.pcm(exp, num, norm_seg_length))


def resample_by_arc_length(xy, spacing_m: float) -> np.ndarray:
    """Points every ``spacing_m`` of arc length along the polyline ``xy`` (n, d), plus its end.

    PCM, DTW and curve length depend on how densely a curve is sampled, so compare curves only
    after resampling both at one spacing. Points are linear interpolation along cumulative arc
    length, so they lie on the original polyline; the first and last points are kept exactly and
    every gap (in arc length) is ``spacing_m`` except the last, which is in (0, spacing_m].
    Repeated consecutive points are dropped first.
    """
    curve = as_curve(xy, "xy")
    spacing_m = float(spacing_m)
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise ValueError(f"spacing_m: must be a positive finite number, got {spacing_m}")
    arc_m = np.concatenate(([0.0], np.cumsum(np.sqrt(np.sum(np.diff(curve, axis=0) ** 2, axis=1)))))
    total_m = arc_m[-1]
    if total_m == 0:
        raise ValueError("xy: curve has zero length (all points coincide)")
    kept = _drop_repeated_points(arc_m)
    curve, arc_m = curve[kept], arc_m[kept]
    n_gaps = math.floor(total_m / spacing_m)
    if n_gaps + 2 > _MAX_RESAMPLED_POINTS:
        raise ValueError(f"spacing_m: {spacing_m} m on a {total_m:.6g} m curve gives too many points")
    stations_m = spacing_m * np.arange(n_gaps + 1)
    # a last station within rounding of the end would duplicate the end point
    if n_gaps >= 1 and total_m - stations_m[-1] <= 1e-9 * spacing_m:
        stations_m[-1] = total_m
    else:
        stations_m = np.append(stations_m, total_m)
    out = np.column_stack([np.interp(stations_m, arc_m, curve[:, k]) for k in range(curve.shape[1])])
    out[0], out[-1] = curve[0], curve[-1]
    return out


def _drop_repeated_points(arc_m: np.ndarray) -> np.ndarray:
    """Indices of points that advance along the curve, always with the first and last point.

    Zero-length segments would give np.interp repeated abscissae. A repeated end point is kept and
    its twin before it dropped, so that the end stays exactly the input's (its twin may differ by
    less than the squared-distance underflow).
    """
    kept = np.flatnonzero(np.concatenate(([True], np.diff(arc_m) > 0)))
    kept[-1] = len(arc_m) - 1  # arc_m[-1] > 0, so kept[-1] is never the first point
    return kept
