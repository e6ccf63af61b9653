"""Drop-in replacement for similaritymeasures 1.5.0: its whole public API, same results, faster.

    import plm_highway.metrics.similarity as similaritymeasures

Every public function of similaritymeasures 1.5.0 is here under the same name and signature:
``area_between_two_curves``, ``curve_length_measure``, ``dtw``, ``dtw_path``, ``frechet_dist``,
``get_arc_length``, ``get_length``, ``is_simple_quad``, ``makeQuad``, ``mae``, ``mse``,
``normalizeTwoCurves``, ``pcm`` and ``poly_area`` (plus the module attributes ``np``, ``distance``
and ``__version__`` it exposes). They return what the original returns (numpy scalars and arrays
of the same shape and dtype, equal to within 1e-9 relative, in practice bit for bit) and raise
the same exception type where it raises, on every input it accepts: lists, integer arrays,
non-contiguous arrays, N-dimensional curves, single points, repeated points, flat and zero-length
curves, NaN and inf. That includes the original's questionable answers, kept on purpose:

* ``pcm`` is NaN when ``exp_data`` has no x or y range, ``curve_length_measure`` NaN when
  ``exp_data`` has zero length and inf/NaN/negative when its mean x or y is <= 0;
* the x-y metrics read columns 0 and 1 only, yet ``area_between_two_curves`` measures segment
  lengths over every column when it densifies the shorter curve, and writes the midpoint x into
  the extra columns; on an integer curve the inserted points are truncated to integers;
* ``makeQuad`` reorders the lists it is given, in place;
* ``frechet_dist``/``dtw`` raise IndexError on a curve with no points.

:mod:`plm_highway.metrics.curves` (exported by :mod:`plm_highway.metrics`) holds the strict
versions the project uses: finite float curves of >= 2 points and exactly 2 columns for the x-y
metrics, a ValueError naming the argument otherwise (zero x/y range for ``pcm``, zero length for
``curve_length_measure``, p <= 0), computed in float64.

The quadratic parts (Frechet and DTW tables, the DTW path, the densification) run in numba, see
:mod:`plm_highway.metrics._kernels`; the rest is the original's numpy arithmetic, vectorised where
the original loops in Python, in the same order of operations. The original is similaritymeasures
1.5.0 by Charles Jekel (MIT License, Copyright (c) 2018, 2019 Charles Jekel).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import distance

from plm_highway.metrics import _kernels

__version__ = "1.5.0"  # the similaritymeasures release whose API and results this module reproduces

__all__ = [
    "area_between_two_curves",
    "curve_length_measure",
    "dtw",
    "dtw_path",
    "frechet_dist",
    "get_arc_length",
    "get_length",
    "is_simple_quad",
    "makeQuad",
    "mae",
    "mse",
    "normalizeTwoCurves",
    "pcm",
    "poly_area",
]

_PCM_N_OFFSETS = 200  # fixed in similaritymeasures.pcm
# dtypes whose quadrilateral arithmetic numpy does the same way element-wise as on the original's
# scalars (float32 is not: np.dot in poly_area sums float32 in another order); others loop
_QUAD_VECTOR_DTYPES = frozenset(np.dtype(t) for t in ("float64", "int64", "int32", "int16", "int8"))


class EmptyCurveError(IndexError, ValueError):
    """A curve or matrix with no points where similaritymeasures indexes its first one.

    similaritymeasures raises IndexError there; this is one, and also a ValueError so that the
    project's command line reports it as bad input.
    """


# --------------------------------------------------------------------------------------------
# helpers similaritymeasures exports
# --------------------------------------------------------------------------------------------


def poly_area(x, y):
    """Shoelace area of the polygon with vertices (x[i], y[i]) (not self-intersecting)."""
    return 0.5 * np.abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))


def _cross2d(a, b):
    a = np.asarray(a)
    b = np.asarray(b)
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def is_simple_quad(ab, bc, cd, da) -> bool:
    """True when the quadrilateral with edge vectors ab, bc, cd, da does not cross itself."""
    cross = np.array([_cross2d(ab, bc), _cross2d(bc, cd), _cross2d(cd, da), _cross2d(da, ab)])
    # the builtin sum (not np.sum), as in the original: a batch of quads fails the same way
    agreeing = cross <= 0 if sum(cross > 0) < sum(cross < 0) else cross >= 0
    return bool(sum(agreeing) > 2)


def _quad_is_simple(x, y) -> bool:
    edges = [[x[(k + 1) % 4] - x[k], y[(k + 1) % 4] - y[k]] for k in range(4)]
    return is_simple_quad(*edges)


def makeQuad(x, y):
    """Shoelace area of the quadrilateral (x[i], y[i]) after reordering it into a simple one.

    Like the original it reorders ``x`` and ``y`` in place: first the two first vertices are
    swapped, then (if still complex) vertices 1 and 2 of the original order; if neither order is
    simple the last one is measured.
    """
    if not _quad_is_simple(x, y):
        x[1], x[0] = x[0], x[1]
        y[1], y[0] = y[0], y[1]
        if not _quad_is_simple(x, y):
            x[2], x[0], x[1] = x[0], x[1], x[2]
            y[2], y[0], y[1] = y[0], y[1], y[2]
    return poly_area(x, y)


def get_arc_length(dataset):
    """(total arc length, arc length of each segment) of the curve ``dataset`` (n, d).

    The original takes the diagonal of an (n-1, n-1) cdist matrix; this computes the diagonal
    only (and, like np.diagonal, returns it read-only).
    """
    m = len(dataset)
    a = dataset[0 : m - 1, :]
    b = dataset[1:m, :]
    # scipy checks the shapes and the dtype: one row of each is enough to raise what it raises
    distance.cdist(a[:1], b[:1], "euclidean")
    arc_lengths = _kernels.consecutive_distances(
        np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64)
    )
    arc_lengths.flags.writeable = False
    return sum(arc_lengths), arc_lengths


def get_length(x, y, norm_seg_length=True):
    """(segment lengths, total length, cumulative length) of the curve (x, y).

    With ``norm_seg_length`` x and y are divided by their largest magnitude first (1e-15 when that
    is 0, as in the original). The first segment length and cumulative length are 0.
    """
    n = len(x)
    if norm_seg_length:
        xmax = np.max(np.abs(x))
        ymax = np.max(np.abs(y))
        if xmax == 0:
            xmax = 1e-15
        if ymax == 0:
            ymax = 1e-15
    else:
        xmax = ymax = 1.0
    if n == 0:
        # the original's first write, le[0] = 0.0, fails on an empty curve
        raise EmptyCurveError("x: has no points (index 0 is out of bounds for axis 0 with size 0)")
    x_arr, y_arr = np.asarray(x), np.asarray(y)
    if not _same_arithmetic_vectorised(x, y, x_arr, y_arr):
        return _get_length_loop(x, y, n, xmax, ymax)
    if n > 1 and len(y_arr) < n:
        raise IndexError(f"y: index {len(y_arr)} is out of bounds for axis 0 with size {len(y_arr)} (x has {n})")
    le = np.zeros(n)
    le[1:] = np.sqrt(((x_arr[1:] - x_arr[:-1]) / xmax) ** 2 + ((y_arr[1:n] - y_arr[: n - 1]) / ymax) ** 2)
    # a sequential cumsum from le[0] = 0 adds in the original loop's order
    return le, np.sum(le), np.cumsum(le)


def _same_arithmetic_vectorised(x, y, x_arr: np.ndarray, y_arr: np.ndarray) -> bool:
    """Whether numpy on whole arrays computes what the original's loop computes on elements.

    It does for 1-D real arrays, except that the loop's elements of a Python list are "weak"
    Python scalars: next to a float32 array they are computed in float32, as arrays in float64.
    """
    if not (x_arr.ndim == 1 and y_arr.ndim == 1 and x_arr.dtype.kind in "iuf" and y_arr.dtype.kind in "iuf"):
        return False
    both_arrays = isinstance(x, np.ndarray) and isinstance(y, np.ndarray)
    return both_arrays or all(a.dtype.itemsize >= 8 or a.dtype.kind != "f" for a in (x_arr, y_arr))


def _get_length_loop(x, y, n, xmax, ymax):
    """get_length's original loop, where whole-array numpy would differ (same errors and rounding)."""
    le = np.zeros(n)
    l_sum = np.zeros(n)
    for i in range(n - 1):
        le[i + 1] = np.sqrt((((x[i + 1] - x[i]) / xmax) ** 2) + (((y[i + 1] - y[i]) / ymax) ** 2))
        l_sum[i + 1] = l_sum[i] + le[i + 1]
    return le, np.sum(le), l_sum


