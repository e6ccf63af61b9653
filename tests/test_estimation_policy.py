"""The EKF lane-keeping policy on the kit's env, and the Table 3 / bench commands."""

from __future__ import annotations

import json

import gymnasium
import numpy as np
import pytest

import plm_highway  # noqa: F401  (registers the env)
from plm_highway.lane_ekf.policy import INFO_FRONT_WHEEL_ANGLE, INFO_YAW_RATE, EkfLaneKeepingPolicy, EkfPolicyConfig
from plm_highway.lane_ekf.sensors import ImuConfig, SteeringSensorConfig
from plm_highway.latency import LatencyWrapper


def _drive(policy, latency: str, max_steps: int | None = None):
    env = LatencyWrapper(gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": "test"}), latency)
    obs, info = env.reset(seed=0)
    policy.reset()
    offsets, estimated = [], []
    terminated = truncated = False
    while not (terminated or truncated) and (max_steps is None or len(offsets) < max_steps):
        action = policy(obs, info)
        assert -1.0 <= action <= 1.0
        obs, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        offsets.append(info["lateral_offset_m"])
        estimated.append(policy.estimator.state[0])
    env.close()
    return info, terminated, np.array(offsets), np.array(estimated)


@pytest.mark.slow
def test_ekf_policy_stays_on_the_road_with_a_quarter_second_latency():
    from plm_highway.road.track import resolve_track
    from plm_highway.rollout.conditions import CONDITIONS, scored_steps

    # The scored stretch: until the camera could first see the road's end (beyond it no lane is there to keep).
    policy = EkfLaneKeepingPolicy(EkfPolicyConfig(), seed=0)
    steps = scored_steps(resolve_track("test"), CONDITIONS["ideal"])
    info, terminated, offsets, estimated = _drive(policy, "const:0.25", max_steps=steps)
    assert not terminated and info["on_road"] and len(offsets) == steps
    assert np.abs(offsets).max() < 2.5  # never beyond the next lane's centre on 4 m lanes
    # Its estimate is of the present, not of the 0.25 s old frame.
    assert np.sqrt(np.mean((estimated - offsets) ** 2)) < 0.35
    assert policy.camera_updates > 0.9 * len(offsets)


def test_policy_reads_the_high_rate_sensors_from_info_when_present():
    quiet = EkfPolicyConfig(imu=ImuConfig(0.0, 0.0, 0.0, 0.0), steering_sensor=SteeringSensorConfig(0.0, 0.0, 0.0))
    policy = EkfLaneKeepingPolicy(quiet)
    env = gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": "test"})
    obs, info = env.reset(seed=0)
    info = dict(info, observation_age_s=0.0, **{INFO_YAW_RATE: 0.123, INFO_FRONT_WHEEL_ANGLE: -0.045,
                                                 "lateral_acceleration_mps2": 1.5})
    policy(obs, info)
    record = policy.estimator.history[-1]
    assert record.imu.tolist() == pytest.approx([1.5, 0.123])
    assert record.steer_rad == pytest.approx(-0.045)
    env.close()


def test_latency_bias_moves_the_capture_stamp():
    captures = {}
    for bias in (0.0, 0.1):
        policy = EkfLaneKeepingPolicy(EkfPolicyConfig(latency_bias_s=bias))
        _drive(policy, "const:0.2", max_steps=20)
        captures[bias] = policy._last_capture_s
    assert captures[0.0] - captures[0.1] == pytest.approx(0.1, abs=1e-9)
    with pytest.raises(ValueError, match="latency_bias_s"):
        EkfPolicyConfig(latency_bias_s=float("nan"))


@pytest.mark.slow
def test_table3_command_one_scenario_orders_the_variants(tmp_path):
    from plm_highway import cli

    out = tmp_path / "t3.json"
    assert cli.main(["estimate", "table3", "--seeds", "2", "--scenarios", "1", "--json", str(out),
                     "--out", str(tmp_path / "fig")]) == 0
    result = json.loads(out.read_text())
    assert result["command"] == "plm-highway estimate table3 --seeds 2 --scenarios 1"
    by_measurement = {}
    for measurement in ("clean", "realistic"):
        (scenario,) = result["measurements"][measurement]["scenarios"]
        ours = by_measurement[measurement] = scenario["ours"]
        for state in ("d", "dpsi", "vn"):
            assert ours["ekf_dc"][state]["rmse"]["mean"] < ours["camera"][state]["rmse"]["mean"]
            assert ours["ekf_dc"][state]["rmse"]["mean"] < ours["ekf"][state]["rmse"]["mean"]
        assert scenario["paper"]["ekf_dc"]["d"]["rmse"] == 0.055
        assert (tmp_path / "fig" / f"scenario1_sine_straight{'' if measurement == 'clean' else '_realistic'}.png"
                ).stat().st_size > 10_000
    # The detector's own error makes the measurement worse, and the compensated estimate with it; the delay-alone
    # row (a perfect measurement) is the same sensor data in both.
    for state in ("d", "dpsi"):
        assert (by_measurement["realistic"]["ekf_dc"][state]["rmse"]["mean"]
                > 1.5 * by_measurement["clean"]["ekf_dc"][state]["rmse"]["mean"])
        assert by_measurement["realistic"]["camera_lag"] == by_measurement["clean"]["camera_lag"]
    ratio = result["rmse_over_paper"]["camera"]["clean"]["1"]["d"]
    assert ratio == pytest.approx(by_measurement["clean"]["camera"]["d"]["rmse"]["mean"] / 0.201)
    assert json.loads((tmp_path / "fig" / "table3.json").read_text())["measurements"] == result["measurements"]
    text = (tmp_path / "fig" / "table3.md").read_text()
    assert "### Scenario 1" in text and "## Realistic lane measurement" in text and "Command: `plm-highway" in text
    # a second run refuses to replace its own output unless told to
    assert cli.main(["estimate", "table3", "--seeds", "1", "--scenarios", "1", "--json", str(out)]) == 2
    assert cli.main(["estimate", "table3", "--seeds", "1", "--measurements", "noisy"]) == 2


def test_table3_refuses_bad_seed_counts_and_scenarios():
    from plm_highway.lane_ekf.table3 import scenarios_by_number, table3

    with pytest.raises(ValueError, match="seeds"):
        table3(0, progress=False)
    with pytest.raises(ValueError, match="unknown"):
        scenarios_by_number("1,7")
    assert [s.number for s in scenarios_by_number("4, 2")] == [4, 2]
