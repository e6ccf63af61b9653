"""The shipped `paper` checkpoints: the original's sizes, trained on the human-like demonstrator's train-track data."""

from __future__ import annotations

import json

import gymnasium
import numpy as np
import pytest
import torch

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.camera.pinhole import PAPER_CAMERA
from plm_highway.envs import ENV_ID
from plm_highway.models.base_model import count_parameters
from plm_highway.models.shipped import load_shipped_plm_net, shipped_checkpoint_dir, shipped_checkpoint_paths
from plm_highway.rollout.policies import checkpoint_pair


@pytest.fixture(scope="module")
def paper_net():
    return load_shipped_plm_net("paper")


def test_paper_checkpoints_have_the_papers_trainable_sizes(paper_net):
    assert count_parameters(paper_net.bm) == 5_800_550
    assert count_parameters(paper_net.tapm, trainable=True) == 6_250_205


def test_paper_checkpoints_were_trained_on_the_demonstrator_on_the_train_track_only():
    manifest = json.loads((shipped_checkpoint_dir() / "manifest.json").read_text())
    data = manifest["presets"]["paper"]["data"]
    assert data["track"] == "train" and data["demonstrator"] == "human" and data["conditions"] == "paper"
    for path in shipped_checkpoint_paths("paper"):
        description = json.loads(path.with_suffix(".json").read_text())
        assert description["preset"] == "paper" and description["image_size_px"] == [160, 160]


def test_paper_conditions_use_the_paper_pair_and_ideal_the_default_pair():
    assert checkpoint_pair(None, "paper") == shipped_checkpoint_paths("paper")
    assert checkpoint_pair(None) == shipped_checkpoint_paths("default")


def test_paper_bm_steers_into_a_curve_seen_by_the_paper_camera(paper_net):
    """On the train track's curves the BM's steering has the curve's sign (a model that learnt nothing fails)."""
    env = gymnasium.make(ENV_ID, config={"track": "train", "camera": PAPER_CAMERA, "policy_frequency": 30,
                                         "simulation_frequency": 30})
    env.reset(seed=0)
    track = env.unwrapped.track
    signs = []
    arc_m = 0.0
    for segment in track.segments:
        length_m = segment.length_m
        if segment.kind == "arc":
            obs, info = env.reset(options={"start_arc_length_m": arc_m + 0.5 * length_m})
            with torch.no_grad():
                steering = float(paper_net.bm(torch.from_numpy(np.array(obs)[None]), torch.tensor([16.7]))[0])
            signs.append(np.sign(steering) == np.sign(info["curvature_1pm"]))
        arc_m += length_m
    assert len(signs) >= 2 and all(signs)
