"""``processing_delay_steps``: the car receives each action that many policy steps late, holding the last one."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.envs import ENV_ID
from plm_highway.errors import BadInput


def commands_after(actions, delay_steps: int) -> list[float]:
    env = gymnasium.make(ENV_ID, config={"track": "test", "processing_delay_steps": delay_steps})
    env.reset(seed=0)
    received = []
    for action in actions:
        _, _, _, _, info = env.step(np.array([action], dtype=np.float32))
        received.append(info["steering_command"])
    return received


@pytest.mark.parametrize("delay_steps", [0, 1, 2])
def test_each_action_reaches_the_car_delay_steps_later(delay_steps):
    actions = [0.1, -0.2, 0.3, -0.4, 0.5, 0.05]
    received = commands_after(actions, delay_steps)
    expected = [0.0] * delay_steps + actions[:len(actions) - delay_steps]
    assert received == pytest.approx(expected, abs=1e-6)


def test_a_delay_is_reset_with_the_episode():
    env = gymnasium.make(ENV_ID, config={"track": "test", "processing_delay_steps": 2})
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.array([0.5], dtype=np.float32))
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.3], dtype=np.float32))
    assert info["steering_command"] == 0.0  # nothing from the last episode is still pending


@pytest.mark.parametrize("value", [-1, 11, 1.5, True, None])
def test_bad_delays_are_refused(value):
    with pytest.raises(BadInput, match="processing_delay_steps"):
        gymnasium.make(ENV_ID, config={"track": "test", "processing_delay_steps": value}).reset(seed=0)
