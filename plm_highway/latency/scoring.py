"""How good a latency estimate was: judged against the true latency, tick by tick.

Pure functions of arrays (one entry per tick): the true latency (the age of the frame the car got), the
estimate a consumer used (:attr:`~plm_highway.latency.estimate.LatencyEstimate.held_s`), whether the
estimator called it estimable, and the tolerance: one frame period of the loop (the precision a frame-based
pipeline can be asked for; 50 ms at 20 Hz, 33 ms at 30 Hz).

- :func:`lock_metrics`: for a latency that holds still: when the estimator first gave an estimable value,
  when it first gave a right one (within the tolerance), how often an estimable value was wrong, and how
  close the used estimate stayed afterwards.
- :func:`step_metrics`: for a latency that changes: after each change of at least half a frame, how long
  until the used estimate is within the tolerance again; and the share of all ticks within it.
- :func:`quiet_metrics`: on stretches where the car barely turns (nothing to align), how often the estimator
  still claimed an estimate, and how often that claim was wrong.
- :func:`claim_step_metrics`: after each step of the true latency by at least two frames, whether the estimator
  stopped claiming a wrong value within 1 s, and whether it then claimed the new value within 5 s or said
  "changing" until it could (and, of the steps it did not answer, those it met saying "not estimable" throughout).
"""

from __future__ import annotations

import math

import numpy as np

from plm_highway.errors import BadInput


def _columns(**named) -> dict[str, np.ndarray]:
    arrays = {name: np.asarray(values) for name, values in named.items()}
    lengths = {len(values) for values in arrays.values()}
    if len(lengths) != 1 or any(values.ndim != 1 for values in arrays.values()):
        raise BadInput(f"scoring: every column must be one-dimensional of one length, got "
                       f"{ {name: values.shape for name, values in arrays.items()} }")
    return arrays


def within(estimate_s, true_s, tolerance_s: float) -> np.ndarray:
    """Ticks whose estimate is within ``tolerance_s`` of the truth (NaN estimates are not)."""
    error = np.abs(np.asarray(estimate_s, float) - np.asarray(true_s, float))
    return np.nan_to_num(error, nan=np.inf) <= tolerance_s + 1e-9


def lock_metrics(time_s, true_s, held_s, latency_s, estimable, tolerance_s: float) -> dict:
    """Lock time and error for a run (see the module docstring); times are from the run's first tick.

    ``held_s`` is what a consumer used at each tick, ``latency_s`` the estimator's own estimate there (NaN
    where it had none) and ``estimable`` its verdict.
    """
    c = _columns(time_s=time_s, true_s=true_s, held_s=held_s, latency_s=latency_s, estimable=estimable)
    t, estimable = c["time_s"].astype(float) - float(c["time_s"][0]), c["estimable"].astype(bool)
    right = within(c["latency_s"], c["true_s"], tolerance_s)
    held_right = within(c["held_s"], c["true_s"], tolerance_s)
    first = int(np.argmax(estimable)) if estimable.any() else None
    locked = estimable & right
    lock = int(np.argmax(locked)) if locked.any() else None
    after = slice(first, None) if first is not None else slice(0, 0)
    held_error = np.abs(c["held_s"] - c["true_s"])[after]
    return {
        "first_estimable_s": math.nan if first is None else float(t[first]),
        "lock_s": math.nan if lock is None else float(t[lock]),
        "estimable_fraction": float(estimable.mean()),
        "wrong_when_estimable_fraction": float((estimable & ~right).sum() / max(estimable.sum(), 1)),
        "claims": int(estimable.sum()),
        "wrong_claims": int((estimable & ~right).sum()),
        "within_after_first_fraction": float(held_right[after].mean()) if held_error.size else math.nan,
        "median_error_after_first_s": float(np.median(held_error)) if held_error.size else math.nan,
        "p90_error_after_first_s": float(np.percentile(held_error, 90)) if held_error.size else math.nan,
        "within_fraction": float(held_right.mean()),
    }


def step_metrics(time_s, true_s, held_s, tolerance_s: float, budget_s: float = 1.0) -> dict:
    """Recovery after each change of the true latency by at least half the tolerance (module docstring).

    A change's recovery time is the time from the change to the first tick whose used estimate is within the
    tolerance, looked for until the next change; a change never recovered from counts as not within the budget.
    """
    c = _columns(time_s=time_s, true_s=true_s, held_s=held_s)
    t = c["time_s"].astype(float)
    changes = np.flatnonzero(np.abs(np.diff(c["true_s"])) >= tolerance_s / 2 - 1e-9) + 1
    right = within(c["held_s"], c["true_s"], tolerance_s)
    recoveries = []
    for index, start in enumerate(changes):
        stop = changes[index + 1] if index + 1 < len(changes) else len(t)
        hits = np.flatnonzero(right[start:stop])
        recoveries.append(float(t[start + hits[0]] - t[start]) if hits.size else math.inf)
    recoveries_array = np.array(recoveries)
    finite = recoveries_array[np.isfinite(recoveries_array)]
    return {
        "changes": int(len(changes)),
        "recovered_within_budget_fraction": float(np.mean(recoveries_array <= budget_s + 1e-9))
        if len(changes) else math.nan,
        "median_recovery_s": float(np.median(finite)) if finite.size else math.nan,
        "never_recovered": int(np.sum(~np.isfinite(recoveries_array))),
        "within_fraction": float(right.mean()),
    }


