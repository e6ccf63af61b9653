"""The winner and runner-up refitted on all usable samples, with 95% intervals.

Intervals from the least-squares Jacobian with the residual variance inflated for autocorrelation
(AR(1) effective sample size), derived quantities (the public parameter names) by the delta
method; the jitter from a block bootstrap of its variance regression (:mod:`.jitter`).
"""

from __future__ import annotations

import numpy as np

from plm_highway.sim2real.fit.jitter import jitter_interval, with_scatter
from plm_highway.sim2real.fit.polish import Polished, coordinates, polish, public_estimates
from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem
from plm_highway.sim2real.physics.effects import SPECS, coordinates_of, params_from


def _autocorrelation_inflation(residual: np.ndarray) -> float:
    """n / n_eff for AR(1)-like residuals (>= 1)."""
    r = residual - residual.mean()
    denom = float(np.dot(r, r))
    if denom <= 0 or r.size < 3:
        return 1.0
    rho = float(np.clip(np.dot(r[1:], r[:-1]) / denom, 0.0, 0.99))
    return (1 + rho) / (1 - rho)


def _uncertainty(problem: FitProblem, effects: tuple[str, ...], result: Polished) -> tuple[dict, dict]:
    """Public estimates and 95% intervals per effect, from the Jacobian (delta method for derived)."""
    n, p = result.residual.size, len(result.keys)
    s2 = result.cost / max(n - p, 1) * _autocorrelation_inflation(result.primary_residual)
    cov = s2 * np.linalg.pinv(result.jacobian.T @ result.jacobian)
    centre = public_estimates(problem, effects, params_from(effects, result.values, problem.ctx))
    keys = list(centre)
    grads = np.zeros((len(keys), p))
    scales = {c.key: c.scale for c in coordinates(effects, problem.ctx)}
    for j, key in enumerate(result.keys):
        h = 1e-4 * scales[key]
        shifted_values = dict(result.values)
        shifted_values[key] += h
        shifted = public_estimates(problem, effects, params_from(effects, shifted_values, problem.ctx))
        grads[:, j] = [(shifted[k] - centre[k]) / h for k in keys]
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", grads, cov, grads), 0.0))
    estimates: dict[str, dict[str, float]] = {}
    ci: dict[str, dict[str, list[float]]] = {}
    for (e, k), s in zip(keys, sd):
        estimates.setdefault(e, {})[k] = centre[(e, k)]
        ci.setdefault(e, {})[k] = [centre[(e, k)] - 1.96 * float(s), centre[(e, k)] + 1.96 * float(s)]
    return estimates, ci


def refit(problem: FitProblem, fit: CandidateFit, rng: np.random.Generator | None = None) -> CandidateFit:
    """Refit a candidate on all usable samples (from its best fold solution), with 95% intervals."""
    if not fit.effects or fit.refitted:
        return fit
    rng = np.random.default_rng(0) if rng is None else rng
    masks = [c.usable for c in problem.channels]
    best = None
    for start in fit.fold_params:
        result = polish(problem, fit.effects, coordinates_of(fit.effects, start, problem.ctx), masks)
        if best is None or result.cost < best.cost:
            best = result
    fit.params = params_from(fit.effects, best.values, problem.ctx)
    fit.estimates, fit.ci95 = _uncertainty(problem, fit.effects, best)
    for e in fit.effects:
        for p in SPECS[e].parameters:
            if p.scatter is not None:  # fitted from the scatter, reported under its own name
                std, interval = jitter_interval(problem, fit.params, p.scatter, masks[0], rng)
                fit.params = with_scatter(fit.params, p.scatter, std)
                fit.estimates[e][p.name] = std
                fit.ci95[e][p.name] = interval
    fit.refitted = True
    return fit
