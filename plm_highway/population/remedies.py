"""Remedies for the drift that stay within the PLM-Net design: other TAPMs for the same pairs' BMs.

A remedy keeps each pair's BM and the TAPM's architecture, recipe and seed, and changes only what the TAPM learns
from. It is tried on the same population: every pair gets a remedy TAPM, PLM-Net with it drives every latency
setting and simulator seed, and the report compares it with the pair's own PLM-Net, pair by pair.

- ``onpolicy-tapm``: the TAPM's data gains the states a late PLM-Net visits (:mod:`plm_highway.data.onpolicy`):
  the pair's own PLM-Net drives the train track seeing the camera late (each latency of the TAPM's grid in turn),
  and the human-like demonstrator, watching the true state, labels each frame. The demonstrations of ``collect``
  only show a car corrected at once; these show how the car moves while its steering answers old frames, which
  is the loop a deployed PLM-Net is in. The TAPM is then trained, as the recipe says, on both recordings together.
"""

from __future__ import annotations

import os
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import torch

from plm_highway.data.collect import CollectConfig, collect
from plm_highway.data.dataset import write_dataset
from plm_highway.data.onpolicy import OnPolicyConfig, collect_on_policy, concatenate
from plm_highway.models.checkpoints import load_plm_net
from plm_highway.models.inference import PLMNetPolicy
from plm_highway.population.recipe import PairSeeds, Recipe
from plm_highway.population.training import CHECKPOINT_FILES, PairTraining
from plm_highway.training.train import TrainConfig, train_tapm

ON_POLICY_SHARE = 3  # one on-policy episode per three demonstration episodes (100 for the recipe's 300)
REMEDIES = {"onpolicy-tapm": "TAPM also trained on the states a late PLM-Net visits, labelled by the demonstrator"}


@dataclass(frozen=True)
class RemedyTask:
    remedy: str
    recipe: Recipe
    seeds: PairSeeds
    files: dict  # the pair's {"bm"|"tapm": {file name: bytes}}
    device: str = "cpu"  # where the remedy's TAPM trains


def train_remedy(task: RemedyTask) -> PairTraining:
    """The remedy TAPM of one pair (``files["tapm"]`` of the result); never raises for a failed training."""
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    started = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory(prefix="plm-highway-remedy-") as work:
            files, summary = _onpolicy_tapm(task, Path(work))
    except KeyboardInterrupt:
        raise
    except Exception as exc:  # reported per pair, as a failed training is
        return PairTraining(task.seeds.pair, False, summary={"seconds": time.perf_counter() - started},
                            error=f"{type(exc).__name__}: {exc}\n" + traceback.format_exc(limit=8))
    summary["seconds"] = time.perf_counter() - started
    return PairTraining(task.seeds.pair, True, files, summary)


def _onpolicy_tapm(task: RemedyTask, work: Path) -> tuple[dict, dict]:
    recipe, seeds = task.recipe, task.seeds
    torch.set_num_threads(recipe.threads)
    for model, files in task.files.items():
        (work / model).mkdir()
        for name, data in files.items():
            (work / model / name).write_bytes(data)
    frames, steps, manifest = collect(recipe.track, progress=False, config=CollectConfig(
        episodes=recipe.episodes, episode_seconds=recipe.episode_seconds, conditions=recipe.conditions,
        seed=seeds.data_seed))
    # oneDNN's own kernels: about twice as fast one frame at a time; data need no batch invariance
    policy = PLMNetPolicy(load_plm_net(work / "bm", work / "tapm"), batch_invariant=False)
    torch.set_num_threads(1)  # one frame at a time: a second thread only hands off
    on_frames, on_steps, on_manifest = collect_on_policy(policy, recipe.conditions, recipe.track, OnPolicyConfig(
        episodes=max(1, recipe.episodes // ON_POLICY_SHARE), episode_seconds=recipe.episode_seconds, latencies_s=recipe.delta_grid_s,
        seed=seeds.data_seed))
    torch.set_num_threads(recipe.threads)
    all_frames, all_steps = concatenate([(frames, steps), (on_frames, on_steps)])
    del frames, on_frames
    manifest["remedy"] = {"name": task.remedy, "on_policy": on_manifest["collector"],
                          "rows_demonstrations": int(len(steps["t_s"])), "rows_on_policy": int(len(on_steps["t_s"]))}
    write_dataset(work / "data", all_frames, all_steps, manifest)
    del all_frames
    config = TrainConfig(epochs=recipe.tapm.epochs, seed=seeds.tapm_seed, max_samples=recipe.tapm.max_samples,
                         balance_max_per_bin=recipe.tapm.balance_max_per_bin, show_progress=False)
    description = train_tapm(work / "data", work / "remedy", work / "bm", config, recipe.delta_grid_s,
                             f"{recipe.train_command('tapm', seeds.tapm_seed)} (remedy {task.remedy})",
                             device=task.device, balance_figure=False)  # only CHECKPOINT_FILES travel back
    files = {"tapm": {name: (work / "remedy" / name).read_bytes() for name in CHECKPOINT_FILES}}
    training = description["training"]
    summary = {"rows_demonstrations": manifest["remedy"]["rows_demonstrations"],
               "rows_on_policy": manifest["remedy"]["rows_on_policy"],
               **{f"tapm_{key}": training[key] for key in ("best_val_loss", "best_epoch", "epochs_run", "rows_train",
                                                           "rows_val")}}
    return files, summary
