"""How every pair of a population is made: one fixed recipe, and the seeds that make each pair its own draw.

A **recipe** is the demonstration data (who drives, which conditions, how many episodes) and the training of the
Base Model and of the TAPM on it (preset, samples, epochs, threads). Every pair of a population is made with the
same recipe; only its seeds differ. The shipped recipes are the commands recorded in
``plm_highway/checkpoints/manifest.json`` for the shipped pairs, so a population is "what the shipped pair would
have been under other seeds":

- ``paper`` (the ``paper`` conditions' pair): the human-like demonstrator at 30 Hz with the original camera,
  300 episodes of 8 s on the train track; BM on 10,000 samples for 4 epochs, TAPM on 40,000 for 5 epochs, 2
  torch threads.
- ``default`` (the ``ideal`` conditions' pair): the expert at 20 Hz with the default camera, 300 episodes of 8 s;
  BM and TAPM for up to 12 epochs on all samples, histogram-balanced at 2,000 per bin.

**Seeds.** Pair ``k`` draws its demonstrations with data seed ``1 + k`` and trains both its BM and its TAPM with
seed ``k``: pair 0 is the shipped pair's recipe and seeds. The rule is fixed before any run, so no pair is chosen
by its outcome.

Overrides (``--episodes``, ``--max-samples``, ``--epochs``) shrink a recipe for quick looks and tests; a
population made with any of them is labelled as not the recipe's.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

from plm_highway.errors import BadInput
from plm_highway.models.tapm import DEFAULT_DELTA_GRID_S


@dataclass(frozen=True)
class TrainingStep:
    """One model's training in a recipe (the fields of ``plm-highway train``)."""

    epochs: int
    max_samples: int | None = None
    balance_max_per_bin: int | None = 2000


@dataclass(frozen=True)
class Recipe:
    """Data and training of one pair; every pair of a population shares it (seeds aside)."""

    name: str
    conditions: str  # the closed-loop conditions the recipe's pairs are made for
    preset: str  # model input size preset
    track: str = "train"
    episodes: int = 300
    episode_seconds: float = 8.0
    bm: TrainingStep = TrainingStep(epochs=4)
    tapm: TrainingStep = TrainingStep(epochs=5)
    delta_grid_s: tuple[float, ...] = DEFAULT_DELTA_GRID_S
    threads: int = 2  # torch threads: training bytes depend on it, so it is part of the recipe
    overrides: dict = field(default_factory=dict)  # what a quick run changed (empty: the recipe as documented)

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> Recipe:
        fields = dict(data)
        fields["bm"] = TrainingStep(**fields["bm"])
        fields["tapm"] = TrainingStep(**fields["tapm"])
        fields["delta_grid_s"] = tuple(fields["delta_grid_s"])
        return cls(**fields)

    def collect_command(self, data_seed: int) -> str:
        return (f"plm-highway collect --conditions {self.conditions} --track {self.track} --out DATA "
                f"--episodes {self.episodes} --episode-seconds {self.episode_seconds:g} --seed {data_seed}")

    def train_command(self, model: str, seed: int) -> str:
        step = self.bm if model == "bm" else self.tapm
        parts = [f"plm-highway train {model} --data DATA --out {model.upper()}"]
        if model == "tapm":
            parts.append("--bm BM --delta-grid " + ",".join(f"{d:g}" for d in self.delta_grid_s))
        parts.append(f"--preset {self.preset} --epochs {step.epochs} --seed {seed}")
        if step.max_samples is not None:
            parts.append(f"--max-samples {step.max_samples}")
        parts.append(f"--balance-max-per-bin {step.balance_max_per_bin or 0} --threads {self.threads}")
        return " ".join(parts)


RECIPES = {
    "paper": Recipe("paper", conditions="paper", preset="paper", bm=TrainingStep(epochs=4, max_samples=10_000),
                    tapm=TrainingStep(epochs=5, max_samples=40_000)),
    "default": Recipe("default", conditions="ideal", preset="default", bm=TrainingStep(epochs=12),
                      tapm=TrainingStep(epochs=12)),
}
RECIPE_FOR_CONDITIONS = {"paper": "paper", "ideal": "default"}


@dataclass(frozen=True)
class PairSeeds:
    """The seeds of pair ``pair``: its demonstrations and its two trainings."""

    pair: int
    data_seed: int
    bm_seed: int
    tapm_seed: int

    @classmethod
    def of(cls, pair: int) -> PairSeeds:
        return cls(pair, data_seed=1 + pair, bm_seed=pair, tapm_seed=pair)


def recipe_named(name: str | None, conditions: str) -> Recipe:
    """The named recipe (None: the one the conditions' shipped pair was made with); it must suit the conditions."""
    name = name or RECIPE_FOR_CONDITIONS.get(conditions)
    if name not in RECIPES:
        raise BadInput(f"--recipe {name!r}: expected one of {list(RECIPES)}")
    recipe = RECIPES[name]
    if recipe.conditions != conditions:
        raise BadInput(f"--recipe {name}: its pairs are made for the {recipe.conditions!r} conditions, not "
                       f"{conditions!r} (their camera, loop rate and steering range differ)")
    return recipe


def with_overrides(recipe: Recipe, episodes: int | None = None, max_samples: int | None = None,
                   epochs: int | None = None) -> Recipe:
    """``recipe`` shrunk for a quick run (None keeps a field); what changed is recorded in ``overrides``."""
    overrides = {key: value for key, value in (("episodes", episodes), ("max_samples", max_samples),
                                               ("epochs", epochs)) if value is not None}
    if not overrides:
        return recipe
    bm, tapm = recipe.bm, recipe.tapm
    if max_samples is not None:
        bm, tapm = replace(bm, max_samples=max_samples), replace(tapm, max_samples=max_samples)
    if epochs is not None:
        bm, tapm = replace(bm, epochs=epochs), replace(tapm, epochs=epochs)
    return replace(recipe, episodes=episodes if episodes is not None else recipe.episodes, bm=bm, tapm=tapm,
                   overrides=overrides)