def quiet_ticks(time_s, yaw_rate_radps, window_s: float, threshold_radps: float) -> np.ndarray:
    """Ticks at which the yaw rate's standard deviation over the last ``window_s`` stayed below
    ``threshold_radps``: the car went (nearly) straight, with nothing for a camera to be aligned with."""
    c = _columns(time_s=time_s, yaw_rate_radps=yaw_rate_radps)
    t, rate = c["time_s"].astype(float), c["yaw_rate_radps"].astype(float)
    quiet = np.zeros(len(t), bool)
    start = 0
    for k in range(len(t)):
        while t[start] < t[k] - window_s:
            start += 1
        quiet[k] = t[k] - t[0] >= window_s and float(np.std(rate[start:k + 1])) < threshold_radps
    return quiet


def quiet_metrics(quiet, latency_s, true_s, estimable, tolerance_s: float) -> dict:
    """On the quiet ticks: how often an estimate was claimed, and how often a claimed one was wrong."""
    c = _columns(quiet=quiet, latency_s=latency_s, true_s=true_s, estimable=estimable)
    quiet, estimable = c["quiet"].astype(bool), c["estimable"].astype(bool)
    claimed = quiet & estimable
    wrong = claimed & ~within(c["latency_s"], c["true_s"], tolerance_s)
    return {"quiet_ticks": int(quiet.sum()), "estimable_when_quiet_fraction": float(claimed.sum() / max(quiet.sum(), 1)),
            "wrong_when_quiet_fraction": float(wrong.sum() / max(quiet.sum(), 1))}


def claim_step_metrics(time_s, true_s, held_s, estimable, changing, tolerance_s: float, stop_budget_s: float = 1.0,
                       claim_budget_s: float = 5.0, blind_s: float = 0.0) -> dict:
    """How the claims behave after each step of the true latency by at least two tolerances (module docstring).

    A step's segment runs to the next change of the truth by at least half a tolerance. *Stopped*: no claim more
    than a tolerance off the truth from ``stop_budget_s`` after the step to the segment's end. *Answered*: a claim
    within the tolerance before ``claim_budget_s`` (or the segment's end), or else no claim and "changing" at every
    tick from ``stop_budget_s`` on until then. A segment shorter than ``stop_budget_s`` asks nothing of either.
    Steps in the run's first ``blind_s`` are not judged: there the camera's first frames grow from age 0 to the
    latency (the start of a stream, not a change of its latency), and an estimator that waits ``blind_s`` for a
    history as long as its largest lag has seen nothing to compare the new latency with.
    """
    c = _columns(time_s=time_s, true_s=true_s, held_s=held_s, estimable=estimable, changing=changing)
    t, true = c["time_s"].astype(float), c["true_s"].astype(float)
    claimed, changing = c["estimable"].astype(bool), c["changing"].astype(bool)
    right = within(c["held_s"], true, tolerance_s)
    jumps = np.abs(np.diff(true))
    boundaries = np.flatnonzero(jumps >= tolerance_s / 2 - 1e-9) + 1
    steps = [int(b) for b in boundaries
             if jumps[b - 1] >= 2 * tolerance_s - 1e-9 and t[b] >= t[0] + blind_s - 1e-9]
    stopped, answered, unseen, judged = [], [], [], 0
    for start in steps:
        later = boundaries[boundaries > start]
        stop = int(later[0]) if later.size else len(t)
        after = np.flatnonzero(t[start:stop] >= t[start] + stop_budget_s - 1e-9) + start
        if not after.size:
            continue
        judged += 1
        stopped.append(not np.any(claimed[after] & ~right[after]))
        horizon = after[t[after] < t[start] + claim_budget_s - 1e-9]
        span = np.arange(start, horizon[-1] + 1) if horizon.size else np.arange(start, start)
        answered.append(bool(np.any(claimed[span] & right[span]))
                        or bool(horizon.size and np.all(~claimed[horizon] & changing[horizon])))
        # Unanswered, but "not estimable" at every tick from the step to the claim budget: no claim to stop and too
        # little information to see that the latency moved (told apart in reports, still counted as unanswered).
        unseen.append(not answered[-1] and not np.any((claimed | changing)[span]))
    return {
        "steps": int(len(steps)),
        "steps_judged": judged,
        "stopped_within_budget_fraction": float(np.mean(stopped)) if stopped else math.nan,
        "answered_fraction": float(np.mean(answered)) if answered else math.nan,
        "handled_fraction": float(np.mean(np.logical_and(stopped, answered))) if stopped else math.nan,
        "stopped": int(np.sum(stopped)),
        "answered": int(np.sum(answered)),
        "handled": int(np.sum(np.logical_and(stopped, answered))),
        "unanswered_not_estimable": int(np.sum(unseen)),
    }
