"""Judging candidates on held-out data: combined scores, block-by-block comparisons, bootstraps.

Per channel the held-out mean-square error (for an effect that shapes the error variance,
``delay_jitter``, its Gaussian likelihood written as an equivalent mean-square error), combined as
the geometric mean over channels (the determinant criterion of system identification: a change
counts by its ratio on every channel), times ``1 + PENALTY_PER_PARAMETER p`` for ``p`` fitted
parameters. One candidate is *clearly* better than another when it wins consistently across
held-out stretches (t statistic of the per-second log ratio) or in total (95% block bootstrap).
"""

from __future__ import annotations

import math

import numpy as np

from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem, heldout_mask

PENALTY_PER_PARAMETER = 0.01
T_STAT_THRESHOLD = 3.0
T_BLOCK_S = 1.0
BOOTSTRAP_RESAMPLES = 1000
BOOTSTRAP_DECISION_RESAMPLES = 400


def _mse(pred: np.ndarray, values: np.ndarray, mask: np.ndarray) -> float:
    return float(np.mean((pred - values)[mask] ** 2)) if mask.any() else math.nan


def _equivalent_mse(err2: np.ndarray, shape: np.ndarray | None) -> float:
    """Gaussian likelihood with error variance proportional to ``shape`` (scale profiled out), as the
    mean-square error of a constant-variance model with the same likelihood. Constant shape: the MSE."""
    if err2.size == 0:
        return math.nan
    if shape is None:
        return float(np.mean(err2))
    return float(np.mean(err2 / shape) * np.exp(np.mean(np.log(shape))))


def combined_score(problem: FitProblem, fit: CandidateFit) -> float:
    """Geometric mean over channels of the held-out (likelihood-equivalent) mean-square errors."""
    logs = []
    for i, c in enumerate(problem.channels):
        mask = heldout_mask(problem, i)
        if not mask.any():
            continue
        err2 = (fit.oof[i] - c.values)[mask] ** 2
        shape = fit.shapes[i][mask] if fit.shapes[i] is not None else None
        logs.append(math.log(max(_equivalent_mse(err2, shape), 1e-300)))
    return math.exp(float(np.mean(logs))) if logs else math.nan


def _block_index(problem: FitProblem, block_s: float = T_BLOCK_S) -> np.ndarray:
    t = problem.recording.t_s
    return np.floor((t - t[0]) / block_s).astype(int)


