"""DTSI lane-keeping index, reconstructed from the OPEMI paper's description.

This is a RECONSTRUCTION, not the authors' code: the definitions below follow the paper's text
as summarised for this project, and constants are those stated there. From the signed distance
e (m) of the vehicle to the lane centre, sampled at times t (s):

* MDC  = mean |e|                                   (m)
* MMDC = mean f(|e|), a penalty that ignores small offsets and grows with large ones (m):
  f = 0 for |e| < 0.7071, |e| for |e| > 1.15, 5.256 (0.2 e^4 - 0.1 e^2) in between
* MDDC = mean |de/dt| over consecutive samples at most 1 s apart  (m/s)
* EMDC = 0.5 MMDC + 0.5 MDDC, the index ``dtsi`` returns (mixes m and m/s, as in the paper)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.metrics._validation import as_series, check_same_length

__all__ = ["LaneDeviation", "dtsi", "lane_deviation", "modified_offset_m"]

DEAD_ZONE_M = 0.7071  # below this offset MMDC does not penalise at all
LINEAR_FROM_M = 1.15  # above this offset the penalty is the offset itself
BLEND_GAIN = 5.256  # scales the quartic blend so that it roughly meets the linear part at 1.15 m
MAX_GAP_S = 1.0  # rate samples across a longer gap (a recording break) are not a derivative


@dataclass(frozen=True)
class LaneDeviation:
    """The four DTSI components; ``emdc`` is the index itself."""

    mdc_m: float
    mmdc_m: float
    mddc_m_per_s: float
    emdc: float


def modified_offset_m(abs_offset_m) -> np.ndarray:
    """The MMDC penalty f(|e|): zero in the dead zone, a quartic blend, then linear."""
    e = np.abs(np.asarray(abs_offset_m, dtype=np.float64))
    blend = BLEND_GAIN * (0.2 * e**4 - 0.1 * e**2)
    return np.where(e < DEAD_ZONE_M, 0.0, np.where(e > LINEAR_FROM_M, e, blend))


def _offset_rates_m_per_s(offset_m: np.ndarray, t_s: np.ndarray, max_gap_s: float) -> np.ndarray:
    gap_s = np.diff(t_s)
    kept = gap_s <= max_gap_s
    if not kept.any():
        raise BadInput(f"t_s: every time gap exceeds {max_gap_s} s, so MDDC is undefined")
    return np.abs(np.diff(offset_m)[kept]) / gap_s[kept]


def lane_deviation(offset_m, t_s, max_gap_s: float = MAX_GAP_S) -> LaneDeviation:
    """MDC, MMDC, MDDC and EMDC of a signed lane-centre offset series (see the module docstring)."""
    e = as_series(offset_m, "offset_m", min_len=2)
    t = as_series(t_s, "t_s", min_len=2)
    check_same_length(e, "offset_m", t, "t_s")
    if not np.all(np.diff(t) > 0):
        first = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise BadInput(f"t_s: must increase strictly, but t_s[{first + 1}] <= t_s[{first}]")
    mmdc = float(np.mean(modified_offset_m(e)))
    mddc = float(np.mean(_offset_rates_m_per_s(e, t, max_gap_s)))
    return LaneDeviation(
        mdc_m=float(np.mean(np.abs(e))),
        mmdc_m=mmdc,
        mddc_m_per_s=mddc,
        emdc=0.5 * mmdc + 0.5 * mddc,
    )


def dtsi(offset_m, t_s) -> float:
    """The DTSI index (EMDC) of a signed lane-centre offset ``offset_m`` sampled at ``t_s``."""
    return lane_deviation(offset_m, t_s).emdc