def normalizeTwoCurves(x, y, w, z):
    """(x, y) scaled to [0, 1] by their own ranges, and (w, z) by the same ranges (for PCM)."""
    min_x, max_x = np.min(x), np.max(x)
    min_y, max_y = np.min(y), np.max(y)
    xi = (x - min_x) / (max_x - min_x)
    eta = (y - min_y) / (max_y - min_y)
    xi_p = (w - min_x) / (max_x - min_x)
    eta_p = (z - min_y) / (max_y - min_y)
    return xi, eta, xi_p, eta_p


# --------------------------------------------------------------------------------------------
# curve metrics
# --------------------------------------------------------------------------------------------


def _cdist_inputs(exp_data, num_data, metric: str, kwargs: dict) -> tuple[np.ndarray, np.ndarray]:
    """exp_data and num_data as scipy's cdist reads them (float64), after cdist's own checks."""
    exp = np.asarray(exp_data)
    num = np.asarray(num_data)
    # cdist raises on the shapes first, and on the dtype or keywords for any row: one row each
    probe = (exp, num) if exp.ndim != 2 or num.ndim != 2 else (exp[:1], num[:1])
    distance.cdist(*probe, metric=metric, **kwargs)
    return np.ascontiguousarray(exp, dtype=np.float64), np.ascontiguousarray(num, dtype=np.float64)


