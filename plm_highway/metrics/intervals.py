"""Means over seeds or pairs with their confidence intervals: the one definition every report uses.

:func:`mean_ci` gives the mean of a few values (one per seed or per trained pair) and a two-sided Student-t
confidence interval, computed on the scale that respects the quantity:

- ``"linear"`` (a difference, a signed quantity): ``mean +- t(1 - (1 - confidence) / 2, n - 1) * s / sqrt(n)`` with
  ``s`` the sample standard deviation.
- ``"positive"`` (an RMS, an MAE, a Frechet distance, a maximum: never negative): the same interval of the logarithms,
  exponentiated (the interval of the geometric mean), so it lies in (0, inf). With a zero among the values the
  logarithm is undefined; the linear interval is used then, its lower end clipped at 0.
- ``"reduction"`` (``100 * (1 - mitigated / baseline)`` in %, never above 100%): the interval of the ratios
  ``mitigated / baseline`` on the log scale, mapped to ``100 * (1 - ratio)``, so it never exceeds 100%. With a ratio
  of 0 among them (a mitigated error of 0), the linear interval of the ratios, clipped at 0.

``mean`` is the arithmetic mean on every scale (what targets and ratios are judged on); ``centre`` is the interval's
own centre (the geometric mean, or ``100 * (1 - the geometric mean ratio)``), which the interval always contains. The
arithmetic mean of positive values is never below the geometric one; with 3 or 4 values it always lies inside the
interval too, with more and strongly skewed values it can lie above it (for a reduction: below it).

The t quantile, not the normal one: with the handful of seeds a report runs, the normal quantile would give
intervals too narrow (at n = 5 the 95% t quantile is 2.776, the normal 1.960). With fewer than
:data:`MIN_INTERVAL_VALUES` values the spread cannot be estimated usefully (at n = 2 the 95% t quantile is 12.7 and
an interval of an RMS would reach far below 0 on the linear scale), so the interval is undefined (``low`` and
``high`` are None) and reports say "too few ... for an interval" (:func:`interval_text`), never a zero-width or a
meaningless interval.

:func:`prediction_interval` gives the interval for one more value (one new seed or trained pair), on the same scale:
``t * s * sqrt(1 + 1/n)`` about the centre in the working scale.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
MIN_INTERVAL_VALUES = 3
SCALES = ("linear", "positive", "reduction")
MAX_LOG = math.log(np.finfo(float).max)


@dataclass(frozen=True)
class Estimate:
    """Mean of ``n`` values with its two-sided confidence interval (``low``, ``high`` None when n < 3).

    ``values``: the values themselves, in the order given (for reports that list them per seed).
    ``scale`` and ``centre``: the scale the interval is computed on and the interval's centre (module docstring).
    """

    mean: float
    low: float | None
    high: float | None
    n: int
    values: tuple[float, ...] = field(default=(), compare=False, repr=False)
    scale: str = field(default="linear", compare=False)
    centre: float | None = field(default=None, compare=False, repr=False)

    @property
    def half_width(self) -> float | None:
        """Half the interval's width (an interval off the linear scale is not symmetric about its centre)."""
        return None if self.low is None else (self.high - self.low) / 2.0

    def as_dict(self) -> dict:
        """``{"mean", "low", "high", "n"}``, as the reports' JSON holds an estimate."""
        return {"mean": self.mean, "low": self.low, "high": self.high, "n": self.n}


def too_few(what: str = "seeds") -> str:
    """What a report prints instead of an interval over fewer than :data:`MIN_INTERVAL_VALUES` ``what``."""
    return f"too few {what} for an interval"


def interval_text(centre: float | None, low: float | None, high: float | None, n: int, fmt=None, unit: str = "",
                  what: str = "seeds", short: bool = False) -> str:
    """``"centre unit [low, high]"``, or without an interval ``"centre unit (n=2, too few seeds for an interval)"``
    (``short``: ``"centre unit (n=2, no interval)"``, for tables whose text says why)."""
    fmt = fmt or (lambda value: f"{value:.3f}")
    shown = "n/a" if centre is None or not math.isfinite(centre) else f"{fmt(centre)}{unit}"
    if low is None or high is None:
        return f"{shown} (n={n}, {'no interval' if short else too_few(what)})"
    return f"{shown} [{fmt(low)}, {fmt(high)}]"


