"""Error of one steering series against a reference one, and how much one error reduces another.

Length rule: the two series are compared step by step, so they must have the same length (step k
of each is the same instant); a difference is a ValueError, never a silent cut. Runs that ended at
different steps (one left the road) are compared over the steps they all reached by saying so:
``steering_errors(*common_span(reference, other))``. Series are finite 1-D arrays of at least one
sample, in any one unit (the errors are in that unit, the MSE in its square).

The names carry ``steering_`` so that they do not shadow similaritymeasures' ``mae``/``mse``,
which compare two curves (see :mod:`plm_highway.metrics.similarity`).
"""

from __future__ import annotations

import numpy as np

from plm_highway.metrics._validation import as_series

__all__ = [
    "ERROR_NAMES",
    "common_span",
    "reduction_pct",
    "steering_errors",
    "steering_mae",
    "steering_mse",
    "steering_rmse",
]

ERROR_NAMES = ("mae", "mse", "rmse")  # the error keys of steering_errors, in report order


def common_span(*series) -> tuple[np.ndarray, ...]:
    """The series (finite, 1-D) cut to the steps every one of them reached: the first min(len) steps."""
    if not series:
        raise ValueError("common_span: needs at least one series")
    arrays = [as_series(values, f"series {k}", min_len=0) for k, values in enumerate(series)]
    n_steps = min(len(values) for values in arrays)
    return tuple(values[:n_steps] for values in arrays)


def _difference(reference, other) -> np.ndarray:
    ref = as_series(reference, "reference")
    oth = as_series(other, "other")
    if len(ref) != len(oth):
        raise ValueError(
            f"reference and other: lengths differ ({len(ref)} vs {len(oth)}); to compare the steps "
            "both reached, pass common_span(reference, other)"
        )
    return oth - ref


def steering_mae(reference, other) -> float:
    """Mean absolute error of ``other`` against ``reference`` (same length), in their unit."""
    return float(np.mean(np.abs(_difference(reference, other))))


def steering_mse(reference, other) -> float:
    """Mean squared error of ``other`` against ``reference`` (same length), in their unit squared."""
    return float(np.mean(np.square(_difference(reference, other))))


def steering_rmse(reference, other) -> float:
    """Root mean squared error of ``other`` against ``reference`` (same length), in their unit."""
    return float(np.sqrt(steering_mse(reference, other)))


def steering_errors(reference, other) -> dict:
    """``{"mae", "mse", "rmse", "steps_compared"}`` of ``other`` against ``reference`` (same length)."""
    diff = _difference(reference, other)
    mse = float(np.mean(np.square(diff)))
    return {"mae": float(np.mean(np.abs(diff))), "mse": mse, "rmse": float(np.sqrt(mse)), "steps_compared": len(diff)}


def reduction_pct(baseline_error: float, mitigated_error: float) -> float:
    """How much smaller the mitigated error is than the baseline's, in % (0 when the baseline's is 0).

    ``100 * (1 - mitigated / baseline)``, as PLM-Net's paper reports its reductions; negative when
    the mitigation makes the error larger.
    """
    return 100.0 * (1.0 - mitigated_error / baseline_error) if baseline_error > 0 else 0.0
