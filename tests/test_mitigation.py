"""Plug-in mitigations around the frozen BM: dead reckoning, the present view, what they read, how they are wired."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from plm_highway.camera.pinhole import PAPER_CAMERA, CameraConfig, pose_matrix
from plm_highway.envs import ENV_ID
from plm_highway.errors import BadInput
from plm_highway.lane_ekf.lane_camera import LaneMeasurement
from plm_highway.mitigation import MITIGATIONS, make_mitigation
from plm_highway.mitigation.odometry import MotionHistory, MotionSample, relative_pose
from plm_highway.mitigation.plugins import CONTROL_TIME_KEYS, lane_change
from plm_highway.mitigation.view import present_view

speeds = st.floats(1.0, 40.0)
yaw_rates = st.floats(-0.5, 0.5)


@given(speed_mps=speeds, yaw_rate_radps=yaw_rates, duration_s=st.floats(0.01, 1.0), step_s=st.sampled_from([0.01, 0.05, 1 / 30]))
def test_a_steady_turn_gives_the_arc_whatever_the_sampling(speed_mps, yaw_rate_radps, duration_s, step_s):
    samples = [MotionSample(k * step_s, speed_mps, yaw_rate_radps) for k in range(int(duration_s / step_s) + 2)]
    forward_m, left_m, yaw_rad = relative_pose(samples, 0.0, duration_s)
    turn = yaw_rate_radps * duration_s
    if abs(yaw_rate_radps) > 1e-9:
        radius_m = speed_mps / yaw_rate_radps
        # 1 - cos(turn) as 2 sin^2(turn / 2): the difference loses every digit for a turn of 1e-8 rad
        expected = (radius_m * math.sin(turn), radius_m * 2 * math.sin(turn / 2) ** 2)
    else:
        expected = (speed_mps * duration_s, 0.0)
    assert yaw_rad == pytest.approx(turn, abs=1e-12)
    assert forward_m == pytest.approx(expected[0], abs=1e-9)
    assert left_m == pytest.approx(expected[1], abs=1e-9)


@given(since_s=st.floats(0.0, 2.0), speed_mps=speeds, yaw_rate_radps=yaw_rates)
def test_no_time_no_motion_and_the_history_forgets_only_what_it_no_longer_needs(since_s, speed_mps, yaw_rate_radps):
    history = MotionHistory(horizon_s=0.5)
    for k in range(100):
        history.add(MotionSample(k * 0.05, speed_mps, yaw_rate_radps))
    now_s = 99 * 0.05
    assert history.pose_since(now_s) == (0.0, 0.0, 0.0)
    assert history.samples[0].time_s <= now_s - 0.5 + 1e-9  # a look back of the horizon is still covered
    look_back_s = min(since_s, 0.5)
    assert history.pose_since(now_s - look_back_s)[2] == pytest.approx(yaw_rate_radps * look_back_s, abs=1e-12)


def test_samples_must_move_forward_in_time():
    history = MotionHistory()
    history.add(MotionSample(1.0, 10.0, 0.0))
    with pytest.raises(ValueError, match="not after"):
        history.add(MotionSample(1.0, 10.0, 0.0))


@pytest.mark.parametrize("camera_dict", [{}, PAPER_CAMERA], ids=["kit camera", "paper camera"])
def test_the_present_view_is_the_frame_the_camera_sees_from_the_new_pose(camera_dict):
    """On the kit's flat ground the re-projected late frame equals the frame rendered at the new pose, but for the
    strip beyond the late frame's range (haze in the late frame, road now): far closer than the late frame itself."""
    env = gymnasium.make(ENV_ID, config={"track": "test", "camera": camera_dict})
    try:
        _, info = env.reset(seed=0)
        camera = env.unwrapped._episode.camera
        x_m, y_m, heading_rad = info["x_m"], info["y_m"], info["heading_rad"]
        config = CameraConfig.from_dict(camera_dict)
        late = np.array(camera.render(x_m, y_m, heading_rad))
        for pose in [(5.0, 0.3, 0.02), (6.0, -0.5, -0.03)]:
            x_new, y_new, _ = pose_matrix(x_m, y_m, heading_rad) @ np.array([pose[0], pose[1], 1.0])
            now = np.array(camera.render(x_new, y_new, heading_rad + pose[2])).astype(int)
            view_error = np.abs(present_view(late, config, pose).astype(int) - now)
            late_error = np.abs(late.astype(int) - now)
            assert np.median(view_error) <= 1.0  # the bulk matches to a grey level (bilinear resampling)
            assert view_error.mean() < 0.35 * late_error.mean()
        assert present_view(late, config, (0.0, 0.0, 0.0)) is late
    finally:
        env.close()


