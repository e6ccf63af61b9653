"""Steering error of the delayed runs against the reference run, step by step."""

from __future__ import annotations

import numpy as np


def _errors(reference: np.ndarray, other: np.ndarray) -> dict:
    n = min(len(reference), len(other))  # a run that left the road is compared over its length
    diff = other[:n] - reference[:n]
    return {"mae": float(np.mean(np.abs(diff))), "mse": float(np.mean(diff ** 2)),
            "rmse": float(np.sqrt(np.mean(diff ** 2))), "steps_compared": int(n)}


def steering_comparison(logs: dict) -> dict:
    reference = logs["reference"].columns["steering"]
    baseline = _errors(reference, logs["baseline"].columns["steering"])
    mitigated = _errors(reference, logs["mitigated"].columns["steering"])
    reduction = 100.0 * (1.0 - mitigated["mae"] / baseline["mae"]) if baseline["mae"] > 0 else 0.0
    return {"baseline": baseline, "mitigated": mitigated, "mae_reduction_pct": reduction}