def block_scores(problem: FitProblem, fit: CandidateFit, block_s: float = T_BLOCK_S
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per block and channel: sums of e^2/shape, of log shape, and counts (held-out samples)."""
    block = _block_index(problem, block_s)
    n_blocks = int(block.max()) + 1
    n_ch = len(problem.channels)
    e_sum = np.zeros((n_blocks, n_ch))
    log_sum = np.zeros((n_blocks, n_ch))
    count = np.zeros((n_blocks, n_ch))
    for i, c in enumerate(problem.channels):
        mask = heldout_mask(problem, i)
        err2 = (fit.oof[i] - c.values)[mask] ** 2
        shape = fit.shapes[i][mask] if fit.shapes[i] is not None else np.ones(err2.size)
        b = block[mask]
        e_sum[:, i] = np.bincount(b, weights=err2 / shape, minlength=n_blocks)
        log_sum[:, i] = np.bincount(b, weights=np.log(shape), minlength=n_blocks)
        count[:, i] = np.bincount(b, minlength=n_blocks)
    return e_sum, log_sum, count


def _combined_from_sums(e_sum: np.ndarray, log_sum: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Geometric mean over channels (with samples) of each row's equivalent mean-square error."""
    with np.errstate(divide="ignore", invalid="ignore"):
        eq = np.where(count > 0, e_sum / np.maximum(count, 1) * np.exp(log_sum / np.maximum(count, 1)), np.nan)
        logs = np.log(np.maximum(eq, 1e-300))
    present = count > 0
    return np.exp(np.where(present, logs, 0.0).sum(axis=1) / np.maximum(present.sum(axis=1), 1))


def paired_t_statistic(err_plain: np.ndarray, err_model: np.ndarray, mask: np.ndarray, t_s: np.ndarray,
                       block_s: float = 1.0) -> float:
    """t statistic of the log ratio of the two models' mean-square errors over ``block_s`` blocks.

    The log ratio, not the difference: squared errors are heavy-tailed (a few hard manoeuvres carry
    most of them), and a difference test would call a 99% improvement "inconsistent" because of the
    spread of those few blocks. Under no improvement the log ratios scatter around zero.
    """
    block = np.floor((t_s - t_s[0]) / block_s).astype(int)[mask]
    if block.size == 0:
        return 0.0
    counts = np.bincount(block)
    keep = counts > 0
    mse_plain = np.bincount(block, weights=err_plain[mask] ** 2)[keep] / counts[keep]
    mse_model = np.bincount(block, weights=err_model[mask] ** 2)[keep] / counts[keep]
    return _t_of_log_ratios(np.log(np.maximum(mse_plain, 1e-300)) - np.log(np.maximum(mse_model, 1e-300)))


def _t_of_log_ratios(log_ratio: np.ndarray) -> float:
    log_ratio = log_ratio[np.isfinite(log_ratio)]
    if log_ratio.size < 3:
        return 0.0
    sd = log_ratio.std(ddof=1)
    if sd == 0:
        return math.inf if log_ratio.mean() > 0 else 0.0
    return float(log_ratio.mean() / (sd / math.sqrt(log_ratio.size)))


def consistency_t(problem: FitProblem, worse: CandidateFit, better: CandidateFit) -> float:
    """t statistic of the per-second log ratio of the two candidates' combined held-out scores
    (positive: ``better`` is better). With one channel and constant variance this is
    :func:`paired_t_statistic`."""
    a = block_scores(problem, worse)
    b = block_scores(problem, better)
    has = (a[2].sum(axis=1) > 0) & (b[2].sum(axis=1) > 0)
    sa = _combined_from_sums(*[x[has] for x in a])
    sb = _combined_from_sums(*[x[has] for x in b])
    return _t_of_log_ratios(np.log(np.maximum(sa, 1e-300)) - np.log(np.maximum(sb, 1e-300)))


def bootstrap_ratio(problem: FitProblem, a: CandidateFit, b: CandidateFit, rng: np.random.Generator,
                    resamples: int = BOOTSTRAP_RESAMPLES) -> tuple[float, float, float]:
    """Held-out combined score of ``b`` over ``a`` (penalties included), with a 95% block-bootstrap
    interval over 1-s blocks: (ratio, low, high). Above 1: ``a`` is better."""
    sa, sb = block_scores(problem, a), block_scores(problem, b)
    n_blocks = sa[0].shape[0]
    keep = np.flatnonzero(sa[2].sum(axis=1) > 0)
    penalty = (1 + PENALTY_PER_PARAMETER * b.dof) / (1 + PENALTY_PER_PARAMETER * a.dof)

    def ratio(weights: np.ndarray) -> float:
        # np.tensordot(weights, x, axes=1)[None, :] without tensordot's bookkeeping (the same dot of the same arrays)
        row = weights.reshape(1, -1)
        wa = [np.dot(row, x) for x in sa]
        wb = [np.dot(row, x) for x in sb]
        return float(_combined_from_sums(*wb)[0] / max(_combined_from_sums(*wa)[0], 1e-300)) * penalty

    full = ratio(np.ones(n_blocks))
    if keep.size < 3:
        return full, full, full
    draws = np.empty(resamples)
    for i in range(resamples):
        weights = np.bincount(rng.choice(keep, size=keep.size), minlength=n_blocks).astype(float)
        draws[i] = ratio(weights)
    return full, float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5))


def clearly_better(problem: FitProblem, simpler: CandidateFit, richer: CandidateFit, rng: np.random.Generator
                   ) -> tuple[bool, float]:
    """Is ``richer`` better on held-out data beyond chance? Either consistently (the per-second log
    ratio's t statistic at least ``T_STAT_THRESHOLD``) or in total (the 95% block-bootstrap interval
    of the penalised score ratio above 1: an effect that shows only in some manoeuvres, such as a
    friction limit or a rate limit, wins big in few seconds). Returns (verdict, t statistic)."""
    t_stat = consistency_t(problem, simpler, richer)
    if t_stat >= T_STAT_THRESHOLD:
        return True, t_stat
    _, low, _ = bootstrap_ratio(problem, richer, simpler, rng, BOOTSTRAP_DECISION_RESAMPLES)
    return low > 1.0, t_stat