def _working(data: np.ndarray, scale: str) -> tuple[np.ndarray, bool]:
    """The values on the scale the t interval is computed on, and whether that scale is logarithmic."""
    if scale == "linear":
        return data, False
    if scale == "positive":
        if np.any(data < 0):
            raise ValueError(f"mean_ci: a positive quantity cannot be negative, got {data.tolist()}")
        quantity = data
    elif scale == "reduction":
        if np.any(data > 100.0):
            raise ValueError(f"mean_ci: a reduction cannot exceed 100%, got {data.tolist()}")
        quantity = 1.0 - data / 100.0  # the ratio mitigated / baseline
    else:
        raise ValueError(f"mean_ci: scale {scale!r}: expected one of {list(SCALES)}")
    if np.all(quantity > 0):
        return np.log(quantity), True
    return quantity, False  # a zero: the linear interval of the quantity, clipped at 0 below


def _back(value: float, scale: str, logged: bool) -> float:
    """A working-scale value on the quantity's scale."""
    if scale == "linear":
        return value
    # exp saturates at the largest float's logarithm: values spanning hundreds of decades give a finite bound
    quantity = math.exp(min(value, MAX_LOG)) if logged else max(0.0, value)
    return quantity if scale == "positive" else 100.0 * (1.0 - quantity)


def _bounds(centre: float, half: float, scale: str, logged: bool) -> tuple[float, float]:
    low, high = _back(centre - half, scale, logged), _back(centre + half, scale, logged)
    return (high, low) if scale == "reduction" else (low, high)  # a larger ratio is a smaller reduction


def _checked(values: Iterable[float], confidence: float) -> np.ndarray:
    data = np.asarray(list(values), dtype=float)
    if data.size == 0 or not np.all(np.isfinite(data)):
        raise ValueError(f"mean_ci: needs at least one finite value, got {data.tolist()}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"mean_ci: confidence {confidence!r} must lie in (0, 1)")
    return data


def _t_half(working: np.ndarray, confidence: float) -> float:
    """``t * s``: the working-scale half-width before dividing by sqrt(n) (a CI) or scaling by sqrt(1 + 1/n) (a PI)."""
    return float(stats.t.ppf(0.5 + confidence / 2.0, working.size - 1)) * float(np.std(working, ddof=1))


def mean_ci(values: Iterable[float], confidence: float = CONFIDENCE, scale: str = "linear") -> Estimate:
    """Mean of ``values`` and its confidence interval on ``scale`` (module docstring); ValueError unless there is
    at least one value, every value is finite and lies in the scale's range (a caller drops undefined values)."""
    data = _checked(values, confidence)
    working, logged = _working(data, scale)
    centre = float(np.mean(working))
    mean, kept = float(np.mean(data)), tuple(data.tolist())
    if data.size < MIN_INTERVAL_VALUES:
        return Estimate(mean, None, None, int(data.size), kept, scale, _back(centre, scale, logged))
    low, high = _bounds(centre, _t_half(working, confidence) / math.sqrt(data.size), scale, logged)
    return Estimate(mean, low, high, int(data.size), kept, scale, _back(centre, scale, logged))


def prediction_interval(values: Iterable[float], confidence: float = CONFIDENCE,
                        scale: str = "linear") -> tuple[float, float] | None:
    """The interval for one more value drawn like ``values``, on ``scale`` (None with fewer than
    :data:`MIN_INTERVAL_VALUES` values)."""
    data = _checked(values, confidence)
    if data.size < MIN_INTERVAL_VALUES:
        return None
    working, logged = _working(data, scale)
    half = _t_half(working, confidence) * math.sqrt(1.0 + 1.0 / data.size)
    return _bounds(float(np.mean(working)), half, scale, logged)
