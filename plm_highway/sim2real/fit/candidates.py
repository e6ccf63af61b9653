"""The candidate space: which effects may be combined, and the candidates one step richer or simpler.

A candidate is a tuple of effect names in registry order (``effects.EFFECTS``); the plain model is
``()``. An effect that needs another group brings it (``road_bank`` needs tires: ``tire_slip``); at
most one effect of a group (``delay``, ``tires``) is in a candidate; an effect that needs a recorded
channel is tried only with it (a late gyro shows only against another channel).
"""

from __future__ import annotations

import itertools

from plm_highway.sim2real.physics.effects import EFFECTS
from plm_highway.sim2real.physics.replay import FitSignal


def expand(effects: tuple[str, ...]) -> tuple[str, ...]:
    """Add what effects need (road_bank -> tire_slip), in registry order."""
    chosen = set(effects)
    for name in effects:
        need = EFFECTS[name].needs_group
        if need and not any(EFFECTS[e].group == need for e in chosen):
            chosen.add(next(e for e in EFFECTS if EFFECTS[e].group == need))
    return tuple(e for e in EFFECTS if e in chosen)


def compatible(effects: tuple[str, ...]) -> bool:
    groups = [EFFECTS[e].group for e in effects if EFFECTS[e].group]
    return len(groups) == len(set(groups))


def available_effects(channels: list[FitSignal]) -> list[str]:
    names = {c.name for c in channels}
    out = []
    for name, effect in EFFECTS.items():
        if effect.needs_channel and (effect.needs_channel not in names or len(channels) < 2):
            continue  # a late gyro only shows against another channel
        out.append(name)
    return out


def singles(available: list[str]) -> list[tuple[str, ...]]:
    out = []
    for name in available:
        c = expand((name,))
        if c not in out:
            out.append(c)
    return out


def pairs_of(single_candidates: list[tuple[str, ...]], lead: int | None = None) -> list[tuple[str, ...]]:
    """Compatible pairs of the candidates; with ``lead``, only pairs containing one of the first
    ``lead`` candidates (forward selection from the best singles)."""
    out = []
    for i, j in itertools.combinations(range(len(single_candidates)), 2):
        if lead is not None and i >= lead:
            continue
        a, b = single_candidates[i], single_candidates[j]
        c = expand(tuple(set(a) | set(b)))
        if compatible(c) and c not in out and c not in single_candidates:
            out.append(c)
    return out


def all_candidates(available: list[str] | None = None) -> list[tuple[str, ...]]:
    """The plain model, each effect alone, and each compatible pair, in a fixed order."""
    s = singles(list(EFFECTS) if available is None else available)
    return [()] + s + pairs_of(s)


def with_refined(effects: tuple[str, ...]) -> set[str]:
    """The effects and the simpler effects they contain (delay_jitter contains transport_delay)."""
    return set(effects) | {EFFECTS[e].refines for e in effects if EFFECTS[e].refines}


def is_superset(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    return set(b) <= with_refined(a)


def simpler(effects: tuple[str, ...]) -> list[tuple[str, ...]]:
    """Candidates one step simpler: a term dropped, or a refinement replaced by its simpler effect."""
    out = [expand(tuple(e for e in effects if e != drop)) for drop in effects if len(effects) >= 2]
    for e in effects:
        if EFFECTS[e].refines:
            out.append(expand(tuple(EFFECTS[e].refines if x == e else x for x in effects)))
    return [c for c in dict.fromkeys(out) if c != effects]


def neighbours(effects: tuple[str, ...]) -> list[tuple[str, ...]]:
    """The candidate with one effect replaced by an effect that refines it."""
    out = []
    for e in effects:
        for other, spec in EFFECTS.items():
            if spec.refines == e:
                c = expand(tuple(other if x == e else x for x in effects))
                if compatible(c):
                    out.append(c)
    return out
