"""The grid stage of a candidate fit: its nonlinear coordinates on the registry's grids, its linear
coordinates in closed form at every grid point, and the best points as starts for polishing.

A grid larger than ``MAX_GRID_POINTS`` is seeded with each effect's best single-effect grid points
(remembered in a :class:`FitCache` shared between candidates, with the grid statistics of every point
simulated so far: candidates' grids share many points, and a point's statistics depend on nothing else).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plm_highway.sim2real.fit.grid import profile_linear
from plm_highway.sim2real.fit.polish import Coordinate, coordinates
from plm_highway.sim2real.fit.problem import FitProblem
from plm_highway.sim2real.physics.effects import (
    SPECS,
    ChainParams,
    EffectParams,
    FitContext,
    chain_grid,
    coordinates_of,
    params_from,
)

MAX_GRID_POINTS = 1200
SEED_POINTS = 6
N_POLISH = 2


@dataclass
class FitCache:
    """Grid statistics shared between candidates, and each effect's best grid rows alone."""

    # {linear directions: {grid point (its CHAIN_DTYPE record's bytes): its rows of the grid statistics}}
    grams: dict = field(default_factory=dict)
    top_rows: dict[str, np.ndarray] = field(default_factory=dict)


def _effect_grid(effect: str, ctx: FitContext) -> np.ndarray:
    return SPECS[effect].grid(ctx)


def _candidate_grid(effects: tuple[str, ...], ctx: FitContext, cache: FitCache) -> list[np.ndarray]:
    """Grid rows per effect (nonlinear coordinates), combined as a product or, when too large,
    seeded: each effect's full grid against the others' best single-effect rows."""
    grids = {e: _effect_grid(e, ctx) for e in effects}
    nonlinear = [e for e in effects if grids[e].shape[1] > 0]
    size = int(np.prod([grids[e].shape[0] for e in nonlinear])) if nonlinear else 1
    if size <= MAX_GRID_POINTS or len(nonlinear) < 2 or any(e not in cache.top_rows for e in nonlinear):
        return [_product([grids[e] for e in effects])]
    blocks = []
    for e in nonlinear:
        axes = [grids[o] if o == e else (cache.top_rows[o] if o in nonlinear else grids[o]) for o in effects]
        blocks.append(_product(axes))
    return blocks


def _product(axes: list[np.ndarray]) -> np.ndarray:
    rows = [np.zeros(0)]
    for axis in axes:
        rows = [np.concatenate([r, a]) for r in rows for a in (axis if axis.shape[1] else np.zeros((1, 0)))]
    return np.array(rows)


def _chain_points(effects: tuple[str, ...], coords: list[Coordinate], rows: np.ndarray, ctx: FitContext
                  ) -> np.ndarray:
    """Grid rows (nonlinear coordinates; linear ones at their neutral values) as chain parameter sets."""
    nonlinear = [c for c in coords if not c.linear]
    chains = []
    for row in rows:
        values = {c.key: float(v) for c, v in zip(nonlinear, row)}
        values |= {c.key: c.neutral for c in coords if c.linear}
        chains.append(params_from(effects, values, ctx).chain())
    return chain_grid(chains)


def _linear_of(coords: list[Coordinate]) -> list[Coordinate]:
    """The coordinates solved in closed form on the grid."""
    return [c for c in coords if c.linear and not c.variance]


def _linear_bounds(linear: list[Coordinate]) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([c.move.bounds[0] for c in linear]), np.array([c.move.bounds[1] for c in linear]))


def _linear_values(points: np.ndarray, linear: list[Coordinate]) -> np.ndarray:
    """The chain parameters the linear coordinates set, per grid point: (G, L)."""
    if not linear:
        return np.zeros((len(points), 0))
    return np.column_stack([points[c.move.field] for c in linear])


def _polish_starts(sse: np.ndarray, rows: np.ndarray, scales: np.ndarray) -> list[int]:
    """The best grid point, plus up to ``N_POLISH - 1`` runners-up from other basins.

    A runner-up is polished only if its grid error is within 20% of the best and some nonlinear
    coordinate is more than one typical scale away from every start already taken.
    """
    order = np.argsort(sse)
    starts = [int(order[0])]
    for idx in order[1:]:
        if len(starts) >= N_POLISH or sse[idx] > 1.2 * sse[order[0]]:
            break
        if rows.shape[1] == 0:
            break
        far = all(np.any(np.abs(rows[idx] - rows[j]) > scales) for j in starts)
        if far:
            starts.append(int(idx))
    return starts