def test_the_present_view_refuses_a_frame_of_another_camera():
    with pytest.raises(ValueError, match="the camera gives uint8"):
        present_view(np.zeros((10, 10), np.uint8), CameraConfig(), (1.0, 0.0, 0.0))


@given(offset_m=st.floats(-1.5, 1.5), forward_m=st.floats(0.0, 10.0), left_m=st.floats(-1.0, 1.0),
       yaw_rad=st.floats(-0.1, 0.1))
def test_on_a_straight_lane_along_the_car_the_lane_change_is_the_motion(offset_m, forward_m, left_m, yaw_rad):
    lane = LaneMeasurement(offset_m, 0.0, 0.0, 4.0, 10)
    assert lane_change(lane, (forward_m, left_m, yaw_rad)) == pytest.approx((left_m, yaw_rad), abs=1e-12)


def test_a_car_heading_into_a_bend_sees_the_heading_error_the_bend_turns_away():
    # heading error h, straight on for s metres: offset grows by s sin h; a left bend of curvature k takes k s of it
    lane = LaneMeasurement(0.0, 0.02, 0.01, 4.0, 10)
    offset_change_m, heading_change_rad = lane_change(lane, (8.0, 0.0, 0.0))
    assert heading_change_rad == pytest.approx(-0.01 * 8.0 * math.cos(0.02), rel=1e-9)
    assert offset_change_m == pytest.approx(8.0 * math.sin(0.02) - 0.5 * 0.01 * (8.0 * math.cos(0.02)) ** 2,
                                            rel=1e-9)


class ControlTimeInfo(dict):
    """An info dict that refuses every key a car does not have at control time."""

    def __init__(self, info: dict, allowed: frozenset):
        super().__init__(info)
        self.allowed = allowed

    def __getitem__(self, key):
        if key not in self.allowed:
            raise AssertionError(f"the mitigation read {key!r}, which a car does not have at control time")
        return super().__getitem__(key)

    def get(self, key, default=None):
        return self[key] if key in self else default


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["bm-warp", "bm-smith"])
def test_a_mitigation_never_reads_the_true_state(policy):
    """Driven through the latency wrapper with every privileged key of info refused: the policy reads only the time,
    the frame's measured age, the speed and the yaw rate."""
    from plm_highway.latency import LatencyWrapper
    from plm_highway.rollout.policies import make_policy

    steer = make_policy(policy, seed=3)
    env = LatencyWrapper(gymnasium.make(ENV_ID, config={"track": "test"}), "const:0.25")
    try:
        frame, info = env.reset(seed=0)
        steer.reset()
        allowed = CONTROL_TIME_KEYS | {"observation_age_s"}
        for _ in range(30):
            action = steer(frame, ControlTimeInfo(info, allowed))
            frame, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
            assert not (terminated or truncated)
    finally:
        env.close()


def test_every_mitigation_is_named_and_an_unknown_one_refused():
    assert set(MITIGATIONS) == {"warp", "smith"}
    with pytest.raises(ValueError, match="expected one of"):
        make_mitigation("crystal-ball")
    with pytest.raises(ValueError, match="needs the model policy"):
        make_mitigation("smith")


def test_a_checkpoint_of_another_pair_is_refused_by_name(tmp_path):
    from plm_highway.population.mitigations import checked_checkpoints

    for model in ("bm", "tapm"):
        (tmp_path / model).mkdir()
        (tmp_path / model / "model.pt").write_bytes(model.encode())
    record = {"pair": 4, "checkpoints": {"bm/model.pt": "0" * 64, "tapm/model.pt": "1" * 64}}
    with pytest.raises(BadInput, match=r"bm/model.pt, tapm/model.pt are not the weights pair 4 was made with"):
        checked_checkpoints(tmp_path, record, tmp_path / "pair-04.json")
    (tmp_path / "tapm" / "model.pt").unlink()
    with pytest.raises(BadInput, match=r"tapm/model.pt: missing; pair 4's checkpoints"):
        checked_checkpoints(tmp_path, record, tmp_path / "pair-04.json")


def test_a_checkpoint_of_the_wrong_preset_is_refused_by_name(tmp_path):
    import shutil

    from plm_highway.models.shipped import shipped_checkpoint_dir
    from plm_highway.rollout.conditions import CONDITIONS
    from plm_highway.rollout.policies import make_policy

    for model in ("bm", "tapm"):  # the shipped default pair, in the layout 'plm-highway train' writes
        (tmp_path / model).mkdir()
        for suffix in (".pt", ".json"):
            shutil.copy(shipped_checkpoint_dir() / f"{model}_default{suffix}", tmp_path / model / f"model{suffix}")
    with pytest.raises(BadInput, match="are preset 'default'.*need preset 'paper'"):
        make_policy("bm-warp", tmp_path, preset="paper", conditions=CONDITIONS["paper"])
