"""A population's results, with the trained pair as the unit: per pair first, then across pairs.

Simulator seeds are near-replicates of one pair (the same weights, starts within +-0.2 m); the training run is
the larger source of variance. So every outcome is first averaged over a pair's seeds (seeds nested in pairs),
and the statistics are across pairs: the mean with its 95% Student-t confidence interval, and the 95%
**prediction interval** for one new pair made with the same recipe, ``t(0.975, K-1) * s * sqrt(1 + 1/K)`` about the
centre, which is what a user who trains one pair can expect. Both on the quantity's scale
(:mod:`plm_highway.metrics.intervals`): errors (MAE, RMS, maximum, Frechet) on the log scale, so never below 0;
reductions through the ratio PLM-Net / BM on the log scale, so never above 100%; differences on the linear scale.
With fewer than 3 pairs there is no interval.

A reduction is ``100 * (1 - PLM-Net / BM)`` of a pair's seed-mean errors. It rises with the BM's error by
construction (the BM's error is its denominator), so the report also fits PLM-Net's error against the BM's
across pairs, and judges the paper's reductions only on pairs whose BM degrades like the paper's BM.

**Verdict per paper number** (two-sided). The comparable pairs are those whose BM's whole-track MAE at that
setting lies within :data:`COMPARABLE_BM_RATIO` of the paper's BM MAE and whose BM stayed on the road in every
seed. ``reproduced``: the paper's reduction lies inside the prediction interval of the comparable pairs' reductions;
``not testable``: fewer than :data:`MIN_COMPARABLE_PAIRS` comparable pairs; otherwise ``ours above`` or ``ours
below`` the paper, with the numbers. A reduction far above the paper's is not a reproduction of it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

from plm_highway.evaluation import paper_results as paper
from plm_highway.evaluation.protocol import paper_key
from plm_highway.metrics.intervals import mean_ci, prediction_interval
from plm_highway.metrics.steering import reduction_pct

CONFIDENCE = 0.95
COMPARABLE_BM_RATIO = (0.67, 1.5)  # the BM's whole-track MAE over the paper's BM MAE, for a comparable pair
MIN_COMPARABLE_PAIRS = 3
PAIR_OUTCOMES = ("steering_mae_paper", "steering_mae_paper_common", "offset_rms_m", "offset_max_m", "frechet_m")


@dataclass(frozen=True)
class Spread:
    """Mean across pairs, its confidence interval and the prediction interval for a new pair (None with n < 3)."""

    mean: float
    ci_low: float | None
    ci_high: float | None
    pi_low: float | None
    pi_high: float | None
    n: int

    def as_dict(self) -> dict:
        return asdict(self)


def spread(values: Iterable[float], confidence: float = CONFIDENCE, scale: str = "linear") -> Spread | None:
    """:class:`Spread` of the finite ``values`` on ``scale`` (``"linear"``, ``"positive"`` or ``"reduction"``; see
    :mod:`plm_highway.metrics.intervals`); None when there are none."""
    data = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if data.size == 0:
        return None
    estimate = mean_ci(data, confidence, scale)
    pi = prediction_interval(data, confidence, scale)
    pi_low, pi_high = (None, None) if pi is None else pi
    return Spread(estimate.mean, estimate.low, estimate.high, pi_low, pi_high, int(data.size))


def scale_of(outcome: str) -> str:
    """The scale a pair outcome's interval is computed on: reductions, or errors that are never negative."""
    return "reduction" if outcome.endswith("reduction_pct") else "positive"


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def pair_summaries(rows: Sequence[dict], settings: Sequence[str]) -> list[dict]:
    """One summary per pair and setting: the seed means of each run's outcomes, the reductions, departures.

    Keys: ``pair``, ``setting``, ``seeds``, ``{bm,plm,ref}_{outcome}`` (seed means), ``{bm,plm}_left_road_seeds``,
    ``mae_reduction_pct`` (whole track), ``mae_common_reduction_pct``, ``offset_rms_reduction_pct``.
    """
    by_key: dict[tuple, list[dict]] = {}
    for row in rows:
        by_key.setdefault((row["pair"], row["role"], row["setting"]), []).append(row)
    summaries = []
    for pair in sorted({row["pair"] for row in rows}):
        reference = by_key.get((pair, "reference", "const:0"), [])
        for setting in settings:
            runs = {"ref": reference, "bm": by_key.get((pair, "baseline", setting), []),
                    "plm": by_key.get((pair, "mitigated", setting), [])}
            if setting == "const:0":
                runs["bm"] = reference  # the BM without latency is the reference
            if not runs["plm"]:
                continue
            summary = {"pair": pair, "setting": setting, "seeds": len(runs["plm"])}
            for who, who_rows in runs.items():
                for outcome in PAIR_OUTCOMES:
                    summary[f"{who}_{outcome}"] = _mean([r[outcome] for r in who_rows])
                summary[f"{who}_left_road_seeds"] = sum(bool(r["left_road"]) for r in who_rows)
            summary["mae_reduction_pct"] = _reduction(summary["bm_steering_mae_paper"],
                                                      summary["plm_steering_mae_paper"])
            summary["mae_common_reduction_pct"] = _reduction(summary["bm_steering_mae_paper_common"],
                                                             summary["plm_steering_mae_paper_common"])
            summary["offset_rms_reduction_pct"] = _reduction(summary["bm_offset_rms_m"], summary["plm_offset_rms_m"])
            summaries.append(summary)
    return summaries


