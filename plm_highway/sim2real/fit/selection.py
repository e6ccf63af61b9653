"""Which effect (or pair of effects) explains the mismatch: fit each inside the model, judge held out.

1. **Split** the recording into alternating blocks in time and use them for 2-fold
   cross-validation: fit on the even blocks and predict the odd ones, then the other way round.
   Every usable sample gets an out-of-fold prediction, both folds see every kind of driving, and no
   fit is scored on samples it saw. (``split="halves"``: fit on the first half, score the second.)
2. **Candidates**: the plain model, every effect of the registry alone (``effects.EFFECTS``; an
   effect that needs tires brings ``tire_slip``, one that needs a recorded channel is tried only
   with it), then pairs by forward selection: each of the best ``LEAD_SINGLES`` singles with every
   single that beats the plain model, and every pair among the best ``TOP_SINGLES``; then, around
   the best ``NEIGHBOURHOOD`` candidates, each effect swapped for its refinement or its simpler
   version (``tire_slip`` <-> ``tire_saturation``, ``transport_delay`` <-> ``delay_jitter``).
3. **Fit** each candidate on each fold's train blocks. Its nonlinear parameters (delays, time
   constant, tires, rate limit, friction) go on the registry's grids, simulated as one parallel
   batch on the primary channel that serves both folds; its linear parameters (gain, offset, bank)
   are solved in closed form at every grid point. A grid larger than ``MAX_GRID_POINTS`` is seeded
   with each effect's best single-effect grid points. The best grid points are then polished with
   ``scipy.optimize.least_squares`` (trust-region reflective, bounded) on **all recorded
   channels** (yaw rate, heading rate, lateral velocity from positions), each weighted by the
   inverse of the plain model's mean-square error on it, so that each channel counts as much as
   the others whatever its unit. Fitting the effect *inside* the model is what keeps a tire-slip
   recording (an apparent ~0.1 s lag to input-output cross-correlation) from being called a
   transport delay: a delay shifts the yaw rate, tire slip also scales it with speed.
4. **Judge** on held-out samples: per channel the mean-square error (for an effect that shapes the
   error variance, ``delay_jitter``, its Gaussian likelihood written as an equivalent mean-square
   error), combined as the geometric mean over channels (the determinant criterion of system
   identification: a change counts by its ratio on every channel), times ``1 + 0.01 p`` for ``p``
   fitted parameters. A pair must also be *clearly* better than its simpler version (step 5's
   test), or the simpler one is kept.
5. **Decide**: a mismatch needs the winner to beat the plain model clearly, either consistently
   across held-out stretches (t statistic of the per-second log ratio of the two scores above 3) or
   in total (95% block-bootstrap interval of the score ratio above 1: effects that show only in
   some manoeuvres), and by more than a tenth of the primary channel's noise variance.

The winner and the runner-up are refitted on all usable samples; 95% intervals from the
least-squares Jacobian with the residual variance inflated for autocorrelation (AR(1) effective
sample size), derived quantities by the delta method; the jitter from a block bootstrap of its
variance regression.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from plm_highway.sim2real.fit.candidates import (
    available_effects,
    is_superset,
    neighbours,
    pairs_of,
    simpler,
    singles,
    with_refined,
)
from plm_highway.sim2real.fit.fitting import fit_candidate, polish_candidate
from plm_highway.sim2real.fit.gridfit import FitCache
from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem
from plm_highway.sim2real.fit.scoring import T_STAT_THRESHOLD, bootstrap_ratio, clearly_better
from plm_highway.sim2real.fit.uncertainty import refit

NOISE_FRACTION = 0.1  # the improvement must exceed this fraction of the noise variance
TOP_SINGLES = 4
LEAD_SINGLES = 2
NEIGHBOURHOOD = 3
RUNNER_UP_CONTENDERS = 3
# Grid fits scoring within this factor of the best are polished (a finer delay or stiffness than
# the grid's moves a score by a few per cent, well under this).
POLISH_WITHIN = 1.3


def _leads_first(ranked: list[tuple[str, ...]]) -> list[tuple[str, ...]]:
    """The ranked singles with the best ``LEAD_SINGLES`` of *different* physics first: a single that
    shares an effect with a better one, or refines it (tire_saturation and tire_slip), is a variant
    of the same explanation, not a second one."""
    leads: list[tuple[str, ...]] = []
    for c in ranked:
        if len(leads) < LEAD_SINGLES and not any(with_refined(c) & with_refined(lead) for lead in leads):
            leads.append(c)
    return leads + [c for c in ranked if c not in leads]


def _polish_promising(problem: FitProblem, fits: list[CandidateFit]) -> list[CandidateFit]:
    """Polish every grid fit whose grid-level score is within ``POLISH_WITHIN`` of the best grid-level
    score: the others cannot win (polishing gains about as much for every candidate near the right
    physics) and keep their grid estimates."""
    best = min(f.grid_score for f in fits)
    todo = [i for i, f in enumerate(fits) if f.grid_score <= POLISH_WITHIN * best and not f.polished]
    out = list(fits)
    # The simulations and the optimiser's linear algebra release the GIL: polish on all cores.
    with ThreadPoolExecutor(max(1, min(os.cpu_count() or 1, len(todo)))) as pool:
        for i, fit in zip(todo, pool.map(lambda i: polish_candidate(problem, fits[i]), todo)):
            out[i] = fit
    return out


def fit_candidates(problem: FitProblem, candidates: list[tuple[str, ...]] | None = None) -> list[CandidateFit]:
    """The plain model, every single effect, then pairs of the singles that beat the plain model
    (or exactly ``candidates``, all polished)."""
    cache = FitCache()
    if candidates is not None:
        ordered = sorted(candidates, key=len)  # singles first: they seed pair grids
        return [fit_candidate(problem, c, cache) for c in ordered]
    available = available_effects(problem.channels)
    plain = fit_candidate(problem, (), cache)
    fits = _polish_promising(problem, [plain] + [fit_candidate(problem, c, cache, polished=False)
                                                  for c in singles(available)])
    helpful = [f.effects for f in sorted(fits[1:], key=lambda f: f.score) if f.score < plain.score]
    # Forward selection: the best singles with every helpful single, and the best few among themselves
    # (effects that explain the same thing crowd the top; a second, different effect ranks lower).
    chosen = pairs_of(_leads_first(helpful), lead=LEAD_SINGLES) + pairs_of(helpful[:TOP_SINGLES])
    if helpful:
        # Forward selection's second step proper: the best single with every other effect, helpful alone
        # or not. An effect can hide behind a larger one: a 15% steering gain beside a steering offset does
        # not beat the plain model on its own, yet the pair explains everything.
        chosen += pairs_of([helpful[0]] + [c for c in singles(available) if c != helpful[0]], lead=1)
    pairs = [fit_candidate(problem, c, cache, polished=False) for c in dict.fromkeys(chosen)
             if all(f.effects != c for f in fits)]
    fits = _polish_promising(problem, fits + pairs)
    # Around the best few: each effect swapped for its refinement or its simpler version
    # (tire_slip <-> tire_saturation, transport_delay <-> delay_jitter), and every simpler
    # candidate polished, so that the final choice compares like with like.
    for _ in range(2):
        top = sorted(fits, key=lambda f: f.score)[:NEIGHBOURHOOD]
        wanted = [c for f in top for c in neighbours(f.effects)] + simpler(top[0].effects)
        known = {f.effects: i for i, f in enumerate(fits)}
        new = [fit_candidate(problem, c, cache) for c in dict.fromkeys(wanted) if c not in known]
        fits = [polish_candidate(problem, f) if f.effects in wanted else f for f in fits] + new
        if not new:
            break
    return fits


@dataclass
class Selection:
    verdict: str  # "match" or "mismatch" (diagnose refines it)
    winner: CandidateFit  # the chosen model (the plain model when no candidate is chosen)
    best: CandidateFit  # the best-scoring candidate (may be non-plain even on a "match")
    runner_up: CandidateFit
    plain: CandidateFit
    t_statistic: float
    margin: float  # runner-up score / winner score - 1 (negative: the runner-up scores better)
    ranking: list[CandidateFit]
    reason: str
    margin_ci: tuple[float, float] = (math.nan, math.nan)  # 95% block bootstrap of the margin
    skipped: list[str] = field(default_factory=list)


def _simplest_sufficient(problem: FitProblem, best: CandidateFit, fits: list[CandidateFit],
                         rng: np.random.Generator) -> CandidateFit:
    """Drop a term (or a refinement) while the richer candidate is not clearly better than the
    simpler one. The penalty is small so that a real second effect is not missed; this test keeps
    a term that only fits noise out."""
    by_effects = {f.effects: f for f in fits}
    while best.effects:
        subsets = [by_effects[c] for c in simpler(best.effects) if c in by_effects]
        if not subsets:
            break
        simpler_fit = min(subsets, key=lambda f: f.score)
        if clearly_better(problem, simpler_fit, best, rng)[0]:
            break
        best = simpler_fit
    return best


def select(problem: FitProblem, fits: list[CandidateFit], noise_sigma: float,
           rng: np.random.Generator | None = None) -> Selection:
    rng = np.random.default_rng(0) if rng is None else rng
    ranking = sorted(fits, key=lambda f: f.score)
    plain = next(f for f in fits if not f.effects)
    best = _simplest_sufficient(problem, ranking[0], fits, rng)
    better, t_stat = clearly_better(problem, plain, best, rng) if best.effects else (False, 0.0)
    improvement = plain.heldout_mse - best.heldout_mse
    if not best.effects:
        verdict, reason = "match", "no candidate beats the plain model on held-out data after the complexity penalty"
    elif not better:
        verdict, reason = "match", (f"the best candidate ({best.name}) improves held-out error inconsistently "
                                    f"(t = {t_stat:.1f} < {T_STAT_THRESHOLD:g}, and its total gain is within the "
                                    "bootstrap spread)")
    elif improvement < NOISE_FRACTION * noise_sigma**2 and best.raw_score > (1 - NOISE_FRACTION) * plain.raw_score:
        verdict, reason = "match", (f"the best candidate ({best.name}) improves held-out mean-square error by "
                                    f"less than {NOISE_FRACTION:g} of the noise variance")
    else:
        verdict, reason = "mismatch", (f"{best.name} beats the plain model on held-out data "
                                       f"(t = {t_stat:.1f}, {100 * (1 - best.raw_score / plain.raw_score):.0f}% "
                                       "lower combined mean-square error)")
    winner = best if verdict == "mismatch" else plain
    # The runner-up is the best *alternative* explanation: neither the winner plus a term (a superset
    # fits at least as well, by construction) nor, when there is another, the winner minus one.
    others = [f for f in ranking if f.effects and f is not winner and not is_superset(f.effects, winner.effects)
              and not is_superset(winner.effects, f.effects)]
    others = others or [f for f in ranking if f.effects and f is not winner
                        and not is_superset(f.effects, winner.effects)]
    if not others:
        others = [f for f in ranking if f.effects and f is not winner] or [plain]
    # Compare polished with polished: a screened-out grid fit's score is pessimistic.
    contenders = [polish_candidate(problem, f) for f in others[:RUNNER_UP_CONTENDERS]]
    runner_up = min(contenders, key=lambda f: f.score)
    ranking = sorted([f for f in ranking if f not in others[:RUNNER_UP_CONTENDERS]] + contenders,
                     key=lambda f: f.score)
    for f in {id(winner): winner, id(runner_up): runner_up, id(best): best}.values():
        refit(problem, f, rng)
    margin = runner_up.score / winner.score - 1.0 if winner.score > 0 else math.inf
    ratio, lo, hi = bootstrap_ratio(problem, winner, runner_up, rng)
    return Selection(verdict, winner, best, runner_up, plain, t_stat, margin, ranking, reason,
                     margin_ci=(lo - 1.0, hi - 1.0))
