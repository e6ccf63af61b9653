"""Steering error of the delayed runs against the reference run, step by step.

Runs share the seed and start, so step k of every run is the same instant; a run that left the
road is compared over its length. The reductions are PLM-Net's against the baseline's error,
``100 * (1 - mitigated / baseline)``, as the paper reports them.
"""

from __future__ import annotations

import numpy as np

ERROR_NAMES = ("mae", "mse", "rmse")


def _errors(reference: np.ndarray, other: np.ndarray) -> dict:
    n = min(len(reference), len(other))  # a run that left the road is compared over its length
    diff = other[:n] - reference[:n]
    return {"mae": float(np.mean(np.abs(diff))), "mse": float(np.mean(diff ** 2)),
            "rmse": float(np.sqrt(np.mean(diff ** 2))), "steps_compared": int(n)}


def reduction_pct(baseline_error: float, mitigated_error: float) -> float:
    """How much smaller the mitigated error is than the baseline's, in % (0 when the baseline's is 0)."""
    return 100.0 * (1.0 - mitigated_error / baseline_error) if baseline_error > 0 else 0.0


def steering_errors(reference: np.ndarray, other: np.ndarray) -> dict:
    """MAE, MSE, RMSE of ``other`` against ``reference`` over their common length, and that length."""
    return _errors(np.asarray(reference, dtype=float), np.asarray(other, dtype=float))


def steering_comparison(logs: dict) -> dict:
    reference = logs["reference"].columns["steering"]
    baseline = _errors(reference, logs["baseline"].columns["steering"])
    mitigated = _errors(reference, logs["mitigated"].columns["steering"])
    result = {"baseline": baseline, "mitigated": mitigated,
              "mae_reduction_pct": reduction_pct(baseline["mae"], mitigated["mae"])}
    for name in ("mse", "rmse"):
        result[f"{name}_reduction_pct"] = reduction_pct(baseline[name], mitigated[name])
    return result
