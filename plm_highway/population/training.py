"""Make one pair: collect its demonstrations, train its BM, then its TAPM on the frozen BM.

:func:`train_pair` runs wherever a backend puts it (this process, a pool worker, a Ray node): it works in a
private temporary directory and returns the checkpoints as bytes, so the parent process writes every file and a
cluster needs no shared filesystem. A training that fails is returned as a failure with its reason, never
raised into the population run: the pair is then reported as failed, not dropped.
"""

from __future__ import annotations

import os
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import torch

from plm_highway.data.collect import CollectConfig, collect
from plm_highway.data.dataset import write_dataset
from plm_highway.population.recipe import PairSeeds, Recipe
from plm_highway.population.timing import StageTimes
from plm_highway.training.train import TrainConfig, train_base_model, train_tapm

CHECKPOINT_FILES = ("model.pt", "model.json")


@dataclass(frozen=True)
class TrainTask:
    recipe: Recipe
    seeds: PairSeeds
    device: str = "cpu"  # where the models train (resolved in the worker: ``auto`` is its GPU where it has one)


@dataclass
class PairTraining:
    """What training one pair produced: the checkpoint files per model, or the failure."""

    pair: int
    ok: bool
    files: dict[str, dict[str, bytes]] = field(default_factory=dict)  # {"bm"|"tapm": {file name: bytes}}
    summary: dict = field(default_factory=dict)
    error: str = ""


def train_pair(task: TrainTask) -> PairTraining:
    """Collect and train pair ``task.seeds.pair`` with ``task.recipe``; never raises for a failed training."""
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    started = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory(prefix="plm-highway-pair-") as work:
            files, summary = _make_pair(task.recipe, task.seeds, Path(work), task.device)
    except KeyboardInterrupt:
        raise
    except Exception as exc:  # reported per pair: one failed training must not stop the others
        reason = f"{type(exc).__name__}: {exc}"
        return PairTraining(task.seeds.pair, False, summary={"seconds": time.perf_counter() - started},
                            error=reason + "\n" + traceback.format_exc(limit=8))
    summary["seconds"] = time.perf_counter() - started
    return PairTraining(task.seeds.pair, True, files, summary)


def _make_pair(recipe: Recipe, seeds: PairSeeds, work: Path, device: str = "cpu") -> tuple[dict, dict]:
    torch.set_num_threads(recipe.threads)
    times = StageTimes()
    data_dir, bm_dir, tapm_dir = work / "data", work / "bm", work / "tapm"
    config = CollectConfig(episodes=recipe.episodes, episode_seconds=recipe.episode_seconds,
                           conditions=recipe.conditions, seed=seeds.data_seed)
    with times.stage("collect"):
        frames, steps, manifest = collect(recipe.track, progress=False, config=config)
        manifest["command"] = recipe.collect_command(seeds.data_seed)
        write_dataset(data_dir, frames, steps, manifest)
        del frames
    descriptions = {}
    for model, step, seed in (("bm", recipe.bm, seeds.bm_seed), ("tapm", recipe.tapm, seeds.tapm_seed)):
        train_config = TrainConfig(epochs=step.epochs, seed=seed, max_samples=step.max_samples,
                                   balance_max_per_bin=step.balance_max_per_bin, show_progress=False)
        command = recipe.train_command(model, seed)
        with times.stage(f"{model}_training"):
            # Only the checkpoint files travel back (CHECKPOINT_FILES): the steering-balance figure is not drawn.
            if model == "bm":
                descriptions[model] = train_base_model(data_dir, bm_dir, recipe.preset, train_config, command,
                                                       device=device, balance_figure=False)
            else:
                descriptions[model] = train_tapm(data_dir, tapm_dir, bm_dir, train_config, recipe.delta_grid_s,
                                                 command, device=device, balance_figure=False)
    files = {model: {name: (directory / name).read_bytes() for name in CHECKPOINT_FILES}
             for model, directory in (("bm", bm_dir), ("tapm", tapm_dir))}
    summary = {"data_samples": int(len(steps["t_s"])), "threads": recipe.threads, "stages": times.as_dict(),
               **{f"{model}_{key}": descriptions[model]["training"][key]
                  for model in ("bm", "tapm") for key in ("best_val_loss", "best_epoch", "epochs_run", "rows_train",
                                                          "rows_val")}}
    return files, summary
