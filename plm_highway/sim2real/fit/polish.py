"""A candidate's coordinates and their polish: bounded least squares on every recorded channel.

A candidate's coordinates are its effects' parameters (``effect.parameter``) as the registry
defines them. Linear ones (gain, offset, bank) move one chain parameter each (their registry
``move``) and are solved in closed form on the grid; a variance parameter (the jitter) is fitted
from the scatter (:mod:`.jitter`), not by least squares. :func:`polish` refines the mean
coordinates with ``scipy.optimize.least_squares`` (trust-region reflective, bounded) on all
channels, each weighted by the inverse of the plain model's mean-square error on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from plm_highway.sim2real.fit.grid import LinearDirection
from plm_highway.sim2real.fit.problem import FitProblem
from plm_highway.sim2real.physics.effect_spec import ChainMove
from plm_highway.sim2real.physics.effects import SPECS, EffectParams, FitContext, effect_report, params_from

MAX_POLISH_EVALUATIONS = 40


@dataclass(frozen=True)
class Coordinate:
    key: str  # "effect.parameter"
    effect: str
    name: str
    scale: float
    lo: float
    hi: float
    linear: bool
    variance: bool
    neutral: float  # the value that leaves the chain as the simulator
    move: ChainMove | None  # a linear mean coordinate's move of the chain

    @property
    def direction(self) -> LinearDirection:
        """The chain direction the grid solves this linear coordinate along."""
        return LinearDirection(self.move.field, self.move.step)


def coordinates(effects: tuple[str, ...], ctx: FitContext) -> list[Coordinate]:
    out = []
    for e in effects:
        for p in SPECS[e].parameters:
            lo, hi = p.bounds_for(ctx)
            out.append(Coordinate(f"{e}.{p.name}", e, p.name, p.scale, lo, hi, p.linear, p.variance, p.neutral,
                                  p.move))
    return out


def public_estimates(problem: FitProblem, effects: tuple[str, ...], params: EffectParams) -> dict[tuple[str, str], float]:
    out = {}
    for e in effects:
        for k, val in effect_report(e, params, problem.ctx).items():
            out[(e, k)] = float(val)
    return out


@dataclass
class Polished:
    values: dict[str, float]  # coordinates
    cost: float  # weighted sum of squares
    jacobian: np.ndarray  # of the weighted residual, in coordinate units
    residual: np.ndarray  # weighted, stacked over channels
    primary_residual: np.ndarray  # unweighted primary-channel residual on its mask
    keys: list[str]


def polish(problem: FitProblem, effects: tuple[str, ...], start: dict[str, float], masks: list[np.ndarray]
           ) -> Polished:
    """Least squares over every mean coordinate on all channels (``masks`` per channel)."""
    coords = [c for c in coordinates(effects, problem.ctx) if not c.variance]
    fixed = {c.key: start.get(c.key, 0.0) for c in coordinates(effects, problem.ctx) if c.variance}
    scale = np.array([c.scale for c in coords])
    lo = np.array([c.lo for c in coords])
    hi = np.array([c.hi for c in coords])
    x0 = np.clip(np.array([start[c.key] for c in coords], float), lo, hi)
    sqrt_w = [math.sqrt(w) for w in problem.weights]
    indices = [np.flatnonzero(m) for m in masks]
    ys = [c.values[i] for c, i in zip(problem.channels, indices)]

    def params(z: np.ndarray) -> EffectParams:
        return params_from(effects, dict(zip([c.key for c in coords], z * scale)) | fixed, problem.ctx)

    def residual(z: np.ndarray) -> np.ndarray:
        preds = problem.predictions_at(params(z), indices)
        return np.concatenate([sw * (p - y) for sw, p, y in zip(sqrt_w, preds, ys)])

    result = least_squares(residual, x0 / scale, bounds=(lo / scale, hi / scale), method="trf", diff_step=1e-4,
                           ftol=1e-7, xtol=1e-6, gtol=1e-12, max_nfev=MAX_POLISH_EVALUATIONS)
    values = dict(zip([c.key for c in coords], result.x * scale)) | fixed
    n_primary = int(masks[0].sum())
    primary = result.fun[:n_primary] / sqrt_w[0]
    return Polished(values, float(result.fun @ result.fun), result.jac / scale, result.fun, primary,
                    [c.key for c in coords])
