"""What an entry of the registry of physical terms is: its parameters, and what a recording tells
the registry about their ranges.

The library of effects (:mod:`.effects`) and the terms residual discovery tries (:mod:`.terms`) are
both written as :class:`Effect` entries, so that one fitting machinery (grid, closed-form linear
coordinates, least-squares polish, intervals) serves both.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from plm_highway.sim2real.physics.chain import TIRE_MIN_SPEED_MPS

# An EffectParams record: built from the registry's chain fields in :mod:`.effects`, which imports this module.
Params = Any

# Quantiles of |steering command| a FitContext carries (the steering map's grids are set from them).
STEER_QUANTILES = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99)


@dataclass(frozen=True)
class FitContext:
    """What a recording tells the library about ranges: its car and how it was driven."""

    a_m: float
    b_m: float
    k2_m2: float
    dt_s: float
    mass_kg: float | None = None
    inertia_known: bool = False
    u_min_mps: float = TIRE_MIN_SPEED_MPS
    steer_rate_median_radps: float = 0.05  # of the commanded front-wheel angle, moving samples
    steer_rate_max_radps: float = 0.5  # its 99.5th percentile
    max_lat_accel_mps2: float = 4.0  # 99.5th percentile of |lateral acceleration|
    steer_quantiles_rad: tuple[float, ...] = ()  # |command| at STEER_QUANTILES, moving samples
    speed_median_mps: float = 0.0  # of the moving samples

    def steer_quantile(self, q: float) -> float:
        """|command| at quantile ``q`` (one of STEER_QUANTILES); 0.05 rad when not measured."""
        if not self.steer_quantiles_rad:
            return 0.05
        return float(self.steer_quantiles_rad[STEER_QUANTILES.index(q)])


@dataclass(frozen=True)
class ChainField:
    """A named value of a parameter record, at its neutral value (the plain simulator; None: absent).

    The chain's fields are the kernels' parameters (:class:`~.effects.ChainParams`, and
    :class:`~.effects.EffectParams` for everything else); the concealed fields are make-recording's
    (``synth.ConcealedEffects``). ``absent_unless``: in EffectParams the field is None unless that
    chain field is positive (the kernels take 0.0). ``gyro_only``: it acts on the recorded gyro
    channel only, after the chain (the chain's simulation does not read it).
    """

    name: str
    neutral: float | None
    absent_unless: str | None = None
    gyro_only: bool = False


@dataclass(frozen=True)
class ChainMove:
    """How a linear coordinate moves the chain: the chain field it sets, the finite-difference step
    there (the grid's sensitivities) and its bounds there (where the closed-form solution is clipped)."""

    field: str
    step: float
    bounds: tuple[float, float]


@dataclass(frozen=True)
class Scatter:
    """How a variance coordinate acts on the chain: it is the standard deviation of a random variation
    of chain field ``of`` and is held in chain field ``field``. The residual's variance grows by its
    square times the square of the signal's sensitivity to ``of`` (so the fit needs only the names)."""

    field: str
    of: str


@dataclass(frozen=True)
class Parameter:
    """A fitted coordinate of an effect. ``linear``: enters the signal linearly (or nearly), solved in
    closed form at every grid point (by ``move``, unless it is a variance parameter, one with a
    ``scatter``: it shapes the error variance, is fitted from the scatter, not by least squares, and is
    reported under its own name); otherwise tried on the effect's grid, then polished. ``neutral``: the
    value that leaves the chain as the simulator."""

    name: str
    unit: str
    bounds: tuple[float, float] | Callable[[FitContext], tuple[float, float]]
    scale: float  # typical size: finite-difference steps and the optimiser's variable scaling
    linear: bool = False
    grid: tuple[float, ...] | Callable[[FitContext], np.ndarray] = ()
    move: ChainMove | None = None  # a linear mean coordinate's move of the chain
    neutral: float = 0.0
    scatter: Scatter | None = None  # a variance coordinate's action on the chain

    @property
    def variance(self) -> bool:
        return self.scatter is not None

    def bounds_for(self, ctx: FitContext) -> tuple[float, float]:
        return self.bounds(ctx) if callable(self.bounds) else self.bounds

    def grid_for(self, ctx: FitContext) -> np.ndarray:
        return np.asarray(self.grid(ctx) if callable(self.grid) else self.grid, float)


@dataclass(frozen=True)
class Effect:
    name: str
    term: str  # the term added to the simulator's model
    parameters: tuple[Parameter, ...]  # fitted coordinates
    public_keys: tuple[str, ...]  # reported names (fixed: other tools read them)
    fingerprint: str
    concealed: str  # how make-recording conceals it
    synth_defaults: dict[str, float]  # make-recording's parameters (public names, first = NAME=VALUE)
    synth_bounds: dict[str, tuple[float, float]]
    conceal: dict[str, ChainField]  # make-recording parameter -> field of synth.ConcealedEffects it sets
    chain_fields: tuple[ChainField, ...]  # the chain fields set_params sets (the records are built from them)
    set_params: Callable[[dict, FitContext], dict]  # fitted coordinates -> EffectParams fields
    read_params: Callable[[Params, FitContext], dict]  # EffectParams -> fitted coordinates
    report: Callable[[Params, FitContext], dict]  # EffectParams -> public names
    sentence: Callable[[dict, dict], str]  # (public estimates, their 95% intervals) -> words
    group: str | None = None  # at most one effect of a group in a candidate
    needs_group: str | None = None  # the group must be present; if not, this effect is added
    needs_channel: str | None = None  # a recorded channel without which the effect is not tried
    varies_noise: bool = False  # shapes the error variance (scored by likelihood)
    refines: str | None = None  # an effect this one contains as a special case (its simpler version)
    separated_from: dict[str, str] = field(default_factory=dict)  # other effect -> the drive that tells them apart
    joint_grid: Callable[[FitContext], np.ndarray] | None = None  # (G, p) grid when parameters are coupled
    # The benchmark's tolerance per public parameter: |estimate - truth| <= max(absolute, relative x |truth|).
    tolerances: dict[str, tuple[float, float]] = field(default_factory=dict)
    # (public estimates, context) -> why a size no working car has makes the estimate doubtful ([] when none).
    doubts: Callable[[dict, FitContext], list[str]] | None = None

    @property
    def dof(self) -> int:
        return len(self.parameters)

    @property
    def primary_synth_key(self) -> str:
        return next(iter(self.synth_defaults))

    def grid(self, ctx: FitContext) -> np.ndarray:
        """Grid points of the nonlinear coordinates, shape (G, number of nonlinear parameters)."""
        if self.joint_grid is not None:
            return self.joint_grid(ctx)
        axes = [p.grid_for(ctx) for p in self.parameters if not p.linear]
        if not axes:
            return np.zeros((1, 0))
        mesh = np.meshgrid(*axes, indexing="ij")
        return np.column_stack([m.ravel() for m in mesh])


def pm(ci: list[float]) -> float:
    return 0.5 * (ci[1] - ci[0])
