"""Diagnose a recording against the simulator: where it departs, which physics is missing, how much
the fitted term explains, and what is left.

The steps, top to bottom (:func:`diagnose`):

0. Check the recording against itself (:mod:`plm_highway.sim2real.record.consistency`); a recording that
   contradicts itself is ``inconsistent`` and nothing is fitted.
1. Check there is enough to judge: the scored samples (moving faster than the recording's speed
   floor, outside gaps and glitches) and the steering's excitation. Too little is an error with
   the numbers; little is a verdict marked low-confidence.
2. Replay the recorded steering and speed through the simulator's model and take residuals on
   every recorded channel (yaw rate, heading rate, lateral velocity from positions).
3. Fit every candidate effect and pair inside the model; pick one on held-out data with a
   complexity penalty (:mod:`plm_highway.sim2real.fit.selection`).
4. Estimate the measurement noise from the best fit's residual (third differences).
5. Locate the mismatch in time and by operating condition (bands from the recording's own
   speed and lateral-acceleration distribution).
6. Analyse what is left (residual whiteness, correlation with speed, lateral acceleration,
   steering rate, steering sign and time) and settle the verdict:

   ================== ===========================================================================
   verdict            meaning
   ================== ===========================================================================
   match              no candidate helps and the plain model's residual is white noise
   mismatch           an effect (or pair) explains the departure down to the noise
   partly explained   an effect helps, but under 80% of the error above the noise is explained, or
                      a structured leftover (not white, +20% noise variance) holds over 2% of it,
                      or the fit makes the re-anchored position over 10% worse (a yaw-plane term
                      standing in for bank, grade or a sensor)
   unexplained        the simulator departs, and nothing in the library helps
   unexcited          the car barely turns: the recording cannot show steering-path physics
   inconclusive       nothing helps, but too little data (or no measured noise) to call it a match
   discovered         the library's best chain leaves structure and residual discovery names a
                      plausible term outside the library that improves held-out data
                      (:mod:`plm_highway.sim2real.residual.discovery`)
   inconsistent       the recording contradicts itself (speed against positions, yaw rate against
                      heading, steering against the turns, time scale against both): no physics is
                      fitted; the channel and the likely cause (units, sign, scale) are named
   ================== ===========================================================================
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy import stats
from scipy.interpolate import CubicSpline
from scipy.ndimage import correlate1d

from plm_highway.sim2real.diagnosis import (
    EXCITATION_NOISE_FACTOR,
    PARTLY_EXPLAINED_BELOW,
    STRUCTURE_MATTERS_BELOW,
    Diagnosis,
)
from plm_highway.sim2real.fit.folds import MIN_BLOCKS, check_block_s, default_block_s
from plm_highway.sim2real.fit.plausibility import library_doubts
from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem, make_problem
from plm_highway.sim2real.fit.selection import Selection, fit_candidates, select
from plm_highway.sim2real.physics.effects import EffectParams
from plm_highway.sim2real.physics.replay import (
    ANCHOR_S,
    MIN_NOISE_SAMPLES,
    FitSignal,
    PoseReplay,
    channel_prediction,
    model_outputs,
    noise_estimate,
    replay_pose,
    yaw_rate_lag_behind_heading,
)
from plm_highway.sim2real.record.consistency import check_consistency
from plm_highway.sim2real.record.recording import Recording
from plm_highway.sim2real.rendering import discovery_text, scored_text, summary_text
from plm_highway.sim2real.residual.discovery import discover, should_run

DISCOVERY_MODES = ("auto", "always", "never")

WINDOW_RMS_S = 1.0
WINDOW_NOISE_FACTOR = 2.0
WINDOW_MIN_S = 0.5
WINDOW_MERGE_S = 1.0
# Window lengths never shorter than this many samples (low sample rates).
WINDOW_MIN_SAMPLES = 5

STEER_FREQ_BANDS_HZ = (0.0, 0.1, 0.3, 0.6, math.inf)
CONDITION_QUANTILES = (0.0, 0.2, 0.4, 0.6, 0.8)
CHANNEL_LAG_MIN_S = 0.06

# Data needed for a verdict with normal confidence (the kit's policy): 30 s scored and half of
# the recording; below MIN_SCORED_S (or fewer than MIN_BLOCKS blocks with data) nothing is judged.
CONFIDENT_SCORED_S = 30.0
CONFIDENT_SCORED_FRACTION = 0.5
MIN_SCORED_S = 5.0
# A held-out error below this fraction of the signal's RMS is the simulator's own replay written
# with finitely many digits (a 6-digit log leaves ~2e-5): rounding, not physics.
REPRODUCED_RELATIVE = 1e-4
# A named effect that makes the re-anchored position error this much worse is not taken as physics.
POSITION_WORSE = 0.10
# What is left after a fit (with diagnosis.PARTLY_EXPLAINED_BELOW): excess variance over the noise, whiteness
# level, and the smallest correlation worth naming.
STRUCTURE_EXCESS = 0.2
WHITENESS_ALPHA = 0.01
MIN_CORRELATION = 0.1
WHITENESS_LAGS = 20


# ----------------------------------------------------------------------------------------------
# Moving statistics


def moving_mean(values: np.ndarray, size: int) -> np.ndarray:
    """Centred moving mean by direct summation (edges reflected, as scipy's uniform filter).

    A running-sum filter subtracts what it added and can return slightly negative means of
    non-negative data (whose square root is then NaN); a direct sum of non-negative terms cannot.
    """
    size = max(1, int(size))
    return correlate1d(np.asarray(values, float), np.full(size, 1.0 / size), mode="reflect")


def _window_samples(seconds: float, dt: float) -> int:
    return max(WINDOW_MIN_SAMPLES, round(seconds / dt))


# ----------------------------------------------------------------------------------------------
# Locating


def mismatch_windows(t_s: np.ndarray, residual: np.ndarray, usable: np.ndarray, noise_sigma: float,
                     rms_s: float = WINDOW_RMS_S, factor: float = WINDOW_NOISE_FACTOR,
                     min_s: float = WINDOW_MIN_S, merge_s: float = WINDOW_MERGE_S) -> list[list[float]]:
    """Stretches where the ``rms_s`` running RMS of the residual exceeds ``factor`` x the noise
    (windows at least ``WINDOW_MIN_SAMPLES`` samples long; merge and minimum lengths likewise)."""
    dt = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    size = _window_samples(rms_s, dt)
    min_s = max(min_s, WINDOW_MIN_SAMPLES * dt)
    merge_s = max(merge_s, WINDOW_MIN_SAMPLES * dt)
    mean_sq = moving_mean(np.where(usable, residual, 0.0) ** 2, size) / np.maximum(
        moving_mean(usable.astype(float), size), 1e-12)
    above = (np.sqrt(mean_sq) > factor * noise_sigma) & usable
    edges = np.diff(np.concatenate([[0], above.astype(int), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    windows: list[list[float]] = []
    for s, e in zip(starts, stops):
        t0, t1 = float(t_s[s]), float(t_s[e])
        if windows and t0 - windows[-1][1] <= merge_s:
            windows[-1][1] = t1
        else:
            windows.append([t0, t1])
    return [[round(a, 3), round(b, 3)] for a, b in windows if b - a >= min_s]


def steering_frequency_hz(t_s: np.ndarray, steer_rad: np.ndarray, window_s: float = 3.0,
                          smooth_s: float = 0.3, steady_rad: float = 0.002) -> np.ndarray:
    """Local dominant steering frequency: rms(steer rate) / (2 pi rms(steer - local mean)).

    Exact for a sinusoid. The steering is first smoothed over ``smooth_s`` so that sensor jitter
    does not read as fast steering, and stretches whose steering varies by less than
    ``steady_rad`` (held turns, straights) read as 0 Hz.
    """
    dt = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    steer = moving_mean(steer_rad, max(1, round(smooth_s / dt)))
    size = max(3, round(window_s / dt))
    mean = moving_mean(steer, size)
    spread = np.sqrt(moving_mean((steer - mean) ** 2, size))
    rate_rms = np.sqrt(moving_mean(np.gradient(steer, dt) ** 2, size))
    freq = rate_rms / (2 * math.pi * np.maximum(spread, 1e-12))
    return np.where(spread < steady_rad, 0.0, freq)


def _nice(value: float) -> float:
    """Round to two significant digits (band edges people can read)."""
    if value <= 0:
        return 0.0
    digits = 1 - int(math.floor(math.log10(value)))
    return round(value, digits)


def quantile_bands(values: np.ndarray, usable: np.ndarray) -> tuple[float, ...]:
    """Band edges at the recording's own quintiles (rounded), from 0 to infinity."""
    v = values[usable]
    if v.size == 0:
        return (0.0, math.inf)
    edges = sorted({_nice(float(np.quantile(v, q))) for q in CONDITION_QUANTILES[1:]} - {0.0})
    return (0.0, *edges, math.inf)


def _band_rows(values: np.ndarray, bands: tuple[float, ...], before: np.ndarray, after: np.ndarray,
               usable: np.ndarray) -> list[dict]:
    rows = []
    total = max(int(usable.sum()), 1)
    for lo, hi in itertools.pairwise(bands):
        sel = usable & (values >= lo) & (values < hi)
        n = int(sel.sum())
        if n < 10:
            continue
        rows.append({"range": [lo, None if math.isinf(hi) else hi], "fraction": round(n / total, 4),
                     "rmse_before": float(np.sqrt(np.mean(before[sel] ** 2))),
                     "rmse_after": float(np.sqrt(np.mean(after[sel] ** 2))), "n": n})
    return rows


def lateral_acceleration(recording: Recording, signal: FitSignal) -> np.ndarray:
    if recording.lat_accel_mps2 is not None:
        return recording.lat_accel_mps2
    return recording.speed_mps * signal.values


def straight_threshold_mps2(lat: np.ndarray, usable: np.ndarray) -> float:
    """|lateral acceleration| below which the car counts as going straight: 0.5 m/s^2, or 15% of the
    recording's 95th percentile when it never corners harder than ~3 m/s^2 (a small or slow car)."""
    p95 = float(np.percentile(np.abs(lat[usable]), 95)) if usable.any() else 0.0
    return min(0.5, 0.15 * p95) if p95 > 0 else 0.5


def operating_conditions(recording: Recording, signal: FitSignal, res_before: np.ndarray, res_after: np.ndarray
                         ) -> dict:
    """Residual RMS before and after, per speed band, |lateral acceleration|, steering frequency, side."""
    usable = signal.usable
    lat = lateral_acceleration(recording, signal)
    freq = steering_frequency_hz(recording.t_s, recording.steer_rad)
    straight = straight_threshold_mps2(lat, usable)
    direction = []
    total = max(int(usable.sum()), 1)
    for label, sel in (("left", lat > straight), ("right", lat < -straight), ("straight", np.abs(lat) <= straight)):
        sel = sel & usable
        n = int(sel.sum())
        if n < 10:
            continue
        direction.append({"side": label, "fraction": round(n / total, 4),
                          "rmse_before": float(np.sqrt(np.mean(res_before[sel] ** 2))),
                          "rmse_after": float(np.sqrt(np.mean(res_after[sel] ** 2))), "n": n})
    return {
        "speed_mps": _band_rows(recording.speed_mps, quantile_bands(recording.speed_mps, usable), res_before,
                                res_after, usable),
        "abs_lat_accel_mps2": _band_rows(np.abs(lat), quantile_bands(np.abs(lat), usable), res_before, res_after,
                                         usable),
        "steer_freq_hz": _band_rows(freq, STEER_FREQ_BANDS_HZ, res_before, res_after, usable),
        "direction": direction,
        "lat_accel_source": "recorded" if recording.lat_accel_mps2 is not None else "speed x yaw rate",
        "straight_below_mps2": straight,
    }


# ----------------------------------------------------------------------------------------------
# What is left: residual analysis (as system identification's `resid`)


def _autocorrelation(e: np.ndarray, valid: np.ndarray, lag: int) -> float:
    pairs = valid[lag:] & valid[:-lag]
    if pairs.sum() < 10:
        return 0.0
    a, b = e[lag:][pairs], e[:-lag][pairs]
    denom = math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b)))
    return float(np.dot(a, b) / denom) if denom > 0 else 0.0


