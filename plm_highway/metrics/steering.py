"""Error between a reference and a predicted steering series (equal length, same units)."""

from __future__ import annotations

import numpy as np

from plm_highway.metrics._validation import as_series, check_same_length

__all__ = ["mae", "mse", "rmse"]


def _difference(reference, predicted) -> np.ndarray:
    ref = as_series(reference, "reference")
    pred = as_series(predicted, "predicted")
    check_same_length(ref, "reference", pred, "predicted")
    return pred - ref


def mae(reference, predicted) -> float:
    """Mean absolute error, in the series' units."""
    return float(np.mean(np.abs(_difference(reference, predicted))))


def mse(reference, predicted) -> float:
    """Mean squared error, in the series' units squared."""
    return float(np.mean(np.square(_difference(reference, predicted))))


def rmse(reference, predicted) -> float:
    """Root mean squared error, in the series' units."""
    return float(np.sqrt(mse(reference, predicted)))
