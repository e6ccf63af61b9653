"""Camera lane measurement from rendered frames, sensors and the simulated scenarios."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plm_highway.camera.ground_map import ground_map
from plm_highway.camera.pinhole import PinholeCamera
from plm_highway.lane_ekf.lane_camera import LaneDetector, LaneDetectorConfig
from plm_highway.lane_ekf.scenarios import SCENARIOS, lane_coordinates, simulate_truth
from plm_highway.lane_ekf.sensors import CameraTiming, ImuConfig
from plm_highway.lane_ekf.table3 import TABLE3_CAMERA
from plm_highway.latency.profiles import parse_camera_delay
from plm_highway.road.geometry import reference_pose_at
from plm_highway.road.track import parse_track


def _track(radius_m):
    segments = ([{"type": "straight", "length_m": 300}] if radius_m is None
                else [{"type": "arc", "radius_m": radius_m, "angle_deg": 90, "direction": "left"}])
    return parse_track({"name": f"lane-test-{radius_m}", "lanes": 3, "lane_width_m": 3.5, "segments": segments})


def _pose(track, s_m, d_m, dpsi_rad):
    x, y, heading = reference_pose_at(track, s_m)
    return x - d_m * math.sin(heading), y + d_m * math.cos(heading), heading + dpsi_rad


@pytest.mark.parametrize("radius_m", [None, 150.0, 100.0])
def test_lane_measurement_from_the_image_matches_the_pose(radius_m):
    track = _track(radius_m)
    camera = PinholeCamera(ground_map(track, 10.0), TABLE3_CAMERA)
    detector = LaneDetector(TABLE3_CAMERA, LaneDetectorConfig(lane_width_m=3.5))
    rng = np.random.default_rng(11)
    errors = []
    for s_m in np.linspace(12, 110, 25):
        d_m, dpsi = rng.uniform(-1.2, 1.2), rng.uniform(-0.08, 0.08)
        frame = camera.render(*_pose(track, s_m, d_m, dpsi))
        frame = np.clip(frame + rng.normal(0, 6, frame.shape), 0, 255).astype(np.uint8)
        measurement = detector.measure(frame)
        assert measurement is not None
        kappa = 0.0 if radius_m is None else 1.0 / radius_m
        errors.append([measurement.offset_m - d_m, measurement.heading_rad - dpsi, measurement.curvature_1pm - kappa])
    rmse = np.sqrt(np.mean(np.square(errors), axis=0))
    assert rmse[0] < 0.05 and rmse[1] < math.radians(0.5) and rmse[2] < 0.002


def test_lane_tracking_keeps_the_offset_continuous_through_a_lane_change():
    track = _track(None)
    camera = PinholeCamera(ground_map(track, 10.0), TABLE3_CAMERA)
    detector = LaneDetector(TABLE3_CAMERA, LaneDetectorConfig(lane_width_m=3.5))
    previous = None
    for d_m in np.linspace(0.0, 3.5, 15):  # into the next lane to the left
        previous = detector.measure(camera.render(*_pose(track, 40.0, d_m, 0.02)), previous)
    assert previous.offset_m == pytest.approx(3.5, abs=0.1)
    # Without the track, the lane the car is in is taken: the same frame reads about 0.
    assert detector.measure(camera.render(*_pose(track, 40.0, 3.5, 0.02))).offset_m == pytest.approx(0.0, abs=0.1)


def test_no_markings_no_measurement_and_wrong_frames_refused():
    detector = LaneDetector(TABLE3_CAMERA)
    blank = np.full((TABLE3_CAMERA.height_px, TABLE3_CAMERA.width_px), 60, np.uint8)
    assert detector.measure(blank) is None
    with pytest.raises(ValueError, match="shape"):
        detector.measure(np.zeros((10, 10), np.uint8))


def test_camera_schedule_one_worker_in_capture_order():
    rng = np.random.default_rng(0)
    schedule = CameraTiming("const:0.3", frame_rate_hz=25).schedule(5.0, 0.01, rng)
    captures, arrivals = np.array(schedule).T
    np.testing.assert_allclose(arrivals - captures, 0.3, atol=1e-9)
    assert np.all(np.diff(captures) >= 0.3 - 1e-9)  # the worker is busy until the result is out
    assert np.all(np.diff(arrivals) > 0)
    per_frame = np.array(CameraTiming("frame:0.25-0.35").schedule(20.0, 0.01, rng))
    delays = per_frame[:, 1] - per_frame[:, 0]
    assert delays.min() >= 0.25 - 1e-9 and delays.max() <= 0.36 and delays.std() > 0.01


@pytest.mark.parametrize("spec", ["const:-0.1", "frame:0.3-0.2", "frame:abc", "const:9"])
def test_bad_camera_delays_are_refused(spec):
    with pytest.raises(ValueError):
        parse_camera_delay(spec)


def test_imu_noise_and_bias():
    imu = ImuConfig(yaw_rate_noise_std_radps=0.01, yaw_rate_bias_radps=0.003,
                    lateral_acceleration_noise_std_mps2=0.2, lateral_acceleration_bias_mps2=-0.1)
    rng = np.random.default_rng(5)
    samples = np.array([imu.measure(0.1, 1.0, rng) for _ in range(20000)])
    assert samples[:, 0].mean() == pytest.approx(0.9, abs=0.01)
    assert samples[:, 1].mean() == pytest.approx(0.103, abs=0.0005)
    np.testing.assert_allclose(samples.std(axis=0), [0.2, 0.01], rtol=0.05)
    with pytest.raises(ValueError):
        ImuConfig(yaw_rate_noise_std_radps=-1.0)


def test_lane_coordinates_on_an_arc():
    track = _track(150.0)
    x, y, heading = _pose(track, 50.0, 0.7, -0.03)
    s_m, d_m, dpsi, kappa = lane_coordinates(track, x, y, heading)
    assert (s_m, d_m, dpsi, kappa) == pytest.approx((50.0, 0.7, -0.03, 1 / 150.0), abs=1e-9)


def test_scenarios_drive_the_manoeuvre():
    sine = simulate_truth(SCENARIOS[0], np.random.default_rng(0))
    dlc = simulate_truth(SCENARIOS[3], np.random.default_rng(0))
    assert 0.8 < np.abs(sine.d_m).max() < 1.5  # 1 m weave
    assert 2.7 < dlc.d_m.max() < 3.4  # 3 m double lane change, back in the lane at the end
    assert abs(dlc.d_m[-1]) < 0.2 and dlc.kappa_1pm[0] == pytest.approx(0.01)
    # The IMU's lateral acceleration is v' + u r: on a steady curve it is u^2 kappa.
    assert dlc.ay_mps2[0] == pytest.approx(dlc.speed_mps ** 2 * 0.01, rel=0.02)