def _check_not_empty(shape: tuple[int, int]) -> None:
    """The original reads the first cell of an (M, P) table; M or P == 0 is an IndexError there."""
    for axis, (size, name) in enumerate(zip(shape, ("exp_data", "num_data"))):
        if size == 0:
            raise EmptyCurveError(f"{name}: has no points (index 0 is out of bounds for axis {axis} with size 0)")


def frechet_dist(exp_data, num_data, p=2):
    """Discrete Frechet distance between (M, N) and (P, N) curves, Minkowski p-norm points."""
    n_exp, n_num = len(exp_data), len(num_data)  # the original starts here: a scalar is a TypeError
    exp, num = _cdist_inputs(exp_data, num_data, "minkowski", {"p": p})
    _check_not_empty((n_exp, n_num))
    p = float(p)
    return np.float64(_kernels.frechet(exp, np.ascontiguousarray(num.T), _kernels.minkowski_kind(p), p))


def dtw(exp_data, num_data, metric="euclidean", **kwargs):
    """(DTW distance, cumulative cost matrix (M, P)); ``metric`` and ``**kwargs`` as scipy's cdist."""
    inline = _kernels.inline_metric(metric, kwargs)
    if inline is None:
        cost = distance.cdist(exp_data, num_data, metric=metric, **kwargs)
        _check_not_empty(cost.shape)
        acc = np.empty(cost.shape)
        _kernels.dtw_fill_matrix_from_cost(cost, acc)
        return acc[-1, -1], acc
    exp, num = _cdist_inputs(exp_data, num_data, metric, kwargs)
    _check_not_empty((len(exp), len(num)))
    # numpy asks for huge pages on big arrays: np.empty's page faults on a 6000 x 6000 matrix
    # cost 0.2 s on this kind of VM, numba's allocator 0.03 s; the kernel fills every cell
    acc = np.empty((len(exp), len(num)))
    _kernels.dtw_fill_matrix(exp, np.ascontiguousarray(num.T), *inline, acc)
    return acc[-1, -1], acc


