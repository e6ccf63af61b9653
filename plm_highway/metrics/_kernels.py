"""numba kernels shared by the similaritymeasures drop-in and the strict curve metrics.

Each kernel does in compiled code what similaritymeasures 1.5.0 does in Python loops, in the same
order of operations, so that results agree to rounding (in practice bit for bit). The dynamic
programs keep two rows instead of the full matrix unless the caller asks for the matrix.
Comparisons use Python's ``min``/``max``, whose NaN behaviour (keep the first argument unless a
later one compares smaller/larger) numba reproduces, so NaN inputs propagate as in the original.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Point-to-point distances computed inside the kernels (anything else goes through scipy's cdist).
EUCLIDEAN, SQEUCLIDEAN, CITYBLOCK, CHEBYSHEV, MINKOWSKI = range(5)
_INLINE_METRICS = {"euclidean": EUCLIDEAN, "sqeuclidean": SQEUCLIDEAN, "cityblock": CITYBLOCK, "chebyshev": CHEBYSHEV}
# scipy computes these Minkowski p with the dedicated metrics; so do we, to share its rounding
_MINKOWSKI_SPECIAL_P = {1.0: CITYBLOCK, 2.0: EUCLIDEAN, math.inf: CHEBYSHEV}
# dtypes the kernels are compiled for; anything else runs the same code as plain Python. Only the
# dtypes whose scalar arithmetic numba and numpy share (numba widens small integers, numpy wraps).
NUMBA_DTYPES = frozenset(np.dtype(t) for t in ("float64", "float32", "int64"))


def minkowski_kind(p: float) -> int:
    """The kernel metric scipy uses for a Minkowski ``p`` (already validated by scipy)."""
    return _MINKOWSKI_SPECIAL_P.get(float(p), MINKOWSKI)


def inline_metric(metric, kwargs: dict) -> tuple[int, float] | None:
    """(kind, p) when the kernels compute scipy ``metric`` with ``kwargs`` themselves, else None.

    Only the canonical names with no keyword other than Minkowski's ``p``: aliases, weights,
    ``out=`` and callables go through scipy's cdist.
    """
    if not isinstance(metric, str):
        return None
    if metric == "minkowski" and set(kwargs) <= {"p"}:
        p = float(kwargs.get("p", 2.0))
        return minkowski_kind(p), p
    if metric in _INLINE_METRICS and not kwargs:
        return _INLINE_METRICS[metric], 2.0
    return None


# error_model="numpy": scipy's Minkowski with p = 0 computes 1 / p = inf, not an exception
@numba.njit(cache=True, error_model="numpy")
def fill_distance_row(point, curve_t, kind, p, out):
    """out[j] = distance(point, curve_t[:, j]), summed in scipy's order so results match cdist.

    The curve comes transposed, (n_dims, m), so that each inner loop runs over contiguous memory
    and vectorises; that makes it about 5x faster than walking (m, n_dims) rows.
    """
    out[:] = 0.0
    for k in range(curve_t.shape[0]):
        pk = point[k]
        coord = curve_t[k]
        if kind == EUCLIDEAN or kind == SQEUCLIDEAN:
            for j in range(out.shape[0]):
                diff = pk - coord[j]
                out[j] += diff * diff
        elif kind == CITYBLOCK:
            for j in range(out.shape[0]):
                out[j] += abs(pk - coord[j])
        elif kind == CHEBYSHEV:
            for j in range(out.shape[0]):
                out[j] = max(out[j], abs(pk - coord[j]))
        else:
            for j in range(out.shape[0]):
                out[j] += abs(pk - coord[j]) ** p
    if kind == EUCLIDEAN:
        for j in range(out.shape[0]):
            out[j] = np.sqrt(out[j])
    elif kind == MINKOWSKI:
        inv_p = 1.0 / p
        for j in range(out.shape[0]):
            out[j] = out[j] ** inv_p


@numba.njit(cache=True)
def frechet(exp, num_t, kind, p):
    """similaritymeasures.frechet_dist's table, two rows at a time; exp (M, N), num_t (N, P)."""
    m = num_t.shape[1]
    cost = np.empty(m)
    prev = np.empty(m)
    cur = np.empty(m)
    fill_distance_row(exp[0], num_t, kind, p, cost)
    prev[0] = cost[0]
    for j in range(1, m):
        prev[j] = max(prev[j - 1], cost[j])
    for i in range(1, exp.shape[0]):
        fill_distance_row(exp[i], num_t, kind, p, cost)
        cur[0] = max(prev[0], cost[0])
        for j in range(1, m):
            cur[j] = max(min(prev[j], cur[j - 1], prev[j - 1]), cost[j])
        prev, cur = cur, prev
    return prev[m - 1]


