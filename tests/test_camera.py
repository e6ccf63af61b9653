"""The dashcam: frames look like a road, and they move the right way when the car moves.

Expected image positions are derived here from the pinhole model by hand: a ground point ``d``
metres ahead of the camera (horizontally) and ``l`` metres to its left, seen from a camera ``h``
metres up and pitched down by ``theta``, lands at depth ``z = d cos(theta) + h sin(theta)``, column
``u = cx - f l / z`` and row ``v = cy + f (h cos(theta) - d sin(theta)) / z``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from plm_highway.camera.ground_map import (
    ASPHALT_GRAY,
    DEFAULT_MAP_PX_PER_M,
    FRAME_TOLERANCE_MEAN_GRAY,
    FRAME_TOLERANCE_WORST_FRAME_GRAY,
    MARKING_GRAY,
    OFFROAD_GRAY,
    GroundMap,
    ground_map,
)
from plm_highway.camera.pinhole import HORIZON_GRAY, CameraConfig, PinholeCamera, pose_matrix
from plm_highway.camera.topdown import TopDownView
from plm_highway.road.geometry import reference_pose_at
from plm_highway.road.track import load_track, parse_track

CONFIG = CameraConfig()  # 66 x 200, fov 70, 1.6 m high, 6 deg down, 1 m ahead of the car, 60 m range
F_PX = 100.0 / math.tan(math.radians(35.0))
CX, CY = 99.5, 32.5
THETA = math.radians(6.0)
LOWER_HALF = slice(33, 66)


def track(lanes: int, segments: list[dict], name: str):
    return parse_track({"name": name, "lanes": lanes, "lane_width_m": 4.0, "segments": segments})


STRAIGHT_3 = track(3, [{"type": "straight", "length_m": 300}], "cam_straight_3")
STRAIGHT_1 = track(1, [{"type": "straight", "length_m": 300}], "cam_straight_1")


def curve(direction: str):
    return track(1, [{"type": "straight", "length_m": 30},
                     {"type": "arc", "radius_m": 40, "angle_deg": 90, "direction": direction}], f"cam_{direction}")


@pytest.fixture(scope="module")
def camera3() -> PinholeCamera:
    return PinholeCamera(ground_map(STRAIGHT_3))


@pytest.fixture(scope="module")
def camera1() -> PinholeCamera:
    return PinholeCamera(ground_map(STRAIGHT_1))


def ground_distance_m(v: float) -> float:
    """Horizontal distance from the camera to the ground seen at row ``v`` (hand-derived)."""
    a = (v - CY) / F_PX
    return 1.6 * (math.cos(THETA) - a * math.sin(THETA)) / (a * math.cos(THETA) + math.sin(THETA))


def column_of_line(v: float, line_y_m: float, x_m: float, y_m: float, heading_rad: float) -> float:
    """Column where the world line ``y = line_y_m`` appears at row ``v`` from a car pose."""
    d = ground_distance_m(v)
    cam_y = y_m + 1.0 * math.sin(heading_rad)  # the camera sits 1 m ahead of the car's reference point
    # A point d ahead and l left of the camera lies at world y = cam_y + d sin(psi) + l cos(psi).
    left = (line_y_m - cam_y - d * math.sin(heading_rad)) / math.cos(heading_rad)
    z = d * math.cos(THETA) + 1.6 * math.sin(THETA)
    return CX - F_PX * left / z


def bright_centroid(frame: np.ndarray, rows=LOWER_HALF) -> float:
    _, cols = np.nonzero(frame[rows] > 200)
    assert len(cols) > 20, "no markings visible"
    return float(cols.mean())


def haze_rows() -> np.ndarray:
    """Rows that see no ground within 60 m: above the horizon, or ground beyond the range."""
    rows = []
    for v in range(CONFIG.height_px):
        depression = THETA + math.atan((v - CY) / F_PX)
        rows.append(depression <= 0 or 1.6 / math.tan(depression) + 1.0 > 60.0)
    return np.array(rows)


# -- what a frame looks like -----------------------------------------------------------------------


def test_focal_length_matches_the_field_of_view():
    assert CONFIG.focal_px == pytest.approx(F_PX)


def test_frame_is_a_road_not_a_blank(camera3):
    frame = camera3.render(50.0, 0.0, 0.0)
    assert frame.shape == (66, 200) and frame.dtype == np.uint8
    ground = frame[~haze_rows()]
    assert ground.std() > 15
    assert (ground > 200).sum() > 50  # painted markings
    assert (ground < 80).sum() > 0.3 * ground.size  # mostly dark asphalt in front of the car
    # The bottom centre (just ahead of the bonnet, mid-lane) is asphalt.
    assert abs(int(frame[60:66, 90:110].mean()) - ASPHALT_GRAY) < 15


def test_horizon_rows_are_haze(camera3):
    frame = camera3.render(50.0, 0.0, 0.0)
    haze = haze_rows()
    # Horizon at cy - f tan(6 deg) = 17.5; 60 m of range ends near row 21.4.
    assert np.flatnonzero(haze).max() == 21 and haze[:22].all()
    assert np.all(frame[haze] == HORIZON_GRAY)
    assert not np.all(frame[22] == HORIZON_GRAY)
    assert not np.any(np.all(frame[~haze] == HORIZON_GRAY, axis=1))


def test_ground_map_colours_by_hand_positions():
    gmap = ground_map(STRAIGHT_3)

    def gray(x_m, y_m):
        col, row = gmap.to_pixels(np.array(x_m), np.array(y_m))
        return int(gmap.image[int(np.rint(row)), int(np.rint(col))])

    assert gray(100.0, 6.0) == MARKING_GRAY  # left road edge, solid
    assert gray(100.0, -6.0) == MARKING_GRAY  # right road edge
    assert gray(1.5, 2.0) == MARKING_GRAY  # dashed line, painted for s in [0, 3) of every 9 m
    assert abs(gray(6.0, 2.0) - ASPHALT_GRAY) < 40  # ... and a gap at s = 6
    assert abs(gray(100.0, 4.0) - ASPHALT_GRAY) < 40  # lane 0 centre
    assert abs(gray(100.0, 20.0) - OFFROAD_GRAY) < 40  # the verge, 14 m beyond the edge
    # The affine matrix and to_pixels agree, with y up in the world and rows down in the image.
    col, row, _ = gmap.world_to_pixel @ np.array([10.0, 5.0, 1.0])
    assert (col, row) == pytest.approx(tuple(gmap.to_pixels(np.array(10.0), np.array(5.0))))
    _, row_north, _ = gmap.world_to_pixel @ np.array([10.0, 6.0, 1.0])
    assert row_north < row


def test_solid_road_edges_appear_where_the_pinhole_model_says(camera3):
    for pose in [(50.0, 0.0, 0.0), (50.0, 0.0, math.radians(5)), (50.0, 1.0, 0.0), (50.0, -0.5, math.radians(-3))]:
        frame = camera3.render(*pose)
        checked = 0
        for v in range(23, 66, 3):
            for line_y in (6.0, -6.0):
                u = column_of_line(v, line_y, *pose)
                if not 3 <= u <= 196:
                    continue
                window = frame[v, int(np.rint(u)) - 2:int(np.rint(u)) + 3]
                assert window.max() > 180, (pose, v, line_y, u, frame[v, int(u) - 6:int(u) + 7])
                checked += 1
        assert checked >= 10


# -- motion ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("degrees", [5.0, -5.0])
def test_markings_shift_the_right_way_when_the_car_turns(camera1, degrees):
    straight = bright_centroid(camera1.render(50.0, 0.0, 0.0))
    turned = bright_centroid(camera1.render(50.0, 0.0, math.radians(degrees)))
    # Turning LEFT (positive heading) swings the road to the RIGHT of the image, and vice versa.
    assert straight == pytest.approx(CX, abs=2.0)  # centred: both edges 2 m either side
    assert math.copysign(1.0, degrees) * (turned - straight) > 8.0


@pytest.mark.parametrize("offset_m", [1.0, -1.0])
def test_markings_shift_the_right_way_when_the_car_moves_sideways(camera1, offset_m):
    centred = bright_centroid(camera1.render(50.0, 0.0, 0.0))
    shifted = bright_centroid(camera1.render(50.0, offset_m, 0.0))
    # The car 1 m LEFT (north) of the lane centre sees the lane to its RIGHT.
    assert math.copysign(1.0, offset_m) * (shifted - centred) > 10.0
    # Rows near the bottom (about 5 m ahead) move by about f * 1 m / 5.4 m = 26 px.
    v = 60
    expected = column_of_line(v, 2.0, 50.0, offset_m, 0.0) - column_of_line(v, 2.0, 50.0, 0.0, 0.0)
    assert expected == pytest.approx(math.copysign(26.4, offset_m), abs=0.5)


@pytest.mark.parametrize("direction", ["left", "right"])
def test_a_curve_ahead_bends_the_right_way(direction):
    camera = PinholeCamera(ground_map(curve(direction)))
    frame = camera.render(10.0, 0.0, 0.0)  # 20 m before a radius-40 m curve
    far = bright_centroid(frame, slice(22, 30))  # 35-60 m ahead: inside the curve
    near = bright_centroid(frame, slice(50, 66))  # 5-8 m ahead: still the straight
    assert near == pytest.approx(CX, abs=2.0)
    sign = -1.0 if direction == "left" else 1.0  # a left bend moves to smaller columns
    assert sign * (far - near) > 8.0


def test_a_synthetic_single_line_ground_projects_by_hand():
    # One bright line along y = 0 on a dark ground, 0.1 m per pixel: independent of the track drawing.
    image = np.full((400, 1000), 50, np.uint8)
    row_of_y0 = 200  # y_max = 20 m
    image[row_of_y0 - 1:row_of_y0 + 2, :] = 250
    image.flags.writeable = False
    ground = GroundMap(image, 10.0, -10.0, 20.0)
    camera = PinholeCamera(ground)
    frame = camera.render(0.0, 1.0, 0.0)  # the line is 1 m to the right of the car
    for v in (30, 40, 50, 60):
        bright = np.flatnonzero(frame[v] > 150)
        expected = column_of_line(v, 0.0, 0.0, 1.0, 0.0)
        assert expected > CX  # to the right
        assert abs(bright.mean() - expected) < 1.5, (v, bright, expected)


# -- top-down render -------------------------------------------------------------------------------


def test_top_down_view_is_north_up_with_the_car_in_the_middle():
    view = TopDownView(ground_map(STRAIGHT_3), 200, 160, 4.0)
    image = view.render(50.0, 10.0, 0.0)  # 10 m north of the road's reference line
    assert image.shape == (160, 200, 3) and image.dtype == np.uint8
    # Car drawn blue-ish at the centre.
    b, _, r = image[80, 100].astype(int)[::-1]
    assert b > r + 50
    # The road (dark gray) is 10 m = 40 px SOUTH, i.e. lower in the image; the verge (greenish) above.
    road = image[120, 20].astype(int)
    assert road.max() - road.min() < 10 and road.mean() < 100
    verge = image[40, 20].astype(int)
    assert verge[1] > verge[0] + 20 and verge[1] > verge[2] + 20


def test_ground_row_warp_matches_the_full_frame_warp():
    """Warping only the ground rows (a row-shifted homography) gives the full-frame warp's pixels to
    within one gray level; the sky rows are haze either way."""
    track = load_track("test")
    gmap = ground_map(track, 10.0)
    camera = PinholeCamera(gmap, CONFIG)
    rng = np.random.default_rng(5)
    differing, total = 0, 0
    for s_m, offset_m, heading_rad in zip(rng.uniform(0, 1100, 60), rng.uniform(-3, 3, 60), rng.uniform(-0.2, 0.2, 60)):
        x_m, y_m, road_heading = reference_pose_at(track, float(s_m))
        pose = (x_m - offset_m * math.sin(road_heading), y_m + offset_m * math.cos(road_heading),
                road_heading + heading_rad)
        homography = gmap.world_to_pixel @ pose_matrix(*pose) @ camera._image_to_ground
        full = cv2.warpPerspective(gmap.image, homography, (CONFIG.width_px, CONFIG.height_px),
                                   flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
        full[camera._sky_rows] = HORIZON_GRAY
        frame = camera.render(*pose)
        difference = np.abs(frame.astype(int) - full.astype(int))
        assert difference.max() <= 1
        differing += int((difference > 0).sum())
        total += difference.size
    assert differing / total < 0.005


def test_frames_are_fresh_read_only_arrays(camera3):
    first = camera3.render(10.0, 0.0, 0.0)
    second = camera3.render(10.0, 0.0, 0.0)
    assert first is not second and not np.shares_memory(first, second)
    assert np.array_equal(first, second)
    with pytest.raises(ValueError, match="read-only"):
        first[0, 0] = 0


@pytest.mark.parametrize("camera_config", [CONFIG, CameraConfig(height_px=160, width_px=160)], ids=["200x66", "160x160"])
def test_default_map_resolution_keeps_frames_within_the_stated_tolerance(camera_config, repo_root):
    """The env draws its ground map coarser than 10 px/m; over the 400 poses of the golden run the
    frames differ from the 10 px/m frames by at most the documented mean absolute pixel difference."""
    import json

    golden = json.loads((repo_root / "tests" / "data" / "env_golden.json").read_text())
    poses = golden["runs"]["expert_no_latency"]["pose"]
    track = load_track("test")
    fine = PinholeCamera(ground_map(track, 10.0), camera_config)
    coarse = PinholeCamera(ground_map(track, DEFAULT_MAP_PX_PER_M), camera_config)
    means = [np.abs(coarse.render(*pose).astype(int) - fine.render(*pose).astype(int)).mean() for pose in poses]
    assert DEFAULT_MAP_PX_PER_M < 10.0
    assert np.mean(means) <= FRAME_TOLERANCE_MEAN_GRAY
    assert max(means) <= FRAME_TOLERANCE_WORST_FRAME_GRAY
    assert np.mean(means) > 0.1  # a different map was really drawn
