"""Why a car whose steering follows the reference's trace can still drift across its lane.

Two measurements per pair:

- **Where the offset's energy lies.** The lateral offset of each run is split at :data:`DRIFT_CUTOFF_HZ` by a
  zero-phase low-pass filter: the slow part (periods longer than 4 s: drift, swings that take many seconds) and
  the fast part (the weave a late camera causes, with periods of about four latencies, 0.6-1.2 s at 0.15-0.30 s).
  The steering MAE is dominated by the fast part (a weave is steering that changes sign every half period); the
  offset integrates steering twice, so a small, slow steering error that the MAE barely sees moves the car far.
- **How hard each policy answers the lane.** The car is posed at the middle of the track's longest straight at a
  lateral offset (heading along the road) or a heading error (on the lane centre), nothing moving, and each policy
  steers from that one camera frame: the BM without latency, and PLM-Net told each latency. The least-squares
  slopes are its feedback gains on offset [1/m] and heading error [1/rad] (normalised steering). PLM-Net told a
  latency predicts what the BM will do that much later; if it answers the lane more weakly than the BM does, the
  loop holds the lane more loosely: the offset wanders slowly while the steering trace stays close to the BM's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import signal

from plm_highway.evaluation.protocol import constant_latency_s
from plm_highway.evaluation.response import demonstrator_law
from plm_highway.expert.controller import expert_steering
from plm_highway.mitigation.posing import POSE_HEADINGS_RAD, POSE_OFFSETS_M, gains_from_answers, posed_frames
from plm_highway.models.checkpoints import load_base_model, load_plm_net
from plm_highway.models.inference import BaseModelPolicy, PLMNetPolicy
from plm_highway.rollout.conditions import CONDITIONS
from plm_highway.rollout.policies import checkpoint_pair

DRIFT_CUTOFF_HZ = 0.25  # periods above 4 s count as drift (the latency weave is 0.6-1.2 s)
FILTER_ORDER = 2


def offset_bands(t_s: np.ndarray, offset_m: np.ndarray, cutoff_hz: float = DRIFT_CUTOFF_HZ) -> dict:
    """RMS [m] of the slow (below ``cutoff_hz``) and fast parts of a lateral offset, and of the whole; NaN for runs
    too short to filter (fewer than about three filter lengths)."""
    t_s, offset_m = np.asarray(t_s, dtype=float), np.asarray(offset_m, dtype=float)
    total = float(np.sqrt(np.mean(offset_m ** 2))) if len(offset_m) else math.nan
    if len(t_s) < 2:
        return {"slow_rms_m": math.nan, "fast_rms_m": math.nan, "rms_m": total}
    rate_hz = 1.0 / float(np.median(np.diff(t_s)))
    sos = signal.butter(FILTER_ORDER, cutoff_hz, btype="low", fs=rate_hz, output="sos")
    padding = 3 * (2 * len(sos) + 1)  # sosfiltfilt's default padding needs this many samples
    if len(offset_m) <= padding:
        return {"slow_rms_m": math.nan, "fast_rms_m": math.nan, "rms_m": total}
    slow = signal.sosfiltfilt(sos, offset_m)
    fast = offset_m - slow
    return {"slow_rms_m": float(np.sqrt(np.mean(slow ** 2))), "fast_rms_m": float(np.sqrt(np.mean(fast ** 2))),
            "rms_m": total}


def posed_gains(checkpoints, conditions_name: str, track: str, latencies_s: Sequence[float],
                offsets_m: Sequence[float] = POSE_OFFSETS_M, headings_rad: Sequence[float] = POSE_HEADINGS_RAD
                ) -> dict:
    """Feedback gains of the BM (no latency), of PLM-Net told each of ``latencies_s`` and of the demonstrator's law,
    from posed camera frames (see the module docstring): ``{"bm": {...}, "plm@0.25": {...}, "law": {...}}`` with
    ``offset_gain_per_m`` and ``heading_gain_per_rad``."""
    conditions = CONDITIONS[conditions_name]
    bm_path, tapm_path = checkpoint_pair(checkpoints, conditions.checkpoint_preset)
    bm = BaseModelPolicy(load_base_model(bm_path), batch_invariant=True)
    plm = PLMNetPolicy(load_plm_net(bm_path, tapm_path), batch_invariant=True)
    law = demonstrator_law(conditions)
    answers: dict[str, dict[str, list[float]]] = {}
    for sweep, frame, info in posed_frames(conditions.env_config(), track, conditions.camera, offsets_m, headings_rad):
        steer = {"bm": bm(frame, info["speed_mps"], 0.0), "law": float(expert_steering(info, law))}
        for latency_s in latencies_s:
            steer[f"plm@{latency_s:g}"] = plm(frame, info["speed_mps"], latency_s)
        for who, value in steer.items():
            answers.setdefault(who, {}).setdefault(sweep, []).append(float(value))
    return {who: gains_from_answers(sweeps, offsets_m, headings_rad) for who, sweeps in answers.items()}


def run_bands(traces: dict[str, dict[str, np.ndarray]]) -> dict[str, dict]:
    """:func:`offset_bands` of every run of one pair and seed (``{run label: bands}``), over the steps it drove."""
    return {label: offset_bands(columns["t_s"], columns["lateral_offset_m"]) for label, columns in traces.items()}


def drift_summary(bands: dict[tuple[int, str], list[dict]], feedback: dict[int, dict],
                  latency_settings: Sequence[str]) -> dict:
    """Per latency setting, over pairs: the slow and fast offset RMS of the reference, the BM and PLM-Net (pair means
    of seed values), PLM-Net's posed gains over the BM's, and how well the gain lost explains the slow drift.

    ``bands``: ``{(pair, run label): [bands per seed]}``; ``feedback``: ``{pair: posed gains}``.
    """
    def pair_mean(pair: int, label: str, key: str) -> float:
        values = [b[key] for b in bands.get((pair, label), []) if math.isfinite(b[key])]
        return float(np.mean(values)) if values else math.nan

    pairs = sorted({pair for pair, _ in bands})
    out: dict = {"cutoff_hz": DRIFT_CUTOFF_HZ, "settings": {}}
    log_points = []
    for setting in latency_settings:
        entry: dict = {}
        for who, label in (("ref", "reference"), ("bm", f"baseline@{setting}"), ("plm", f"mitigated@{setting}")):
            for key in ("slow_rms_m", "fast_rms_m"):
                values = [pair_mean(p, label, key) for p in pairs]
                finite = [v for v in values if math.isfinite(v)]
                entry[f"{who}_{key}"] = float(np.mean(finite)) if finite else math.nan
        latency_s = constant_latency_s(setting)
        if latency_s:
            name = f"plm@{latency_s:g}"
            ratios = {key: [feedback[p][name][key] / feedback[p]["bm"][key] for p in pairs
                            if p in feedback and name in feedback[p] and feedback[p]["bm"][key] != 0]
                      for key in ("offset_gain_per_m", "heading_gain_per_rad")}
            for key, values in ratios.items():
                entry[f"plm_over_bm_{key}"] = float(np.mean(values)) if values else math.nan
                entry[f"plm_over_bm_{key}_range"] = [float(min(values)), float(max(values))] if values else None
            for p in pairs:
                if p not in feedback or name not in feedback[p]:
                    continue
                gain_ratio = feedback[p][name]["offset_gain_per_m"] / feedback[p]["bm"]["offset_gain_per_m"]
                slow_ratio = pair_mean(p, f"mitigated@{setting}", "slow_rms_m") / pair_mean(p, "reference",
                                                                                          "slow_rms_m")
                if gain_ratio > 0 and math.isfinite(slow_ratio) and slow_ratio > 0:
                    log_points.append((math.log(1.0 / gain_ratio), math.log(slow_ratio)))
        out["settings"][setting] = entry
    if len(log_points) >= 3:
        x, y = np.array(log_points).T
        fit = np.polyfit(x, y, 1)
        out["gain_explains_drift"] = {"points": len(log_points), "slope": float(fit[0]), "intercept": float(fit[1]),
                                      "r": float(np.corrcoef(x, y)[0, 1])}
    return out