@numba.njit(cache=True)
def _dtw_first_row(cost, out):
    out[0] = cost[0]
    for j in range(1, cost.shape[0]):
        out[j] = out[j - 1] + cost[j]


@numba.njit(cache=True)
def _dtw_next_row(prev, cost, out):
    out[0] = prev[0] + cost[0]
    for j in range(1, cost.shape[0]):
        out[j] = cost[j] + min(prev[j], out[j - 1], prev[j - 1])


@numba.njit(cache=True)
def dtw_fill_matrix(exp, num_t, kind, p, acc):
    """acc (M, P) = similaritymeasures.dtw's cumulative cost matrix."""
    cost = np.empty(num_t.shape[1])
    fill_distance_row(exp[0], num_t, kind, p, cost)
    _dtw_first_row(cost, acc[0])
    for i in range(1, exp.shape[0]):
        fill_distance_row(exp[i], num_t, kind, p, cost)
        _dtw_next_row(acc[i - 1], cost, acc[i])


@numba.njit(cache=True)
def dtw_distance(exp, num_t, kind, p):
    """The last cell of similaritymeasures.dtw's matrix, without storing the matrix."""
    m = num_t.shape[1]
    cost = np.empty(m)
    prev = np.empty(m)
    cur = np.empty(m)
    fill_distance_row(exp[0], num_t, kind, p, cost)
    _dtw_first_row(cost, prev)
    for i in range(1, exp.shape[0]):
        fill_distance_row(exp[i], num_t, kind, p, cost)
        _dtw_next_row(prev, cost, cur)
        prev, cur = cur, prev
    return prev[m - 1]


@numba.njit(cache=True)
def dtw_fill_matrix_from_cost(cost, acc):
    _dtw_first_row(cost[0], acc[0])
    for i in range(1, cost.shape[0]):
        _dtw_next_row(acc[i - 1], cost[i], acc[i])


@numba.njit(cache=True)
def dtw_distance_from_cost(cost):
    m = cost.shape[1]
    prev = np.empty(m)
    cur = np.empty(m)
    _dtw_first_row(cost[0], prev)
    for i in range(1, cost.shape[0]):
        _dtw_next_row(prev, cost[i], cur)
        prev, cur = cur, prev
    return prev[m - 1]


@numba.njit(cache=True)
def dtw_path(d):
    """similaritymeasures.dtw_path's walk back from d[-1, -1], end first; d has >= 1 row and column.

    Also run as plain Python (``dtw_path.py_func``) for dtypes numba does not compile.
    """
    i = d.shape[0] - 1
    j = d.shape[1] - 1
    path = np.empty((i + j + 1, 2), dtype=np.int64)
    path[0, 0] = i
    path[0, 1] = j
    k = 0
    while i > 0 or j > 0:
        if i == 0:
            j = j - 1
        elif j == 0:
            i = i - 1
        else:
            up = d[i - 1, j]
            left = d[i, j - 1]
            diagonal = d[i - 1, j - 1]
            step = min(up, left, diagonal)
            if up == step:
                i = i - 1
            elif left == step:
                j = j - 1
            else:
                i = i - 1
                j = j - 1
        k += 1
        path[k, 0] = i
        path[k, 1] = j
    return path[: k + 1]


