"""A population's plan: the recipe, every pair's seeds, and the closed-loop runs each pair is judged by.

The plan is written into the work directory before anything is trained or driven, so every seed is on record
before any result exists, and a resumed run can check that it continues the same population.

Closed-loop runs of one pair (its BM and its PLM-Net, loaded from the pair's own checkpoints), per simulator seed:
the reference (the BM without latency), then per latency setting the BM with that latency (``baseline``) and
PLM-Net with it (``mitigated``), as ``plm-highway reproduce`` plans them (under the legacy FIFO the BM baseline
of a time-varying setting runs at the constant latency the original's BM saw). PLM-Net also drives without
latency (``mitigated`` at ``const:0``): mitigation must do no harm when nothing is late.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from plm_highway.errors import BadInput
from plm_highway.population.recipe import PairSeeds, Recipe
from plm_highway.population.remedies import REMEDIES
from plm_highway.rollout.conditions import LATENCY_SOURCE_NAMES

# The paper's constant latencies and its stated time-varying profile, with 0 s for the no-harm check.
DEFAULT_SETTINGS = ("const:0", "const:0.15", "const:0.2", "const:0.25", "const:0.3", "steps:0.0-0.35:1.0")
DEFAULT_SIM_SEEDS = 5
MAX_PAIRS = 1000
PLAN_FORMAT = "plm_highway.population/1"


@dataclass(frozen=True)
class PopulationPlan:
    """Everything that defines a population's results (not how fast or where it runs)."""

    recipe: Recipe
    conditions: str
    track: str
    settings: tuple[str, ...]
    sim_seeds: tuple[int, ...]
    pairs: tuple[PairSeeds, ...]
    max_steps: int | None = None
    remedies: tuple[str, ...] = ()  # TAPM variants (plm_highway.population.remedies) tried on the same pairs
    # What PLM-Net is told of the latency (plm_highway.rollout.conditions.LATENCY_SOURCE_NAMES); "" is the conditions'
    # own source. Written only when set, so a plan without it reads and hashes as before.
    latency_source: str = ""

    def as_dict(self) -> dict:
        data = {"format": PLAN_FORMAT, "recipe": self.recipe.as_dict(), "conditions": self.conditions,
                "track": self.track, "settings": list(self.settings), "sim_seeds": list(self.sim_seeds),
                "pairs": [asdict(p) for p in self.pairs], "max_steps": self.max_steps,
                "remedies": list(self.remedies)}
        return {**data, "latency_source": self.latency_source} if self.latency_source else data

    @classmethod
    def from_dict(cls, data: dict) -> PopulationPlan:
        if data.get("format") != PLAN_FORMAT:
            raise BadInput(f"population plan: format {data.get('format')!r}, expected {PLAN_FORMAT!r}")
        return cls(Recipe.from_dict(data["recipe"]), data["conditions"], data["track"], tuple(data["settings"]),
                   tuple(data["sim_seeds"]), tuple(PairSeeds(**p) for p in data["pairs"]), data["max_steps"],
                   tuple(data.get("remedies", ())), data.get("latency_source", ""))

    @property
    def latency_settings(self) -> tuple[str, ...]:
        """The settings with latency (the ones a reduction is judged at)."""
        return tuple(s for s in self.settings if s != "const:0")


def make_plan(recipe: Recipe, conditions: str, pairs: int, track: str = "test",
              settings: tuple[str, ...] = DEFAULT_SETTINGS, sim_seeds: tuple[int, ...] | None = None,
              max_steps: int | None = None, remedies: tuple[str, ...] = (),
              latency_source: str | None = None) -> PopulationPlan:
    """The plan of ``pairs`` pairs (pair k seeded by :meth:`PairSeeds.of`), checked."""
    if latency_source is not None and latency_source not in LATENCY_SOURCE_NAMES:
        raise BadInput(f"--latency-source {latency_source!r}: expected one of {list(LATENCY_SOURCE_NAMES)}")

    unknown = [name for name in remedies if name not in REMEDIES]
    if unknown:
        raise BadInput(f"--remedy {unknown[0]!r}: expected one of {list(REMEDIES)}")
    if isinstance(pairs, bool) or not isinstance(pairs, int) or not 1 <= pairs <= MAX_PAIRS:
        raise BadInput(f"--pairs {pairs!r}: expected an integer in [1, {MAX_PAIRS}]")
    if "const:0" not in settings:
        raise BadInput("population settings: const:0 (the reference) must be among them")
    seeds = tuple(range(DEFAULT_SIM_SEEDS)) if sim_seeds is None else tuple(sim_seeds)
    return PopulationPlan(recipe, conditions, str(track), tuple(settings), seeds,
                          tuple(PairSeeds.of(k) for k in range(pairs)), max_steps, tuple(dict.fromkeys(remedies)),
                          latency_source or "")


def pair_name(pair: int) -> str:
    return f"pair-{pair:02d}"