def dtw_path(d):
    """Optimal DTW path (k, 2) through the cumulative cost matrix ``d``, from [0, 0] to the end.

    path[:, 0] indexes exp_data, path[:, 1] num_data; ties go to the step up, then left, then
    diagonal, as in the original.
    """
    rows, cols = d.shape
    if rows == 0 or cols == 0:
        # the original's walk starts at (rows - 1, cols - 1) and reads d only on a real step
        if rows <= 1 and cols <= 1:
            return np.array([(rows - 1, cols - 1)])[::-1]
        raise EmptyCurveError(f"d: has shape {d.shape}, no cell to walk back from")
    numba_ready = type(d) is np.ndarray and d.dtype in _kernels.NUMBA_DTYPES
    walk = _kernels.dtw_path if numba_ready else _kernels.dtw_path.py_func
    return walk(d)[::-1]


def _densify(num, arc_lengths, n_points_out: int):
    """The original's densification loop (see _kernels.densify), failing where it fails."""
    num[0 : len(num) - 1, 0]  # the loop's first read: a curve without columns is an IndexError
    if len(arc_lengths) == 0:
        raise ValueError("attempt to get argmax of an empty sequence (num_data has a single point)")
    num[0, 1]  # then it reads y: a single-column curve is an IndexError
    num = np.asarray(num)
    kernel = _kernels.densify if num.dtype in _kernels.NUMBA_DTYPES else _kernels.densify.py_func
    return kernel(num, n_points_out)


def _edge_cross_products(vx: list, vy: list) -> np.ndarray:
    """Cross products AB x BC, BC x CD, CD x DA, DA x AB of quads with vertices (vx[i], vy[i])."""
    ex = [vx[(i + 1) % 4] - vx[i] for i in range(4)]
    ey = [vy[(i + 1) % 4] - vy[i] for i in range(4)]
    return np.stack([ex[i] * ey[(i + 1) % 4] - ey[i] * ex[(i + 1) % 4] for i in range(4)])


def _quads_are_simple(vx: list, vy: list) -> np.ndarray:
    """is_simple_quad for a batch of quads."""
    cross = _edge_cross_products(vx, vy)
    mostly_negative = (cross > 0).sum(axis=0) < (cross < 0).sum(axis=0)
    agreeing = np.where(mostly_negative, cross <= 0, cross >= 0)
    return agreeing.sum(axis=0) > 2


def _shoelace_areas(vx: list, vy: list) -> np.ndarray:
    """poly_area for a batch of quads, summed in np.dot's order."""
    x0, x1, x2, x3 = vx
    y0, y1, y2, y3 = vy
    forward = x0 * y3 + x1 * y0 + x2 * y1 + x3 * y2
    backward = y0 * x3 + y1 * x0 + y2 * x1 + y3 * x2
    return 0.5 * np.abs(forward - backward)


def _quad_areas(exp: np.ndarray, num: np.ndarray) -> np.ndarray:
    """makeQuad over quads (exp[i-1], exp[i], num[i], num[i-1]), all at once."""
    corners = (exp[:-1], exp[1:], num[1:], num[:-1])
    areas = None
    simple_so_far = None
    # makeQuad tries these vertex orders in turn and keeps the first simple one, else the last
    for order in ((0, 1, 2, 3), (1, 0, 2, 3), (0, 2, 1, 3)):
        vx = [corners[k][:, 0] for k in order]
        vy = [corners[k][:, 1] for k in order]
        area = _shoelace_areas(vx, vy)
        if areas is None:
            areas, simple_so_far = area, _quads_are_simple(vx, vy)
            continue
        areas = np.where(simple_so_far, areas, area)
        simple_so_far = simple_so_far | _quads_are_simple(vx, vy)
    return areas


def _sum_of_quad_areas(exp_data, num_data, n_exp: int):
    vectorisable = all(
        type(c) is np.ndarray and c.ndim == 2 and c.shape[1] >= 2 and c.dtype in _QUAD_VECTOR_DTYPES
        for c in (exp_data, num_data)
    ) and len(exp_data) == len(num_data) == n_exp
    if n_exp < 2 or not vectorisable:
        # the original loop: it fails where the original fails and keeps its scalar arithmetic
        areas = []
        for i in range(1, n_exp):
            x = [exp_data[i - 1, 0], exp_data[i, 0], num_data[i, 0], num_data[i - 1, 0]]
            y = [exp_data[i - 1, 1], exp_data[i, 1], num_data[i, 1], num_data[i - 1, 1]]
            areas.append(makeQuad(x, y))
        return np.sum(areas)
    return np.sum(_quad_areas(exp_data[:, :2], num_data[:, :2]))


