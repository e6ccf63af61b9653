"""Residual discovery: what the library's best chain leaves, modelled by terms outside the library.

When the library's best chain leaves structure (verdict ``partly explained`` or ``unexplained``, or
a ``mismatch`` with over 2% of the error above the noise left), discovery tries interpretable terms
on top of it, each fitted inside the model on every recorded channel and judged on held-out data:

* the steering map and the gyro (:mod:`.terms`): dead band, backlash, end stops, left/right
  asymmetry, a speed-dependent steering ratio, a gyro bias. Grid over the term's own parameter with
  the chain held, every linear coordinate in closed form, then polished jointly with the chain
  (:func:`~plm_highway.sim2real.fit.gridfit.extended_starts`); held out on the library's blocks;
* a delay that varies in time (:mod:`.delay_track`), held out on interleaved gyro samples (a
  time-local track cannot predict other stretches; the gyro's noise is white from sample to sample),
  and named only if it beats a free-form smoother as flexible as itself;
* a road bank that varies along the track (:mod:`.track_bank`), held out on alternate visits to
  each place (laps): kept only when the error follows the track position rather than the time.

Forward selection: the term with the largest held-out gain enters when it is *clearly* better than
the model without it (the library's test: per-second t statistic at least 3, or a 95% block
bootstrap of the score ratio above 1), gains more than a tenth of the noise variance or of the
score, and removes at least a tenth of the held-out error left above the noise; then the next, up to
``MAX_TERMS``. Before it is named a term is checked for plausibility
(:mod:`.plausibility`): a doubtful one is reported with the reason, does not make the verdict
``discovered``, and the next-best term is tried in its place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from plm_highway.sim2real.fit.fitting import polish_candidate, scored
from plm_highway.sim2real.fit.gridfit import extended_starts
from plm_highway.sim2real.fit.plausibility import compensation_doubts, delay_doubts, size_doubts
from plm_highway.sim2real.fit.problem import CandidateFit, FitProblem
from plm_highway.sim2real.fit.scoring import clearly_better
from plm_highway.sim2real.fit.selection import NOISE_FRACTION, POLISH_WITHIN, Selection
from plm_highway.sim2real.fit.uncertainty import refit
from plm_highway.sim2real.physics.effects import SPECS
from plm_highway.sim2real.physics.terms import TERMS
from plm_highway.sim2real.record.consistency import Consistency
from plm_highway.sim2real.residual import delay_track, track_bank

MAX_TERMS = 2
# A term is the missing physics only if it removes at least this share of the held-out error left above
# the noise (a sliver of improvement is not an explanation).
MIN_REMOVED = 0.1
# A delay track must do better on held-out samples than a free-form smoother as flexible as itself.
SMOOTHER_SHARE = 1.0
# Discovery runs when the library's best chain leaves structure (these verdicts) or leaves more than
# 2% of the error above the noise unexplained (a mismatch whose variance model absorbs the rest).
RUNS_AFTER = ("partly explained", "unexplained")
RUNS_BELOW_EXPLAINED = 0.98


def should_run(verdict: str, explained_fraction: float) -> bool:
    return verdict in RUNS_AFTER or (verdict == "mismatch" and explained_fraction < RUNS_BELOW_EXPLAINED)


@dataclass
class Found:
    """A term that entered: in words and numbers, with what it gains on held-out data."""

    name: str
    sentence: str
    estimates: dict[str, float]
    ci95: dict[str, list[float]]
    validation: str  # how it was held out
    mse_before: float  # primary channel, held out, without the term
    mse_after: float
    removed_fraction: float  # of the held-out error above the noise the term removes
    t_statistic: float
    doubts: list[str] = field(default_factory=list)
    detail: dict = field(default_factory=dict)  # the models before and after it (params, track or field)

    @property
    def plausible(self) -> bool:
        return not self.doubts


@dataclass
class Tried:
    name: str
    score_ratio: float  # penalised held-out score with the term / without (below 1: better)
    entered: bool
    why: str


@dataclass
class Discovery:
    base: CandidateFit  # the library's best chain
    final: CandidateFit  # the base plus every registry term that entered (held-out predictions)
    noise_sigma: float
    found: list[Found] = field(default_factory=list)
    tried: list[Tried] = field(default_factory=list)
    not_tried: dict[str, str] = field(default_factory=dict)
    function_terms: list = field(default_factory=list)  # the delay track or bank field that entered

    @property
    def named(self) -> list[Found]:
        return [f for f in self.found if f.plausible]

    @property
    def doubtful(self) -> list[Found]:
        return [f for f in self.found if not f.plausible]


def removed_fraction(mse_before: float, mse_after: float, noise_sigma: float) -> float:
    """Share of the error above the noise that a change removes (held out; 0 when nothing is above it)."""
    excess = mse_before - noise_sigma**2
    return float(np.clip((mse_before - mse_after) / excess, -math.inf, 1.0)) if excess > 0 else 0.0


def removed_words(fraction: float, would: bool = False) -> str:
    """'removes 73%' (or 'would remove') or, for a change that makes it worse, 'adds 12%'."""
    verb = ("would remove" if would else "removes") if fraction >= 0 else ("would add" if would else "adds")
    return f"{verb} {100 * abs(fraction):.0f}%"


def _registry_option(problem: FitProblem, current: CandidateFit, term: str) -> CandidateFit:
    """``current`` plus a registry term, fitted on each fold (grid stage; polished later if promising)."""
    starts = extended_starts(problem, current.effects, current.fold_params, term)
    fit = scored(problem, current.effects + (term,), [s[0] for s in starts], starts, False)
    fit.grid_score = fit.score
    return fit


def _available_terms(problem: FitProblem, current: CandidateFit, not_tried: dict[str, str]) -> list[str]:
    names = {c.name for c in problem.channels}
    out = []
    for name, term in TERMS.items():
        if name in current.effects:
            continue
        if term.needs_channel and term.needs_channel not in names:
            not_tried[name] = f"no {term.needs_channel} channel in the fit"
            continue
        out.append(name)
    return out


@dataclass
class _Option:
    """A term tried on top of the current model, judged in its own held-out scheme."""

    name: str
    problem: FitProblem  # where it is held out
    before: CandidateFit
    after: CandidateFit
    validation: str
    model: object = None  # a delay track or a bank field

    @property
    def ratio(self) -> float:
        return self.after.score / self.before.score if self.before.score > 0 else math.inf


def _registry_options(problem: FitProblem, current: CandidateFit, not_tried: dict[str, str]) -> list[_Option]:
    fits = [_registry_option(problem, current, t) for t in _available_terms(problem, current, not_tried)]
    if not fits:
        return []
    best_grid = min(f.grid_score for f in fits)
    fits = [polish_candidate(problem, f) if f.grid_score <= POLISH_WITHIN * best_grid else f for f in fits]
    return [_Option(f.effects[-1], problem, current, f, "the library's alternating blocks (2-fold)") for f in fits]


def _function_options(problem: FitProblem, current: CandidateFit, selection: Selection,
                      not_tried: dict[str, str]) -> list[_Option]:
    options = []
    track = delay_track.compare(problem, current)
    if track is None:
        not_tried["delay_track"] = ("no yaw_rate channel in the fit (the track is judged on the gyro's "
                                    "interleaved samples)")
    else:
        interleaved, before, after, fitted = track
        options.append(_Option("delay_track", interleaved, before, after,
                               "interleaved gyro samples (every other sample fits, the others judge)", fitted))
    bank = track_bank.compare(problem, current, selection.ranking)
    if isinstance(bank, str):
        not_tried["bank_along_track"] = bank
    else:
        places, before, after, field_ = bank
        options.append(_Option("bank_along_track", places, before, after,
                               "alternate visits to each place (one half of the laps predicts the other)",
                               field_))
    return options


def discover(problem: FitProblem, selection: Selection, noise_sigma: float, rng: np.random.Generator,
             consistency: Consistency | None = None) -> Discovery:
    """Forward selection of terms outside the library on top of the library's best chain."""
    base = selection.winner
    current = base
    result = Discovery(base, base, noise_sigma)
    for _ in range(MAX_TERMS):
        options = (_registry_options(problem, current, result.not_tried)
                   + _function_options(problem, current, selection, result.not_tried))
        judged = []
        for option in sorted(options, key=lambda o: o.ratio):
            better, t_stat = clearly_better(option.problem, option.before, option.after, rng) \
                if option.ratio < 1 else (False, 0.0)
            mse_drop = option.before.heldout_mse - option.after.heldout_mse
            small = (mse_drop < NOISE_FRACTION * noise_sigma**2
                     and option.after.raw_score > (1 - NOISE_FRACTION) * option.before.raw_score)
            if not better:
                why = f"held-out score {100 * (option.ratio - 1):+.1f}%" + (
                    "" if option.ratio >= 1 else f", but not consistently (t = {t_stat:.1f})")
            elif small:  # the library's own rule: a tenth of the noise variance, or a tenth of the score
                why, better = "gains less than a tenth of the noise variance and of the score", False
            elif removed_fraction(option.before.heldout_mse, option.after.heldout_mse, noise_sigma) < MIN_REMOVED:
                share = removed_fraction(option.before.heldout_mse, option.after.heldout_mse, noise_sigma)
                effect = (f"removes only {100 * share:.0f}% of" if share >= 0
                          else f"adds {100 * -share:.0f}% to")
                why, better = (f"held-out score {100 * (option.ratio - 1):+.1f}% (t = {t_stat:.1f}), but it "
                               f"{effect} the primary channel's error left above the noise"), False
            else:
                why = f"held-out score {100 * (option.ratio - 1):+.1f}% (t = {t_stat:.1f})"
            judged.append((option, better, t_stat, why))
        # The best passing term enters if it is plausible; a doubtful one is reported and the next tried.
        entering = None
        for option, better, t_stat, why in judged:
            if entering is not None:
                why = f"{entering.name} entered first ({why})"
            elif better:
                found = _found(problem, option, t_stat, noise_sigma, consistency, rng)
                result.found.append(found)
                if found.plausible:
                    entering = option
                else:
                    why = f"{why}; doubtful: {'; '.join(found.doubts)}"
            result.tried.append(Tried(option.name, option.ratio, option is entering, why))
        if entering is None:
            break
        if entering.model is not None:  # a function-valued term ends the search
            result.function_terms.append(entering.model)
            break
        current = refit(problem, entering.after, rng)
        result.final = current
    return result