def whiteness(e: np.ndarray, valid: np.ndarray, lags: int = WHITENESS_LAGS) -> dict:
    """Ljung-Box test of the residual over ``lags`` lags (only pairs of valid samples count)."""
    n = int(valid.sum())
    e = np.where(valid, e - (e[valid].mean() if n else 0.0), 0.0)
    rho = np.array([_autocorrelation(e, valid, k) for k in range(1, lags + 1)])
    if n <= lags + 2:
        return {"lags": lags, "q": math.nan, "p_value": math.nan, "lag1": 0.0, "white": True, "n": n}
    q = float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, lags + 1))))
    p = float(stats.chi2.sf(q, lags))
    return {"lags": lags, "q": q, "p_value": p, "lag1": float(rho[0]), "white": p >= WHITENESS_ALPHA, "n": n}


def _correlation(e: np.ndarray, x: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """(correlation, its 99% significance level with the Bartlett effective sample size)."""
    a, b = e[valid], x[valid]
    if a.size < 10 or np.std(a) == 0 or np.std(b) == 0:
        return 0.0, math.inf
    rho = float(np.corrcoef(a, b)[0, 1])
    ra = _autocorrelation(e - a.mean(), valid, 1)
    rb = _autocorrelation(x - b.mean(), valid, 1)
    n_eff = a.size * max(1 - ra * rb, 1e-3) / (1 + ra * rb)
    return rho, 2.576 / math.sqrt(max(n_eff, 1.0))


def on_recorded_samples(recording: Recording, signal: FitSignal, prediction: np.ndarray, valid: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(times, recorded - predicted, valid, nearest grid index): on the rows as recorded when the
    gyro was resampled (interpolation averages and colours its noise), else on the grid."""
    raw = recording.raw
    if signal.name != "yaw_rate" or raw is None or "yaw_rate" not in raw:
        return recording.t_s, signal.values - prediction, valid & np.isfinite(prediction), np.arange(recording.n)
    t = raw["t"]
    index = np.clip(np.round((t - recording.t_s[0]) / recording.dt_s).astype(int), 0, recording.n - 1)
    ok = valid & np.isfinite(prediction)
    spline = CubicSpline(recording.t_s, np.where(ok, prediction, 0.0))
    # A raw row counts when both grid samples around it are valid (the spline is exact there).
    lower = np.clip(np.floor((t - recording.t_s[0]) / recording.dt_s).astype(int), 0, recording.n - 2)
    return t, raw["yaw_rate"] - spline(t), ok[lower] & ok[lower + 1], index


def residual_analysis(recording: Recording, signal: FitSignal, prediction: np.ndarray, valid: np.ndarray,
                      noise_sigma: float, plain_yaw_rate: np.ndarray, shape: np.ndarray | None = None) -> dict:
    """Is what is left (recorded - ``prediction``) white noise, and if not, what does it correlate
    with: speed in the turn's direction, the steering's lateral acceleration u r, steering rate and
    sign, time, and (its size) the steering rate?

    Measured on the rows as recorded when they were resampled; filtered channels are decimated by
    their filter length first (their noise is not white). ``shape``: a winner's error-variance
    shape (delay jitter): the residual is standardised by it.
    """
    t, e, valid, index = on_recorded_samples(recording, signal, prediction, valid)
    if shape is not None:
        e = e / np.sqrt(shape[index])
    stride = max(1, len(signal.taps)) if len(signal.taps) > 1 else 1
    take = np.zeros(len(t), bool)
    take[::stride] = True
    valid = valid & take & np.isfinite(e)
    e = np.where(valid, e, 0.0)
    white = whiteness(e[::stride], valid[::stride])
    rms = float(np.sqrt(np.mean(e[valid] ** 2))) if valid.any() else math.nan
    excess = rms**2 / noise_sigma**2 - 1.0 if noise_sigma > 0 and math.isfinite(rms) else math.inf
    steer_rate = np.gradient(recording.steer_rad, recording.dt_s)
    # Regressors from the inputs only (steering and speed, as system identification's residual
    # analysis): a measured lateral acceleration carries the same disturbances as the residual.
    regressors = {
        "speed": recording.speed_mps * np.sign(plain_yaw_rate),  # an error growing with speed in the turn
        "lateral acceleration": recording.speed_mps * plain_yaw_rate,
        "steering rate": steer_rate,
        "steering sign": np.sign(recording.steer_rad),
        "time": recording.t_s - recording.t_s.mean(),
        "steering rate (scatter)": np.abs(steer_rate),  # against |residual|: variance growing with it
    }
    correlations = []
    for name, x in regressors.items():
        target = np.abs(e) if "scatter" in name else e
        rho, level = _correlation(target[::stride], x[index][::stride], valid[::stride])
        if math.isfinite(level):
            correlations.append({"with": name, "rho": rho, "significance": level,
                                 "significant": abs(rho) > level and abs(rho) >= MIN_CORRELATION})
    correlations.sort(key=lambda c: -abs(c["rho"]))
    named = [c for c in correlations if c["significant"]]
    # Structure that matters: the residual exceeds the noise by STRUCTURE_EXCESS of its variance, and
    # is not white or correlates with a regressor (statistical significance alone flags tiny
    # structure in a long recording).
    structured = excess > STRUCTURE_EXCESS and (not white["white"] or bool(named))
    return {"rmse": rms, "noise_sigma": noise_sigma, "excess_variance_ratio": excess, "whiteness": white,
            "correlations": correlations, "correlates_with": [c["with"] for c in named], "structured": structured,
            "on_recorded_rows": recording.raw is not None and signal.name == "yaw_rate"}


# ----------------------------------------------------------------------------------------------
# Words


def _rmse(values: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values[mask] ** 2))) if mask.any() else math.nan


def _chosen_outputs(problem: FitProblem, fit: CandidateFit, anchor_s: float) -> tuple[list[np.ndarray], PoseReplay]:
    """The chosen model's channels and re-anchored pose: held-out samples from the fold model that
    did not see them, all other samples from the model refitted on everything."""
    rec = problem.recording
    out = model_outputs(rec, fit.params)
    channels = [channel_prediction(c, rec, fit.params, out) for c in problem.channels]
    pose = replay_pose(rec, out[0], out[2], anchor_s)
    heading_err, position_err = pose.heading_error_rad.copy(), pose.position_error_m.copy()
    x, y, h = pose.x_m.copy(), pose.y_m.copy(), pose.heading_rad.copy()
    for f, params in enumerate(fit.fold_params):
        _, test = problem.time_folds[f]
        fold_out = model_outputs(rec, params)
        pose_fold = replay_pose(rec, fold_out[0], fold_out[2], anchor_s)
        for i in range(len(problem.channels)):
            held = problem.channel_folds[i][f][1]
            channels[i][held] = fit.oof[i][held]
        heading_err[test] = pose_fold.heading_error_rad[test]
        position_err[test] = pose_fold.position_error_m[test]
        x[test], y[test], h[test] = pose_fold.x_m[test], pose_fold.y_m[test], pose_fold.heading_rad[test]
    return channels, PoseReplay(x, y, h, heading_err, position_err)


def channel_notes(recording: Recording, signal: FitSignal) -> tuple[dict, list[str]]:
    """Consistency of the recording's own channels: does the yaw rate agree with the heading?"""
    checks: dict = {}
    notes: list[str] = []
    lag = yaw_rate_lag_behind_heading(recording)
    if lag is not None:
        checks["yaw_rate_lag_behind_heading"] = lag
        if abs(lag["lag_s"]) >= max(2 * recording.dt_s, CHANNEL_LAG_MIN_S) and \
                lag["rmse_at_lag"] < 0.9 * lag["rmse_at_zero"]:
            late = "late" if lag["lag_s"] > 0 else "early"
            notes.append(f"the recorded yaw_rate runs {abs(lag['lag_s']):.2f} s {late} against the derivative of "
                         "the recorded heading: one of the two channels is filtered or delayed (the sensor_delay "
                         "candidate tests the gyro; compare with --signal heading and --signal yaw_rate)")
    return checks, notes


def scored_data(recording: Recording, signal: FitSignal) -> dict:
    """How much of the recording is scored, what was dropped and why, and how confident a verdict can be."""
    n = recording.n
    dt = recording.dt_s
    gap = ~recording.usable if recording.usable is not None else np.zeros(n, bool)
    slow = recording.speed_mps <= recording.speed_floor_mps
    scored = signal.usable
    dropped = {
        "below_speed_floor": int((slow & ~gap).sum()),
        "gaps_and_glitches": int(gap.sum()),
        "settling_and_filter_edges": int((~scored & ~slow & ~gap).sum()),
    }
    scored_s = float(scored.sum()) * dt
    data = {"samples": n, "scored_samples": int(scored.sum()), "scored_s": scored_s,
            "duration_s": recording.duration_s, "scored_fraction": float(scored.mean()),
            "speed_floor_mps": recording.speed_floor_mps, "dropped": dropped, "low_confidence_reasons": []}
    if scored_s < CONFIDENT_SCORED_S:
        data["low_confidence_reasons"].append(f"under {CONFIDENT_SCORED_S:g} s scored")
    if data["scored_fraction"] < CONFIDENT_SCORED_FRACTION:
        data["low_confidence_reasons"].append(f"under {100 * CONFIDENT_SCORED_FRACTION:.0f}% of the recording scored")
    return data


def dropped_notes(data: dict, recording: Recording) -> list[str]:
    notes = []
    n = data["samples"]
    d = data["dropped"]
    if d["below_speed_floor"]:
        notes.append(f"{d['below_speed_floor']} of {n} samples ({100 * d['below_speed_floor'] / n:.0f}%) are not "
                     f"scored: slower than the speed floor {data['speed_floor_mps']:.3g} m/s (min of "
                     f"0.4 wheelbases/s and a quarter of the median moving speed)")
    if d["gaps_and_glitches"]:
        notes.append(f"{d['gaps_and_glitches']} of {n} samples ({100 * d['gaps_and_glitches'] / n:.0f}%) are not "
                     "scored: inside sampling gaps or around heading glitches")
    return notes


def _check_enough(data: dict, recording: Recording, problem_blocks: int) -> None:
    if data["scored_s"] < MIN_SCORED_S or problem_blocks < MIN_BLOCKS:
        raise ValueError(
            f"{recording.name}: too little usable data for any verdict: {scored_text(data)} "
            f"(need at least {MIN_SCORED_S:g} s in {MIN_BLOCKS} cross-validation blocks); "
            f"{data['dropped']['below_speed_floor']} samples are slower than the speed floor "
            f"{data['speed_floor_mps']:.3g} m/s (the car's top speed is {float(np.max(recording.speed_mps)):.3g} m/s)")


def diagnose(recording: Recording, *, block_s: float | None = None, anchor_s: float = ANCHOR_S,
             split: str = "blocks", signal_name: str = "auto",
             candidates: list[tuple[str, ...]] | None = None,
             rng: np.random.Generator | None = None, discovery: str = "auto") -> Diagnosis:
    """Run the whole diagnosis on a recording (see the module docstring). ``rng`` drives the
    bootstraps (default: a fixed seed, so a diagnosis is reproducible). ``discovery``: ``auto`` runs
    residual discovery when the library leaves structure (``partly explained``, ``unexplained``),
    ``always`` after any fit, ``never`` not at all."""
    if discovery not in DISCOVERY_MODES:
        raise ValueError(f"unknown discovery mode {discovery!r}; known: {', '.join(DISCOVERY_MODES)}")
    rng = np.random.default_rng(0) if rng is None else rng
    if not recording.is_uniform:
        raise ValueError(f"{recording.name}: not uniformly sampled; read it with read_recording or "
                         "recording_from_arrays, which resample it")
    if not (math.isfinite(anchor_s) and 2 * recording.dt_s <= anchor_s <= recording.duration_s):
        raise ValueError(f"--anchor-s must be between two samples ({2 * recording.dt_s:.3g} s) and the recording's "
                         f"duration ({recording.duration_s:.1f} s), got {anchor_s!r}")
    if block_s is None:
        block_s = default_block_s(recording.duration_s, recording.dt_s)
    else:
        check_block_s(block_s, recording.duration_s)
    # 0. The recording against itself: units, signs and time scale that contradict are not physics.
    consistency = check_consistency(recording)
    if not consistency.consistent:
        return Diagnosis(recording, None, math.nan, None, block_s, anchor_s, None, None, None, None, None, None, [],
                         {}, {}, consistency.summary(recording.name), verdict="inconsistent",
                         consistency=consistency)
    problem = make_problem(recording, signal_name, block_s, split)
    signal = problem.signal
    data = scored_data(recording, signal)
    data["unchecked_consistency"] = [f"{c.name.replace('_', ' ')} ({c.text})" for c in consistency.unchecked_turns]
    block = np.floor((recording.t_s - recording.t_s[0]) / block_s).astype(int)
    _check_enough(data, recording, len(np.unique(block[signal.usable])))
    checks, notes = channel_notes(recording, signal)
    notes = dropped_notes(data, recording) + notes
    # 1. Plain replay.
    r_plain, vy_plain, slip_plain = model_outputs(recording, EffectParams())
    before = problem.plain_predictions[0]
    res_before = signal.values - before
    pose_before = replay_pose(recording, r_plain, slip_plain, anchor_s)
    # 2. Candidates.
    fits = fit_candidates(problem, candidates)
    ranking = sorted(fits, key=lambda f: f.score)
    # 3. Noise from the best candidate's out-of-fold residual (smooth model error cancels in third
    # differences, but less of it is left to cancel than in the plain model's residual).
    noise, noise_count, noise_measured = _noise(problem, ranking[0], res_before)
    selection = select(problem, fits, noise, rng)
    after_channels, pose_after = _chosen_outputs(problem, selection.winner, anchor_s)
    after = after_channels[0]
    best = after if selection.best is selection.winner else _chosen_outputs(problem, selection.best, anchor_s)[0][0]
    res_after = signal.values - after
    windows = mismatch_windows(recording.t_s, res_before, signal.usable, noise)
    conditions = operating_conditions(recording, signal, res_before, res_after)
    heldout = problem.heldout
    mse_before, mse_after = selection.plain.heldout_mse, selection.winner.heldout_mse
    excess = mse_before - noise**2
    explained = (mse_before - mse_after) / excess if excess > 0 else 0.0
    channels_fit = {}
    for i, c in enumerate(problem.channels):
        held = np.zeros(recording.n, bool)
        for _, test in problem.channel_folds[i]:
            held |= test
        channels_fit[c.name] = {
            "unit": c.unit, "rmse_before": _rmse(c.values - problem.plain_predictions[i], held),
            "rmse_after": _rmse(c.values - after_channels[i], held),
            "noise_sigma": noise if i == 0 else c.noise_sigma, "weight_rmse": 1.0 / math.sqrt(
                problem.weights[i] * max(int(c.usable.sum()), 1)), "samples_scored": int(held.sum())}
    fit = {
        "signal": signal.name,
        "signals": [c.name for c in problem.channels],
        "rmse_before": math.sqrt(mse_before),
        "rmse_after": math.sqrt(mse_after),
        "noise_sigma": noise,
        "noise_measured": noise_measured,
        "noise_samples": noise_count,
        "heldout": True,
        "explained_fraction": float(np.clip(explained, 0.0, 1.0)),
        "heading_rmse_before_rad": _rmse(pose_before.heading_error_rad, heldout),
        "heading_rmse_after_rad": _rmse(pose_after.heading_error_rad, heldout),
        "position_rmse_before_m": _rmse(pose_before.position_error_m, heldout),
        "position_rmse_after_m": _rmse(pose_after.position_error_m, heldout),
        "channels": channels_fit,
        "anchor_s": anchor_s,
        "split": split,
        "block_s": block_s,
        "heldout_fraction": float(heldout.sum() / max(signal.usable.sum(), 1)),
        "t_statistic": selection.t_statistic,
        "score_before": selection.plain.score,
        "score_after": selection.winner.score,
    }
    # 4. What is left, and the verdict.
    plain_signal = filtered_plain = problem.plain_predictions[0]
    shape = selection.winner.shapes[0] if selection.winner.shapes else None
    left = residual_analysis(recording, signal, after, heldout, noise, r_plain, shape)
    left_plain = left if not selection.winner.effects else residual_analysis(
        recording, signal, before, heldout, noise, r_plain)
    data["model_signal_rms"] = float(np.std(filtered_plain[signal.usable]))
    data["recorded_signal_rms"] = float(np.std(signal.values[signal.usable]))
    data["steer_std_rad"] = float(np.std(recording.steer_rad[signal.usable]))
    verdict = _verdict(selection, fit, data, left, left_plain, noise, signal, plain_signal)
    d = Diagnosis(recording, signal, noise, selection, block_s, anchor_s, heldout, before, after, best,
                  pose_before, pose_after, windows, conditions, fit, summary="", checks=checks, notes=notes,
                  verdict=verdict, confidence="low" if data["low_confidence_reasons"] or data["unchecked_consistency"]
                  else "normal", data=data,
                  residual=left if selection.winner.effects else left_plain, channels=problem.channels,
                  problem=problem, consistency=consistency, library_verdict=verdict)
    d.summary = summary_text(d)
    caveats = [n for n in notes if "yaw_rate runs" in n]
    if caveats and verdict not in ("unexcited",):
        d.summary += "\nCaveat: " + "; ".join(caveats) + "."
    doubts = library_doubts(selection.winner, consistency) if verdict in ("mismatch", "partly explained") else []
    if doubts:
        d.notes.append("doubtful: " + "; ".join(doubts))
        d.summary += "\nDoubtful: " + "; ".join(doubts) + "."
    if (discovery == "always" and verdict not in ("unexcited",)
            or discovery == "auto" and should_run(verdict, fit["explained_fraction"])):
        d.discovery = discover(problem, selection, noise, rng, consistency)
        if d.discovery.named:
            d.verdict = "discovered"
        d.summary += "\n" + discovery_text(d.discovery, signal)
    return d


def _noise(problem: FitProblem, best_fit: CandidateFit, res_before: np.ndarray) -> tuple[float, int, bool]:
    """The gyro's noise from the third differences of the best candidate's out-of-fold residual (or
    the plain model's, if lower), on the rows as recorded."""
    signal = problem.signal
    if signal.name != "yaw_rate":
        return signal.noise_sigma, MIN_NOISE_SAMPLES if signal.noise_measured else 0, signal.noise_measured
    rec = problem.recording
    _, residual, usable, _ = on_recorded_samples(rec, signal, best_fit.oof[0], problem.heldout)
    sigma, count = noise_estimate(np.where(usable, residual, 0.0), usable)
    _, res_plain, usable_plain, _ = on_recorded_samples(rec, signal, signal.values - res_before, signal.usable)
    sigma_plain, count_plain = noise_estimate(np.where(usable_plain, res_plain, 0.0), usable_plain)
    if not math.isfinite(sigma) or (math.isfinite(sigma_plain) and sigma_plain < sigma):
        sigma, count = sigma_plain, count_plain
    return (sigma if math.isfinite(sigma) else 0.0), count, count >= MIN_NOISE_SAMPLES


def _verdict(sel: Selection, fit: dict, data: dict, left: dict, left_plain: dict, noise: float,
             signal: FitSignal, plain_signal: np.ndarray) -> str:
    scale = max(float(np.sqrt(np.mean(signal.values[signal.usable] ** 2))), 1e-12)
    data["reproduced"] = bool(fit["rmse_before"] <= REPRODUCED_RELATIVE * scale)
    if data["reproduced"]:
        return "match"  # the simulator's own replay, up to the digits the file was written with
    floor = EXCITATION_NOISE_FACTOR * max(noise, 1e-9 * scale)
    steering_flat = data["model_signal_rms"] <= floor
    data["steering_flat"] = bool(steering_flat and data["recorded_signal_rms"] > floor)
    if steering_flat and data["recorded_signal_rms"] <= floor:
        return "unexcited"
    if sel.verdict == "mismatch":
        # A yaw-plane term can fit the yaw rate while moving the car the wrong way (a steering offset
        # standing in for a road bank or grade): the re-anchored position must not get worse.
        data["position_worse"] = bool(fit["position_rmse_after_m"] > (1 + POSITION_WORSE) * fit["position_rmse_before_m"])
        data["structure_within_accuracy"] = bool(left["structured"]
                                                 and fit["explained_fraction"] >= STRUCTURE_MATTERS_BELOW)
        if (fit["explained_fraction"] < PARTLY_EXPLAINED_BELOW or data["position_worse"]
                or (left["structured"] and not data["structure_within_accuracy"])):
            return "partly explained"
        return "mismatch"
    if steering_flat:
        return "unexplained"
    if left_plain["structured"]:
        return "unexplained"
    if data["low_confidence_reasons"] or not fit["noise_measured"]:
        reasons = list(data["low_confidence_reasons"])
        if not fit["noise_measured"]:
            reasons.append(f"the noise was measured on only {fit['noise_samples']} samples")
        data["inconclusive_because"] = " and ".join(reasons)
        return "inconclusive"
    return "match"