def area_between_two_curves(exp_data, num_data):
    """Area between two x-y curves by quadrilaterals (Jekel et al. 2018).

    The shorter curve is densified first, by splitting its longest segment at the x midpoint
    until both curves have the same number of points.
    """
    n_exp, n_num = len(exp_data), len(num_data)
    if n_exp < n_num:
        exp_data, num_data = num_data.copy(), exp_data.copy()
        n_exp, n_num = n_num, n_exp
    _, arc_lengths = get_arc_length(num_data)
    if n_exp > n_num:
        num_data = _densify(num_data, arc_lengths, n_exp)
    return _sum_of_quad_areas(exp_data, num_data, n_exp)


def curve_length_measure(exp_data, num_data):
    """Curve length measure (Andrade-Campos et al. 2012, OF2 form) of two x-y curves.

    It divides by the mean x and y of exp_data: NaN or inf when those are 0, negative terms when
    they are negative.
    """
    x_e = exp_data[:, 0]
    y_e = exp_data[:, 1]
    x_c = num_data[:, 0]
    y_c = num_data[:, 1]
    _, le_nj, le_sum = get_length(x_e, y_e)
    _, lc_nj, lc_sum = get_length(x_c, y_c)
    xmean = np.mean(x_e)
    ymean = np.mean(y_e)
    lieq = le_sum * (lc_nj / le_nj)
    xinterp = np.interp(lieq, lc_sum, x_c)
    yinterp = np.interp(lieq, lc_sum, y_c)
    r_sq = np.log(1.0 + (np.abs(xinterp - x_e) / xmean)) ** 2
    r_sq += np.log(1.0 + (np.abs(yinterp - y_e) / ymean)) ** 2
    return np.sqrt(np.sum(r_sq))


def pcm(exp_data, num_data, norm_seg_length=False):
    """Partial Curve Mapping area (Witowski and Stander 2012) of two x-y curves.

    Both curves are scaled by exp_data's x and y ranges; the shorter (in scaled length) slides
    along the longer at 200 offsets and the smallest area counts.
    """
    xi1, eta1, xi2, eta2 = normalizeTwoCurves(exp_data[:, 0], exp_data[:, 1], num_data[:, 0], num_data[:, 1])
    _, le_nj, le_sum = get_length(xi1, eta1, norm_seg_length)
    _, lc_nj, lc_sum = get_length(xi2, eta2, norm_seg_length)
    if lc_nj > le_nj:
        xi1, eta1, xi2, eta2 = xi2, eta2, xi1, eta1
        le_nj, le_sum, lc_nj, lc_sum = lc_nj, lc_sum, le_nj, le_sum
    le_sum = le_sum / le_nj
    lc_sum = lc_sum / lc_nj
    max_offset = le_nj - lc_nj
    offsets = [0.0] if max_offset == 0.0 else np.linspace(0.0, max_offset, _PCM_N_OFFSETS)
    areas = np.zeros(len(offsets))
    for k, offset in enumerate(offsets):
        shifted = le_sum + offset
        d = np.sqrt((eta1 - np.interp(shifted, lc_sum, eta2)) ** 2 + (xi1 - np.interp(shifted, lc_sum, xi2)) ** 2)
        # weighted by the cumulative (not the segment) length: the original's formula, kept as is
        areas[k] = np.sum(0.5 * (d[:-1] + d[1 : len(le_sum)]) * le_sum[1 : len(le_sum)])
    return np.min(areas)


def mae(exp_data, num_data):
    """Mean absolute difference of two curves of equal shape (over every coordinate)."""
    return np.mean(np.abs(exp_data - num_data))


def mse(exp_data, num_data):
    """Mean squared difference of two curves of equal shape (over every coordinate)."""
    return np.mean(np.square(exp_data - num_data))