def _found(problem: FitProblem, option: _Option, t_stat: float, noise_sigma: float,
           consistency: Consistency | None, rng: np.random.Generator) -> Found:
    """The entering term in words and numbers, with its plausibility checked."""
    before, after = option.before, option.after
    common = dict(validation=option.validation, mse_before=before.heldout_mse, mse_after=after.heldout_mse,
                  removed_fraction=removed_fraction(before.heldout_mse, after.heldout_mse, noise_sigma),
                  t_statistic=t_stat)
    if option.name == "delay_track":
        estimates, ci, sentence = delay_track.describe(option.model, problem.recording.dt_s)
        found = Found(option.name, sentence, estimates, ci, **common)
        found.doubts = delay_doubts(estimates["delay_high_s"], "a delay", consistency)
        if after.heldout_mse > SMOOTHER_SHARE * option.model.smoother_mse:
            found.doubts.append(f"a free-form smoother as flexible explains as much (held-out RMSE "
                                f"{math.sqrt(option.model.smoother_mse):.4f} against the track's "
                                f"{math.sqrt(after.heldout_mse):.4f}): the error left is smooth, not a varying delay")
        found.detail = {"track": option.model, "before": before.params}
        return found
    if option.name == "bank_along_track":
        estimates, ci, sentence = track_bank.describe(option.model)
        found = Found(option.name, sentence, estimates, ci, **common)
        found.doubts = size_doubts(problem, option.name, estimates)
        found.detail = {"field": option.model, "before": before.params}
        return found
    fitted = refit(problem, after, rng)
    term = option.name
    found = Found(term, SPECS[term].sentence(fitted.estimates[term], fitted.ci95[term]), fitted.estimates[term],
                  fitted.ci95[term], **common)
    found.doubts = compensation_doubts(before, fitted) + size_doubts(problem, term, fitted.estimates[term])
    found.detail = {"params": fitted.params, "before": before.params}
    return found
