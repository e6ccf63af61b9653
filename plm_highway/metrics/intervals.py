"""Means over seeds with their confidence intervals: the one definition every report uses.

:func:`mean_ci` gives the mean of a few values (one per seed) and the two-sided Student-t confidence
interval of that mean, ``mean +- t(1 - (1 - confidence) / 2, n - 1) * s / sqrt(n)`` with ``s`` the
sample standard deviation. The t quantile, not the normal one: with the handful of seeds a report runs,
the normal quantile would give intervals too narrow (at n = 5 the 95% t quantile is 2.776, the normal
1.960). With one value there is no spread to estimate, so the interval is undefined (``low`` and ``high``
are None), never a zero-width interval that would claim certainty.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

CONFIDENCE = 0.95


@dataclass(frozen=True)
class Estimate:
    """Mean of ``n`` values with its two-sided confidence interval (``low``, ``high`` None when n < 2).

    ``values``: the values themselves, in the order given (for reports that list them per seed).
    """

    mean: float
    low: float | None
    high: float | None
    n: int
    values: tuple[float, ...] = field(default=(), compare=False, repr=False)

    @property
    def half_width(self) -> float | None:
        return None if self.low is None else (self.high - self.low) / 2.0

    def as_dict(self) -> dict:
        """``{"mean", "low", "high", "n"}``, as the reports' JSON holds an estimate."""
        return {"mean": self.mean, "low": self.low, "high": self.high, "n": self.n}


def mean_ci(values: Iterable[float], confidence: float = CONFIDENCE) -> Estimate:
    """Mean of ``values`` and the Student-t confidence interval of the mean; ValueError unless there is at
    least one value and every value is finite (a caller drops or reports undefined values itself)."""
    data = np.asarray(list(values), dtype=float)
    if data.size == 0 or not np.all(np.isfinite(data)):
        raise ValueError(f"mean_ci: needs at least one finite value, got {data.tolist()}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"mean_ci: confidence {confidence!r} must lie in (0, 1)")
    mean = float(np.mean(data))
    kept = tuple(data.tolist())
    if data.size < 2:
        return Estimate(mean, None, None, 1, kept)
    sem = float(np.std(data, ddof=1) / math.sqrt(data.size))
    half = float(stats.t.ppf(0.5 + confidence / 2.0, data.size - 1)) * sem
    return Estimate(mean, mean - half, mean + half, int(data.size), kept)