def _reduction(baseline: float, mitigated: float) -> float:
    if not (math.isfinite(baseline) and math.isfinite(mitigated)) or baseline <= 0:
        return math.nan
    return reduction_pct(baseline, mitigated)


def paper_numbers(setting: str) -> dict | None:
    """The paper's BM and PLM-Net steering MAE and its MAE reduction at ``setting`` (None if not reported)."""
    key = paper_key(setting)
    if key is None:
        return None
    baseline, mitigated = paper.steering(key, "baseline"), paper.steering(key, "mitigated")
    target = paper.TARGETS["mae_reduction_pct"].get(key)
    if baseline is None or mitigated is None or target is None:
        return None
    return {"bm_mae": baseline["mae"], "plm_mae": mitigated["mae"], "reduction_pct": target}


def comparable(summary: dict, paper_bm_mae: float) -> bool:
    """Whether a pair's BM degrades like the paper's at this setting (see the module docstring)."""
    ratio = summary["bm_steering_mae_paper"] / paper_bm_mae
    low, high = COMPARABLE_BM_RATIO
    return summary["bm_left_road_seeds"] == 0 and low <= ratio <= high


def verdict(setting: str, summaries: Sequence[dict]) -> dict | None:
    """The two-sided verdict on the paper's MAE reduction at ``setting`` (None where the paper has none)."""
    numbers = paper_numbers(setting)
    if numbers is None:
        return None
    at_setting = [s for s in summaries if s["setting"] == setting]
    matching = [s for s in at_setting if comparable(s, numbers["bm_mae"])]
    reductions = spread((s["mae_reduction_pct"] for s in matching), scale="reduction")
    result = {"setting": setting, "paper": numbers, "pairs": len(at_setting), "comparable_pairs": len(matching),
              "comparable": [s["pair"] for s in matching],
              "reduction": None if reductions is None else reductions.as_dict(),
              "bm_ratio_to_paper": [s["bm_steering_mae_paper"] / numbers["bm_mae"] for s in at_setting]}
    if len(matching) < MIN_COMPARABLE_PAIRS or reductions.pi_low is None:
        result["verdict"] = "not testable"
    elif reductions.pi_low <= numbers["reduction_pct"] <= reductions.pi_high:
        result["verdict"] = "reproduced"
    else:
        result["verdict"] = "ours above" if reductions.pi_low > numbers["reduction_pct"] else "ours below"
    return result


def shares(summaries: Sequence[dict], setting: str) -> dict:
    """For how many pairs PLM-Net lowers the steering MAE and the lateral-offset RMS at ``setting``."""
    at_setting = [s for s in summaries if s["setting"] == setting]
    lower_mae = sum(s["plm_steering_mae_paper"] < s["bm_steering_mae_paper"] for s in at_setting)
    lower_offset = sum(s["plm_offset_rms_m"] < s["bm_offset_rms_m"] for s in at_setting)
    return {"setting": setting, "pairs": len(at_setting), "lower_mae": lower_mae, "lower_offset_rms": lower_offset}


