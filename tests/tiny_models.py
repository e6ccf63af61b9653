"""A tiny Base Model + TAPM trained in seconds, for tests that drive model policies.

The weights are meaningless (one epoch on 120 frames); the tests check behaviour, not driving
quality. Built once per test process and shared by every test module that asks for it.
"""

from __future__ import annotations

from pathlib import Path

_BUILT: dict[str, Path] = {}


def tiny_checkpoints(tmp_path_factory) -> Path:
    """A directory with ``bm/`` and ``tapm/`` (the layout ``--checkpoints`` takes)."""
    if "dir" in _BUILT:
        return _BUILT["dir"]
    from plm_highway.data.collect import collect
    from plm_highway.data.dataset import write_dataset
    from plm_highway.training.train import TrainConfig, train_base_model, train_tapm

    root = tmp_path_factory.mktemp("tiny_models")
    frames, steps, manifest = collect(track="train", episodes=3, episode_seconds=2, progress=False)
    write_dataset(root / "data", frames, steps, manifest)
    config = TrainConfig(epochs=1, balance_max_per_bin=None, augmentation=None, show_progress=False)
    train_base_model(root / "data", root / "ckpt" / "bm", config=config)
    train_tapm(root / "data", root / "ckpt" / "tapm", root / "ckpt" / "bm", config=config)
    _BUILT["dir"] = root / "ckpt"
    return _BUILT["dir"]


def other_tiny_checkpoints(tmp_path_factory) -> Path:
    """A second tiny pair from the same data and another training seed: other weights, same layout (what
    ``plm-highway train ... --overwrite`` into the same directory leaves)."""
    if "other" in _BUILT:
        return _BUILT["other"]
    from plm_highway.training.train import TrainConfig, train_base_model, train_tapm

    data = tiny_checkpoints(tmp_path_factory).parent / "data"
    root = tmp_path_factory.mktemp("tiny_models_other")
    config = TrainConfig(epochs=1, balance_max_per_bin=None, augmentation=None, show_progress=False, seed=1)
    train_base_model(data, root / "ckpt" / "bm", config=config)
    train_tapm(data, root / "ckpt" / "tapm", root / "ckpt" / "bm", config=config)
    _BUILT["other"] = root / "ckpt"
    return _BUILT["other"]
