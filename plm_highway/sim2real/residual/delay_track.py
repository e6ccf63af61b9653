"""A delay that varies in time: its track, fitted on half the gyro's samples and judged on the others.

The library's delays are constants (``transport_delay``) or white jitter around one (``delay_jitter``).
A delay that wanders (a camera pipeline whose latency changes with load, a bus that holds its
frames) leaves an error that follows the steering rate with a sign and size that change from stretch
to stretch. The track is the chain's constant delay plus a piecewise-constant change per ``KNOT_S``:

    wheel(t) = command(t - delay - change(t))

fitted by Gauss-Newton on the gyro's residual against the signal's sensitivity to the delay, with a
total-variation penalty on the change between knots (iteratively reweighted least squares, one
banded solve per iteration; the penalty is chosen on held-out samples). A track explains a stretch
only from that stretch, so it cannot predict other blocks: it is fitted on every other sample of
the gyro and judged on the samples between (whose white noise it has not seen), then the other way
round. Held out that way a track can follow any smooth error the steering happens to scale, so it
must also beat a free-form smoother of the same flexibility (the error itself, piecewise constant
per knot, the same penalty): only an error that follows the delay's signature (it changes sign with
the steering rate) does. Where the steering barely moves, the delay cannot be seen; the track stays at the chain's
delay there and the summary says what share of the run it describes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import solve_banded

from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem
from plm_highway.sim2real.fit.scoring import combined_score
from plm_highway.sim2real.physics.effects import EffectParams, later_by, transport_delay_s, without_scatter
from plm_highway.sim2real.physics.replay import FitSignal, channel_prediction, model_outputs
from plm_highway.sim2real.record.recording import Recording

# Knots at half the shortest hold worth resolving (0.1 s).
KNOT_S = 0.05
SENSITIVITY_STEP_S = 0.005
GAUSS_NEWTON_ITERATIONS = 3
IRLS_ITERATIONS = 6
TV_EPSILON_S = 0.005
PENALTY_GRID = (0.3, 1.0, 3.0, 10.0, 30.0)
MAX_CHANGE_S = 0.5
# Parameters a track counts as for the complexity penalty: the penalty chosen and the knot spacing
# (its values are judged on samples it has not seen, not counted one by one).
TRACK_DOF = 2
# The delay is seen where one knot's value is known to this standard error (the steering moves).
VISIBLE_ERROR_S = 0.03
# A change between knots counts as a new value above this share of the track's 5-95% range.
STEP_SHARE = 0.25


@dataclass
class DelayTrack:
    """A fitted track: the delay at each sample (the chain's plus the change) and its standard error."""

    delay_at_sample_s: np.ndarray
    standard_error_s: np.ndarray
    visible: np.ndarray  # samples whose knot's value is known to VISIBLE_ERROR_S (the steering moves)
    base_delay_s: float
    penalty: float
    smoother_mse: float = math.nan  # held out, of a free-form smoother as flexible (see _smoother_mse)


def warped(recording: Recording, change_s: np.ndarray, base_delay_s: float) -> Recording:
    """The recording with its command re-timed so that the chain's constant delay ``base_delay_s``
    makes the wheels follow ``command(t - base_delay_s - change_s(t))`` (``change_s`` at wheel time)."""
    t = recording.t_s
    shift = np.interp(t + base_delay_s, t, change_s)
    return replace(recording, steer_rad=np.interp(t - shift, t, recording.steer_rad))


def _gyro(problem: FitProblem) -> tuple[int, FitSignal] | None:
    for i, c in enumerate(problem.channels):
        if c.name == "yaw_rate":
            return i, c
    return None


def _prediction(signal: FitSignal, recording: Recording, params: EffectParams) -> np.ndarray:
    return channel_prediction(signal, recording, params, model_outputs(recording, params, with_slip=False))


def _knots(n: int, dt: float) -> tuple[np.ndarray, int]:
    per = max(1, round(KNOT_S / dt))
    index = np.arange(n) // per
    return index, int(index[-1]) + 1


def _tv_fit(residual: np.ndarray, sensitivity: np.ndarray, knot: np.ndarray, n_knots: int, mask: np.ndarray,
            penalty: float, epsilon: float = TV_EPSILON_S, limit: float = MAX_CHANGE_S
            ) -> tuple[np.ndarray, np.ndarray]:
    """Per-knot delay change minimising sum (e - s d)^2 + penalty sum |d_k+1 - d_k| (IRLS), and each
    knot's curvature (the diagonal of the normal matrix, for standard errors)."""
    a = np.bincount(knot[mask], weights=sensitivity[mask] ** 2, minlength=n_knots)
    b = np.bincount(knot[mask], weights=(sensitivity * residual)[mask], minlength=n_knots)
    ridge = 1e-6 * max(float(np.median(a[a > 0])) if np.any(a > 0) else 1.0, 1e-30)
    change = np.zeros(n_knots)
    for _ in range(IRLS_ITERATIONS):
        w = penalty / np.maximum(np.abs(np.diff(change)), epsilon)
        diagonal = a + ridge
        diagonal[:-1] += w
        diagonal[1:] += w
        banded = np.zeros((3, n_knots))
        banded[0, 1:] = -w
        banded[1] = diagonal
        banded[2, :-1] = -w
        change = np.clip(solve_banded((1, 1), banded, b), -limit, limit)
    return change, a + ridge


def fit_track(problem: FitProblem, params: EffectParams, mask: np.ndarray, penalty: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """The delay change at each sample fitted on ``mask`` (Gauss-Newton around the chain), and each
    sample's standard error (from its knot's curvature and the residual variance)."""
    gyro_index, gyro = _gyro(problem)
    rec = problem.recording
    knot, n_knots = _knots(rec.n, rec.dt_s)
    mask = mask & gyro.usable
    change = np.zeros(rec.n)
    curvature = np.ones(n_knots)
    later = later_by(params, SENSITIVITY_STEP_S)
    base_delay_s = transport_delay_s(params)
    for _ in range(GAUSS_NEWTON_ITERATIONS):
        shifted = warped(rec, change, base_delay_s)
        pred = _prediction(gyro, shifted, params)
        sensitivity = (_prediction(gyro, shifted, later) - pred) / SENSITIVITY_STEP_S
        step, curvature = _tv_fit(gyro.values - pred, sensitivity, knot, n_knots, mask, penalty)
        change = np.clip(change + step[knot], -base_delay_s, MAX_CHANGE_S)
    residual = gyro.values - _prediction(gyro, warped(rec, change, base_delay_s), params)
    variance = float(np.mean(residual[mask] ** 2)) if mask.any() else 1.0
    return change, np.sqrt(variance / curvature)[knot]


def _base_params(base: CandidateFit) -> EffectParams:
    """The chain a track replaces the jitter of (the track is the delay's variation)."""
    return without_scatter(base.params)


def interleaved_problem(problem: FitProblem) -> FitProblem:
    """The gyro alone, held out sample by sample: even samples fit, odd ones judge, and back."""
    _, gyro = _gyro(problem)
    even = np.arange(problem.recording.n) % 2 == 0
    return FitProblem(problem.recording, [gyro], [(even, ~even), (~even, even)])


def _candidate(interleaved: FitProblem, base: CandidateFit, predictions: np.ndarray, dof: int) -> CandidateFit:
    gyro = interleaved.channels[0]
    held = np.zeros(interleaved.recording.n, bool)
    for _, test in interleaved.channel_folds[0]:
        held |= test
    err = (predictions - gyro.values)[held]
    fit = CandidateFit(base.effects, base.params, dof, math.nan, float(np.mean(err**2)), oof=[predictions],
                       shapes=[None])
    fit.raw_score = combined_score(interleaved, fit)
    fit.score = fit.raw_score * (1 + 0.01 * dof)
    return fit


def compare(problem: FitProblem, base: CandidateFit) -> tuple[FitProblem, CandidateFit, CandidateFit, DelayTrack] | None:
    """(the interleaved problem, the chain and the chain with a delay track held out there, the track
    fitted on every sample with the penalty the held-out samples chose); None without a gyro."""
    if _gyro(problem) is None:
        return None
    interleaved = interleaved_problem(problem)
    gyro = interleaved.channels[0]
    rec = problem.recording
    params = _base_params(base)
    base_delay_s = transport_delay_s(params)
    plain = _prediction(gyro, rec, base.params)
    base_fit = _candidate(interleaved, base, plain, base.dof)
    best = None
    for factor in PENALTY_GRID:
        penalty = factor * _penalty_scale(problem, params)
        oof = np.full(rec.n, np.nan)
        for train, test in interleaved.channel_folds[0]:
            change, _ = fit_track(problem, params, train, penalty)
            oof[test] = _prediction(gyro, warped(rec, change, base_delay_s), params)[test]
        fit = _candidate(interleaved, base, oof, base.dof + TRACK_DOF)
        if best is None or fit.score < best[0].score:
            best = (fit, penalty)
    fit, penalty = best
    change, error = fit_track(problem, params, gyro.usable, penalty)
    visible = gyro.usable & (error <= VISIBLE_ERROR_S)
    track = DelayTrack(base_delay_s + change, error, visible, base_delay_s, penalty,
                       smoother_mse=_smoother_mse(interleaved, plain))
    return interleaved, base_fit, fit, track


def _smoother_mse(interleaved: FitProblem, plain: np.ndarray) -> float:
    """Held-out mean-square error of a free-form smoother of the same flexibility: the gyro's error
    itself, piecewise constant per knot with the same total-variation penalty (no physics). A delay
    track that does no better is explaining a smooth error, not a varying delay."""
    gyro = interleaved.channels[0]
    rec = interleaved.recording
    knot, n_knots = _knots(rec.n, rec.dt_s)
    residual = gyro.values - plain
    ones = np.ones(rec.n)
    noise = gyro.noise_sigma if math.isfinite(gyro.noise_sigma) else float(np.std(residual[gyro.usable]))
    best = math.inf
    for factor in PENALTY_GRID:
        per_knot = max(round(KNOT_S / rec.dt_s), 1)
        penalty = factor * per_knot * max(noise, 1e-9)
        oof = np.full(rec.n, np.nan)
        for train, test in interleaved.channel_folds[0]:
            offset, _ = _tv_fit(residual, ones, knot, n_knots, train, penalty, epsilon=max(noise, 1e-9),
                                limit=math.inf)
            oof[test] = offset[knot][test]
        held = np.isfinite(oof) & gyro.usable
        best = min(best, float(np.mean((residual - oof)[held] ** 2)))
    return best


def _penalty_scale(problem: FitProblem, params: EffectParams) -> float:
    """A natural unit of the total-variation penalty: a typical knot's curvature times TV_EPSILON_S."""
    _, gyro = _gyro(problem)
    rec = problem.recording
    pred = _prediction(gyro, rec, params)
    later = later_by(params, SENSITIVITY_STEP_S)
    sensitivity = (_prediction(gyro, rec, later) - pred) / SENSITIVITY_STEP_S
    knot, n_knots = _knots(rec.n, rec.dt_s)
    a = np.bincount(knot[gyro.usable], weights=sensitivity[gyro.usable] ** 2, minlength=n_knots)
    return float(np.median(a[a > 0])) * TV_EPSILON_S if np.any(a > 0) else 1.0


def _holds(track: DelayTrack, step_s: float, dt_s: float) -> np.ndarray:
    """How long each value is held [s]: the stretches between two changes of the track, counted only
    where the track is seen throughout (elsewhere it keeps its last value for want of evidence)."""
    holds = []
    seen = np.concatenate([[False], track.visible, [False]])
    starts = np.flatnonzero(~seen[:-1] & seen[1:])
    stops = np.flatnonzero(seen[:-1] & ~seen[1:])
    for a, b in zip(starts, stops):
        changes = a + 1 + np.flatnonzero(np.abs(np.diff(track.delay_at_sample_s[a:b])) > step_s)
        holds += list(np.diff(changes) * dt_s)
    return np.array(holds)


def describe(track: DelayTrack, dt_s: float) -> tuple[dict[str, float], dict[str, list[float]], str]:
    """Estimates (range, holds), their intervals and the sentence."""
    seen = track.visible if track.visible.any() else np.ones(track.delay_at_sample_s.size, bool)
    values = track.delay_at_sample_s[seen]
    lo, mid, hi = (float(np.percentile(values, q)) for q in (5, 50, 95))
    error = float(np.median(track.standard_error_s[seen]))
    holds = _holds(track, max(STEP_SHARE * (hi - lo), 0.01), dt_s)
    h10, h50, h90 = (float(np.percentile(holds, q)) for q in (10, 50, 90)) if holds.size else (math.nan,) * 3
    estimates = {"delay_low_s": lo, "delay_median_s": mid, "delay_high_s": hi, "hold_short_s": h10,
                 "hold_median_s": h50, "hold_long_s": h90, "visible_fraction": float(seen.mean()),
                 "standard_error_s": error}
    ci = {"delay_low_s": [lo - 1.96 * error, lo + 1.96 * error], "delay_high_s": [hi - 1.96 * error, hi + 1.96 * error],
          "delay_median_s": [mid - 1.96 * error, mid + 1.96 * error]}
    sentence = (f"the delay varies between {lo:.2f} and {hi:.2f} s (5-95%, median {mid:.2f} s; each value +-"
                f"{1.96 * error:.2f} s), holding each value for {h10:.2f}-{h90:.2f} s (median {h50:.2f} s); seen "
                f"where the steering moves ({100 * seen.mean():.0f}% of the run)")
    return estimates, ci, sentence
