"""The variance model of a jittering chain field: the residual's scatter grows with the signal's sensitivity.

A delay that jitters with standard deviation ``j`` leaves a residual whose variance is the noise's
plus ``j^2 (d signal / d delay)^2``: regressed by non-negative least squares on the train blocks,
refitted with the mean, and bootstrapped over 1-s blocks for its interval. Which chain field jitters
and which holds the standard deviation, the registry entry's variance coordinate says (its
:class:`~plm_highway.sim2real.physics.effect_spec.Scatter`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import nnls

from plm_highway.sim2real.fit.problem import FitProblem
from plm_highway.sim2real.fit.scoring import T_BLOCK_S
from plm_highway.sim2real.physics.effect_spec import Scatter
from plm_highway.sim2real.physics.effects import EffectParams, moved

JITTER_ITERATIONS = 2
JITTER_MAX_S = 0.5


def scatter_sensitivity(problem: FitProblem, params: EffectParams, scatter: Scatter, step: float = 1e-3
                        ) -> np.ndarray:
    """d(primary channel)/d(the jittering field): for a delay, the yaw-rate scatter per second of jitter."""
    base = problem.predict(params)
    return (problem.predict(moved(params, scatter.of, step)) - base) / step


def with_scatter(params: EffectParams, scatter: Scatter, std: float) -> EffectParams:
    """``params`` with the jitter's standard deviation set to ``std``."""
    return replace(params, **{scatter.field: std})


def fit_jitter(residual: np.ndarray, sensitivity: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(noise variance, jitter variance) from ``residual^2 ~ s0 + j^2 sensitivity^2`` (non-negative LS)."""
    e2 = residual[mask] ** 2
    g2 = sensitivity[mask] ** 2
    if e2.size < 10:
        return float(np.mean(e2)) if e2.size else 1.0, 0.0
    scale_e, scale_g = max(float(np.mean(e2)), 1e-300), max(float(np.mean(g2)), 1e-300)
    design = np.column_stack([np.ones_like(g2), g2 / scale_g])
    coef, _ = nnls(design, e2 / scale_e)
    s0 = max(coef[0] * scale_e, 1e-6 * scale_e)
    return float(s0), float(coef[1] * scale_e / scale_g)


def jitter_interval(problem: FitProblem, params: EffectParams, scatter: Scatter, mask: np.ndarray,
                    rng: np.random.Generator) -> tuple[float, list[float]]:
    """The jitter's standard deviation on ``mask`` and its 95% interval (block bootstrap)."""
    residual = problem.y - problem.predict(params)
    sens = scatter_sensitivity(problem, params, scatter)
    _, j2 = fit_jitter(residual, sens, mask)
    block = np.floor((problem.recording.t_s - problem.recording.t_s[0]) / T_BLOCK_S).astype(int)
    ids = np.unique(block[mask])
    draws = []
    for _ in range(200):
        pick = rng.choice(ids, size=ids.size)
        counts = np.bincount(pick, minlength=block.max() + 1)
        weights = counts[block] * mask
        idx = np.repeat(np.arange(len(mask)), weights)
        draws.append(math.sqrt(fit_jitter(residual[idx], sens[idx], np.ones(idx.size, bool))[1]))
    return math.sqrt(j2), [float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5))]