@numba.njit(cache=True)
def consecutive_distances(a, b):
    """Euclidean distance between a[i] and b[i] (float64 rows), scipy's cdist rounding."""
    out = np.zeros(a.shape[0])
    for i in range(a.shape[0]):
        total = 0.0
        for k in range(a.shape[1]):
            diff = a[i, k] - b[i, k]
            total += diff * diff
        out[i] = np.sqrt(total)
    return out


@numba.njit(cache=True)
def _np_interp_two_points(x, x0, x1, f0, f1):
    """np.interp(x, [x0, x1], [f0, f1]) with numpy's branch structure (arr_interp, 2-point xp)."""
    if np.isnan(x):
        return x
    if x > x1:
        return f1
    if x < x0:
        return f0
    if x >= x1:
        return f1
    if x == x0:
        return f0
    slope = (f1 - f0) / (x1 - x0)
    value = slope * (x - x0) + f0
    if np.isnan(value):
        value = slope * (x - x1) + f1
        if np.isnan(value) and f0 == f1:
            value = f0
    return value


@numba.njit(cache=True)
def _first_argmax(values, count):
    """np.argmax(values[:count]): the first maximum, or the first NaN if there is one."""
    best = 0
    if np.isnan(values[0]):
        return 0
    for k in range(1, count):
        if np.isnan(values[k]):
            return k
        if values[k] > values[best]:
            best = k
    return best


@numba.njit(cache=True)
def _row_distance(work, i):
    total = 0.0
    for k in range(work.shape[1]):
        diff = work[i, k] - work[i + 1, k]
        total += diff * diff
    return np.sqrt(total)


@numba.njit(cache=True)
def densify(num, n_points_out):
    """similaritymeasures' densification in area_between_two_curves: split the longest segment.

    Repeatedly splits the longest segment (Euclidean over every column, first maximum on ties)
    at its x midpoint, with y interpolated linearly, until the curve has ``n_points_out`` rows.
    Like ``np.insert`` in the original, the new row holds the midpoint x in every column but y,
    cast to ``num``'s dtype (so an integer curve gets truncated points). The original recomputes
    every segment per insertion (O(n^2) each); only the two new segments change, so we update
    those. ``num`` needs >= 2 rows and >= 2 columns.
    """
    n, n_cols = num.shape
    out = np.empty((n_points_out, n_cols), dtype=num.dtype)
    work = np.empty((n_points_out, n_cols))  # float64 copy: cdist measures in double precision
    for r in range(n):
        for c in range(n_cols):
            out[r, c] = num[r, c]
            work[r, c] = num[r, c]
    seg = np.empty(n_points_out - 1)
    for r in range(n - 1):
        seg[r] = _row_distance(work, r)
    x_sum = np.empty(1, dtype=num.dtype)  # numpy adds two float32 in float32, numba in float64
    for count in range(n, n_points_out):
        i = _first_argmax(seg, count - 1)
        xa = out[i, 0]
        xb = out[i + 1, 0]
        x_sum[0] = xb + xa
        new_x = x_sum[0] / 2.0
        # np.interp computes in float64 (numba's float() would keep a float32 a float32)
        x, left, right = np.float64(new_x), np.float64(out[i, 1]), np.float64(out[i + 1, 1])
        if xa < xb:
            new_y = _np_interp_two_points(x, np.float64(xa), np.float64(xb), left, right)
        else:
            new_y = _np_interp_two_points(x, np.float64(xb), np.float64(xa), right, left)
        for r in range(count, i + 1, -1):
            for c in range(n_cols):
                out[r, c] = out[r - 1, c]
                work[r, c] = work[r - 1, c]
        for r in range(count - 1, i + 1, -1):
            seg[r] = seg[r - 1]
        for c in range(n_cols):
            out[i + 1, c] = new_x
        out[i + 1, 1] = new_y
        for c in range(n_cols):
            work[i + 1, c] = out[i + 1, c]
        seg[i] = _row_distance(work, i)
        seg[i + 1] = _row_distance(work, i + 1)
    return out
