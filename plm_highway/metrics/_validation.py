"""Input checks shared by the metrics: every error names the argument and says what is wrong."""

from __future__ import annotations

import numpy as np

from plm_highway.errors import BadInput

_MAX_ROWS_LISTED = 10


def _rows_text(rows: np.ndarray) -> str:
    listed = ", ".join(str(int(r)) for r in rows[:_MAX_ROWS_LISTED])
    more = f", ... ({len(rows)} rows in all)" if len(rows) > _MAX_ROWS_LISTED else ""
    word = "row" if len(rows) == 1 else "rows"
    return f"{word} [{listed}{more}]"


def check_finite(values: np.ndarray, name: str) -> None:
    """Raise ValueError listing how many NaN / inf values ``values`` holds and in which rows."""
    if np.isfinite(values).all():
        return
    problems = []
    for label, mask in (("NaN", np.isnan(values)), ("inf", np.isinf(values))):
        count = int(mask.sum())
        if count:
            row_mask = mask if mask.ndim == 1 else mask.any(axis=tuple(range(1, mask.ndim)))
            noun = "value" if count == 1 else "values"
            problems.append(f"{count} {label} {noun} at {_rows_text(np.flatnonzero(row_mask))}")
    raise BadInput(f"{name}: " + "; ".join(problems))


def as_float_array(data, name: str) -> np.ndarray:
    try:
        return np.asarray(data, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise BadInput(f"{name}: cannot be read as an array of floats ({exc})") from exc


def as_curve(data, name: str, n_dims: int | None = None) -> np.ndarray:
    """A finite float64 array of shape (n_points >= 2, n_dims)."""
    curve = as_float_array(data, name)
    if curve.ndim != 2:
        hint = "; for a 1-D series pass values.reshape(-1, 1)" if curve.ndim == 1 else ""
        raise BadInput(
            f"{name}: expected a 2-D array of shape (n_points, n_dims), got shape {curve.shape}{hint}"
        )
    if n_dims is not None and curve.shape[1] != n_dims:
        raise BadInput(f"{name}: expected {n_dims} columns (x, y), got shape {curve.shape}")
    if curve.shape[1] < 1:
        raise BadInput(f"{name}: has no coordinate columns (shape {curve.shape})")
    if curve.shape[0] < 2:
        raise BadInput(f"{name}: needs at least 2 points, got {curve.shape[0]}")
    check_finite(curve, name)
    return curve


def as_series(data, name: str, min_len: int = 1) -> np.ndarray:
    """A finite 1-D float64 array with at least ``min_len`` samples."""
    series = as_float_array(data, name)
    if series.ndim != 1:
        raise BadInput(f"{name}: expected a 1-D array, got shape {series.shape}")
    if len(series) < min_len:
        noun = "sample" if min_len == 1 else "samples"
        raise BadInput(f"{name}: needs at least {min_len} {noun}, got {len(series)}")
    check_finite(series, name)
    return series


def check_same_length(a: np.ndarray, a_name: str, b: np.ndarray, b_name: str) -> None:
    if len(a) != len(b):
        raise BadInput(f"{a_name} and {b_name}: lengths differ ({len(a)} vs {len(b)})")