def fold_starts(problem: FitProblem, effects: tuple[str, ...], coords: list[Coordinate], blocks, grams,
                fold: int) -> list[EffectParams]:
    """The best grid points (linear terms profiled in closed form) on one fold's train blocks."""
    linear = _linear_of(coords)
    lo, hi = _linear_bounds(linear)
    parts = []
    for (rows, points), gram in zip(blocks, grams):
        sse, solved = profile_linear(gram[:, fold], lo, hi, _linear_values(points, linear))
        parts.append((sse, rows, points, solved))
    sse_all, rows_all, points_all, solved_all = (np.concatenate([p[i] for p in parts]) for i in range(4))
    scales = np.array([c.scale for c in coords if not c.linear])
    starts = []
    for idx in _polish_starts(sse_all, rows_all, scales):
        point = points_all[idx].copy()
        for j, c in enumerate(linear):
            point[c.move.field] = solved_all[idx, j]
        params = EffectParams.from_chain(ChainParams(*point.item()))
        starts.append(params_from(effects, coordinates_of(effects, params, problem.ctx), problem.ctx))
    return starts


def grid_blocks(problem: FitProblem, effects: tuple[str, ...], coords: list[Coordinate], cache: FitCache):
    directions = [c.direction for c in _linear_of(coords)]
    blocks, grams = [], []
    for rows in _candidate_grid(effects, problem.ctx, cache):
        points = _chain_points(effects, coords, rows, problem.ctx)
        blocks.append((rows, points))
        grams.append(_cached_grid_gram(problem, points, directions, cache))
    return blocks, grams


def _cached_grid_gram(problem: FitProblem, points: np.ndarray, directions: list, cache: FitCache) -> np.ndarray:
    """``problem.grid_gram(points, directions)``, simulating only the points no earlier grid of the cache had.

    A point's statistics are computed from that point alone (its own simulations, the problem's channel and fold
    weights, the directions' steps), never from the other points of its grid, so a row met before is the row a
    new simulation would give, to the bit.
    """
    known = cache.grams.setdefault(tuple(directions), {})
    keys = [points[g:g + 1].tobytes() for g in range(len(points))]
    first = {}
    for g, key in enumerate(keys):
        if key not in known:
            first.setdefault(key, g)
    if first:
        for key, row in zip(first, problem.grid_gram(points[list(first.values())], directions)):
            known[key] = row
    return np.stack([known[key] for key in keys])


def remember_top_rows(problem: FitProblem, effects: tuple[str, ...], coords: list[Coordinate], blocks, grams,
                      cache: FitCache) -> None:
    """A single effect's best grid rows (summed over folds): seeds for large pair grids."""
    own = [e for e in effects if e not in cache.top_rows and _effect_grid(e, problem.ctx).shape[1] > 0]
    if not own or len(blocks) != 1:
        return
    (rows, points), gram = blocks[0], grams[0]
    linear = _linear_of(coords)
    lo, hi = _linear_bounds(linear)
    base = _linear_values(points, linear)
    total = sum(profile_linear(gram[:, f], lo, hi, base)[0] for f in range(gram.shape[1]))
    order = np.argsort(total)
    column = 0
    for e in effects:
        width = _effect_grid(e, problem.ctx).shape[1]
        if e in own:
            chosen = []
            for idx in order:
                row = rows[idx, column:column + width]
                if not any(np.allclose(row, c) for c in chosen):
                    chosen.append(row)
                if len(chosen) >= SEED_POINTS:
                    break
            cache.top_rows[e] = np.array(chosen)
        column += width


def extended_starts(problem: FitProblem, effects: tuple[str, ...], fold_params: list[EffectParams], term: str
                    ) -> list[list[EffectParams]]:
    """Per fold, the best grid point of ``effects + (term,)`` with the fitted candidate ``effects`` held
    at its fold's nonlinear values: the term's grid only, every linear coordinate (the candidate's and
    the term's) solved in closed form. Residual discovery's grid stage."""
    ctx = problem.ctx
    extended = effects + (term,)
    coords = coordinates(extended, ctx)
    linear = _linear_of(coords)
    directions = [c.direction for c in linear]
    lo, hi = _linear_bounds(linear)
    term_nonlinear = [c for c in coords if c.effect == term and not c.linear]
    term_grid = _effect_grid(term, ctx)
    starts = []
    for fold, base in enumerate(fold_params):
        held = coordinates_of(effects, base, ctx)
        chains = []
        for row in term_grid:
            values = dict(held) | {c.key: c.neutral for c in linear}
            values |= {c.key: float(v) for c, v in zip(term_nonlinear, row)}
            values |= {c.key: 0.0 for c in coords if c.effect == term and c.variance}
            chains.append(params_from(extended, values, ctx).chain())
        points = chain_grid(chains)
        gram = problem.grid_gram(points, directions)
        sse, solved = profile_linear(gram[:, fold], lo, hi, _linear_values(points, linear))
        best = int(np.argmin(sse))
        point = points[best].copy()
        for j, c in enumerate(linear):
            point[c.move.field] = solved[best, j]
        params = EffectParams.from_chain(ChainParams(*point.item()))
        starts.append([params_from(extended, coordinates_of(extended, params, ctx), ctx)])
    return starts