def error_fit(summaries: Sequence[dict], settings: Sequence[str]) -> dict | None:
    """PLM-Net's whole-track MAE against the BM's, least squares across pairs and latency settings.

    Returns slope, intercept, their standard errors, r and the number of points (None with fewer than 3).
    A slope well under 1 is mitigation that helps more the worse the BM gets.
    """
    points = [(s["bm_steering_mae_paper"], s["plm_steering_mae_paper"]) for s in summaries
              if s["setting"] in settings and math.isfinite(s["bm_steering_mae_paper"])
              and math.isfinite(s["plm_steering_mae_paper"])]
    if len(points) < 3:
        return None
    x, y = np.array(points).T
    fit = stats.linregress(x, y)
    return {"slope": float(fit.slope), "slope_se": float(fit.stderr), "intercept": float(fit.intercept),
            "intercept_se": float(fit.intercept_stderr), "r": float(fit.rvalue), "points": len(points)}


def variance_split(rows: Sequence[dict], summaries: Sequence[dict], setting: str, role: str, outcome: str) -> dict:
    """How much of an outcome's spread is between pairs (training runs) and how much within (simulator seeds)."""
    who = {"baseline": "bm", "mitigated": "plm", "reference": "ref"}[role]
    pair_means = [s[f"{who}_{outcome}"] for s in summaries if s["setting"] == setting]
    within = []
    for pair in sorted({s["pair"] for s in summaries}):
        values = [r[outcome] for r in rows if r["pair"] == pair and r["setting"] == setting and r["role"] == role
                  and r[outcome] is not None and math.isfinite(r[outcome])]
        if len(values) > 1:
            within.append(float(np.std(values, ddof=1)))
    return {"between_pairs_sd": float(np.std(pair_means, ddof=1)) if len(pair_means) > 1 else math.nan,
            "within_pair_sd": float(np.mean(within)) if within else math.nan}


def remedy_comparison(rows: Sequence[dict], remedy: str, settings: Sequence[str], own: Sequence[dict]) -> dict:
    """The remedy's PLM-Net against each pair's own, paired by pair, per setting, and whether to ship it.

    Shipped only when it lowers the lateral-offset RMS (the 95% CI of the paired difference below 0) at most latency
    settings and raises the steering MAE (CI above 0) at none.
    """
    remedy_rows = [r for r in rows if r.get("remedy") == remedy and r["role"] == "mitigated"]
    base_rows = [r for r in rows if not r.get("remedy") and r["role"] != "mitigated"]
    theirs = {(s["pair"], s["setting"]): s for s in pair_summaries([*base_rows, *remedy_rows], settings)}
    ours = {(s["pair"], s["setting"]): s for s in own}
    out: dict = {"settings": {}}
    lowers_offset = raises_mae = 0
    latency_settings = [s for s in settings if s != "const:0"]
    for setting in settings:
        pairs = sorted(p for (p, s) in theirs if s == setting and (p, s) in ours)
        mae = [theirs[(p, setting)]["plm_steering_mae_paper"] - ours[(p, setting)]["plm_steering_mae_paper"]
               for p in pairs]
        offset = [theirs[(p, setting)]["plm_offset_rms_m"] - ours[(p, setting)]["plm_offset_rms_m"] for p in pairs]
        mae_spread, offset_spread = spread(mae), spread(offset)
        out["settings"][setting] = {
            "pairs": len(pairs),
            "own_mae": _mean([ours[(p, setting)]["plm_steering_mae_paper"] for p in pairs]),
            "remedy_mae": _mean([theirs[(p, setting)]["plm_steering_mae_paper"] for p in pairs]),
            "own_offset_rms_m": _mean([ours[(p, setting)]["plm_offset_rms_m"] for p in pairs]),
            "remedy_offset_rms_m": _mean([theirs[(p, setting)]["plm_offset_rms_m"] for p in pairs]),
            "own_left_road": sum(ours[(p, setting)]["plm_left_road_seeds"] for p in pairs),
            "remedy_left_road": sum(theirs[(p, setting)]["plm_left_road_seeds"] for p in pairs),
            "mae_difference": None if mae_spread is None else mae_spread.as_dict(),
            "offset_rms_difference_m": None if offset_spread is None else offset_spread.as_dict(),
        }
        if setting in latency_settings:
            lowers_offset += bool(offset_spread and offset_spread.ci_high is not None and offset_spread.ci_high < 0)
            raises_mae += bool(mae_spread and mae_spread.ci_low is not None and mae_spread.ci_low > 0)
    ship = lowers_offset > len(latency_settings) / 2 and raises_mae == 0
    out["decision"] = "shipped" if ship else "not shipped"
    out["decision_rule"] = (f"offset RMS lower (CI below 0) at {lowers_offset} of {len(latency_settings)} latency "
                            f"settings, steering MAE higher (CI above 0) at {raises_mae}; shipped only when lower at "
                            "most and higher at none")
    return out
