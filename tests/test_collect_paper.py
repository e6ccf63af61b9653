"""``collect --conditions paper``: the human-like demonstrator drives, the original camera records, at 30 Hz."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import plm_highway  # noqa: F401  (registers the env)
from plm_highway import cli
from plm_highway.camera.pinhole import PAPER_CAMERA
from plm_highway.data.collect import DEMONSTRATOR_STREAM, collect
from plm_highway.data.dataset import read_dataset
from plm_highway.envs import ENV_ID
from plm_highway.expert import HumanDemonstrator, expert_steering
from plm_highway.expert.controller import ExpertParams
from plm_highway.rollout.conditions import CONDITIONS


@pytest.fixture(scope="module")
def paper_collected():
    return collect("train", episodes=2, episode_seconds=3.0, seed=4, conditions="paper", displaced_fraction=0.0,
                   progress=False)


def test_paper_recording_has_the_original_camera_loop_and_driver(paper_collected):
    frames, steps, manifest = paper_collected
    assert frames.shape == (2 * 90, 160, 160)  # 3 s at 30 Hz, two episodes
    assert np.allclose(np.diff(steps["t_s"][steps["episode_id"] == 0]), 1 / 30)
    assert manifest["policy_frequency"] == 30 and manifest["demonstrator"] == "human"
    assert manifest["conditions"] == "paper"
    assert manifest["steering_time_constant_s"] == CONDITIONS["paper"].steering_time_constant_s > 0
    assert manifest["max_steering_rad"] == CONDITIONS["paper"].max_steering_rad == 0.4
    assert {key: manifest["camera"][key] for key in PAPER_CAMERA} == PAPER_CAMERA
    assert manifest["collector"]["expert"]["reaction_delay_s"] > 0


def test_paper_labels_are_the_demonstrators_not_the_experts(paper_collected):
    _, steps, _ = paper_collected
    env = gymnasium.make(ENV_ID, config={"track": "train", "policy_frequency": 30, "simulation_frequency": 30,
                                         "steering_time_constant_s": CONDITIONS["paper"].steering_time_constant_s,
                                         "max_steering_rad": CONDITIONS["paper"].max_steering_rad})
    rows = np.flatnonzero(steps["episode_id"] == 0)
    # The same start: the collector's first episode starts where its first row is (centred, start drawn from seed 4).
    rng = np.random.default_rng(4)
    rng.random()
    env.reset(seed=4)
    usable_length_m = env.unwrapped.track.length_m - 16.7 * 3.0
    _, info = env.reset(seed=4, options={"start_arc_length_m": float(rng.uniform(0.0, usable_length_m))})
    driver = HumanDemonstrator(30, rng=np.random.default_rng([4, DEMONSTRATOR_STREAM]))
    driver.reset()  # the collector resets its driver at every episode start
    expert_gap = []
    for row in rows:
        assert (info["x_m"], info["y_m"]) == pytest.approx((steps["x_m"][row], steps["y_m"][row]), abs=1e-6)
        label = driver(None, info)
        assert steps["steering"][row] == pytest.approx(label, abs=1e-6)
        expert_gap.append(abs(label - expert_steering(info, ExpertParams(max_steering_rad=0.4))))
        _, _, _, _, info = env.step(np.array([steps["executed_steering"][row]], dtype=np.float32))
    assert np.mean(expert_gap) > 0.02  # the human is not the expert


def test_same_seed_same_recording_and_the_demonstrator_can_be_overridden(paper_collected):
    again = collect("train", episodes=2, episode_seconds=3.0, seed=4, conditions="paper", displaced_fraction=0.0,
                    progress=False)
    np.testing.assert_array_equal(again[1]["steering"], paper_collected[1]["steering"])
    np.testing.assert_array_equal(again[0], paper_collected[0])
    expert = collect("train", episodes=2, episode_seconds=3.0, seed=4, conditions="paper", displaced_fraction=0.0,
                     demonstrator="expert", progress=False)
    assert expert[2]["demonstrator"] == "expert" and expert[0].shape == paper_collected[0].shape
    assert not np.allclose(expert[1]["steering"], paper_collected[1]["steering"])


def test_ideal_conditions_record_as_before():
    frames, steps, manifest = collect("test", episodes=1, episode_seconds=1.0, seed=0, progress=False)
    assert frames.shape == (20, 66, 200) and manifest["demonstrator"] == "expert"
    assert manifest["policy_frequency"] == 20 and manifest["steering_time_constant_s"] == 0.0


def test_collect_command_line_paper_conditions(tmp_path, capsys):
    out = tmp_path / "ds"
    code = cli.main(["collect", "--conditions", "paper", "--track", "train", "--out", str(out), "--episodes", "1",
                     "--episode-seconds", "1", "--seed", "2"])
    assert code == 0, capsys.readouterr().err
    dataset = read_dataset(out)
    assert dataset.frames.shape == (30, 160, 160) and dataset.manifest["demonstrator"] == "human"


@pytest.mark.parametrize(("arguments", "message"), [(["--demonstrator", "robot"], "robot"),
                                                    (["--conditions", "lab"], "lab")])
def test_collect_refuses_unknown_conditions_and_demonstrators(tmp_path, capsys, arguments, message):
    code = cli.main(["collect", "--out", str(tmp_path / "ds"), "--episodes", "1", *arguments])
    assert code == cli.EXIT_BAD_INPUT
    assert message in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()
