"""Fitting one candidate: grid, polish, held-out predictions and scores (:func:`fit_candidate`).

Each candidate is fitted on each fold's train blocks: its grid stage (:mod:`.gridfit`) gives the
best grid points, :func:`~plm_highway.sim2real.fit.polish.polish` refines them on all channels, and
the fold's model predicts the held-out blocks. A candidate whose grid score cannot win stays a
grid fit (``polished=False``) until :func:`polish_candidate` finishes it.
"""

from __future__ import annotations

import math

import numpy as np

from plm_highway.sim2real.fit.gridfit import FitCache, fold_starts, grid_blocks, remember_top_rows
from plm_highway.sim2real.fit.jitter import (
    JITTER_ITERATIONS,
    JITTER_MAX_S,
    fit_jitter,
    scatter_sensitivity,
    with_scatter,
)
from plm_highway.sim2real.fit.polish import coordinates, polish, public_estimates
from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem, heldout_mask
from plm_highway.sim2real.fit.scoring import PENALTY_PER_PARAMETER, _mse, combined_score
from plm_highway.sim2real.physics.effects import SPECS, EffectParams, coordinates_of, params_from, scatter_of


def _candidate_dof(effects: tuple[str, ...]) -> int:
    return sum(SPECS[e].dof for e in effects)


def _polish_fold(problem: FitProblem, effects: tuple[str, ...], starts: list[EffectParams], fold: int
                 ) -> EffectParams:
    """Polish each start on one fold's train masks (all channels); keep the best."""
    masks = [folds[fold][0] for folds in problem.channel_folds]
    best = None
    for start in starts:
        result = polish(problem, effects, coordinates_of(effects, start, problem.ctx), masks)
        if best is None or result.cost < best.cost:
            best = result
    return params_from(effects, best.values, problem.ctx)


def fit_candidate(problem: FitProblem, effects: tuple[str, ...], cache: FitCache | None = None,
                  polished: bool = True) -> CandidateFit:
    """Fit one candidate on each fold's train blocks and predict its held-out blocks.

    ``polished=False`` stops at the best grid point (linear terms solved); :func:`polish_candidate`
    finishes it later (the screening of candidates that cannot win uses grid fits).
    """
    cache = FitCache() if cache is None else cache
    if not effects:
        plain = scored(problem, effects, [EffectParams() for _ in problem.time_folds], [], True)
        plain.grid_score = plain.score
        return plain
    coords = coordinates(effects, problem.ctx)
    blocks, grams = grid_blocks(problem, effects, coords, cache)
    remember_top_rows(problem, effects, coords, blocks, grams, cache)
    starts = [fold_starts(problem, effects, coords, blocks, grams, f) for f in range(len(problem.time_folds))]
    grid_fit = scored(problem, effects, [s[0] for s in starts], starts, False)
    grid_fit.grid_score = grid_fit.score
    return grid_fit if not polished else polish_candidate(problem, grid_fit)


def polish_candidate(problem: FitProblem, fit: CandidateFit) -> CandidateFit:
    """A grid fit polished (returns ``fit`` itself when it already is)."""
    if fit.polished:
        return fit
    params = [_polish_fold(problem, fit.effects, s, f) for f, s in enumerate(fit.starts)]
    polished = scored(problem, fit.effects, params, fit.starts, True)
    polished.grid_score = fit.grid_score
    return polished


def scored(problem: FitProblem, effects: tuple[str, ...], fold_params: list[EffectParams], starts: list,
            polished: bool) -> CandidateFit:
    """Held-out predictions (and the jitter's variance model) of per-fold parameters, and scores."""
    n_channels = len(problem.channels)
    oof = [np.full(problem.recording.n, np.nan) for _ in range(n_channels)]
    shapes: list[np.ndarray | None] = [None] * n_channels
    variance_coord = scatter_of(effects)  # a jitter, fitted from the scatter
    train_sse, train_n = 0.0, 0
    for f, params in enumerate(fold_params):
        preds = problem.predictions(params) if effects else problem.plain_predictions
        train0, test0 = problem.folds[f]
        if variance_coord is not None:
            # The jitter shows in the scatter: regress it, then refit the mean (which it smooths).
            for _ in range(JITTER_ITERATIONS if polished else 1):
                sens = scatter_sensitivity(problem, params, variance_coord.scatter)
                s0, j2 = fit_jitter(problem.y - preds[0], sens, train0)
                params = with_scatter(params, variance_coord.scatter, min(math.sqrt(j2), JITTER_MAX_S))
                if polished:
                    params = _polish_fold(problem, effects, [params], f)
                preds = problem.predictions(params)
            sens = scatter_sensitivity(problem, params, variance_coord.scatter)
            s0, j2 = fit_jitter(problem.y - preds[0], sens, train0)
            fold_params[f] = params = with_scatter(params, variance_coord.scatter, min(math.sqrt(j2), JITTER_MAX_S))
            shape = (s0 + j2 * sens**2) / s0
            if shapes[0] is None:
                shapes[0] = np.ones(problem.recording.n)
            shapes[0][test0] = shape[test0]
        for i, pred in enumerate(preds):
            test = problem.channel_folds[i][f][1]
            oof[i][test] = pred[test]
        train_sse += float(np.sum((preds[0] - problem.y)[train0] ** 2))
        train_n += int(train0.sum())
    err = oof[0] - problem.y
    held = problem.heldout
    fit = CandidateFit(effects, fold_params[0], _candidate_dof(effects), train_sse / max(train_n, 1),
                       float(np.sum(err[held] ** 2)) / max(int(held.sum()), 1), fold_params=fold_params, oof=oof,
                       shapes=shapes, polished=polished, starts=starts)
    fit.channel_mse = {c.name: _mse(oof[i], c.values, heldout_mask(problem, i))
                       for i, c in enumerate(problem.channels)}
    fit.raw_score = combined_score(problem, fit)
    fit.score = fit.raw_score * (1.0 + PENALTY_PER_PARAMETER * fit.dof)
    if effects:  # until refitted: the mean of the folds' estimates, without intervals
        per_fold = [public_estimates(problem, effects, p) for p in fold_params]
        for (e, k) in per_fold[0]:
            fit.estimates.setdefault(e, {})[k] = float(np.mean([pf[(e, k)] for pf in per_fold]))
    return fit
