"""The original PLM-Net camera: an 800x800 image's road strip (rows 380-520) resized to 160x160.

The cropped camera folds the crop and the resize into its homography; these tests build the same frame
the long way (render the whole 800x800 sensor image, crop it, resize it with OpenCV) and compare.
"""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from plm_highway.camera.ground_map import ground_map
from plm_highway.camera.pinhole import HORIZON_GRAY, PAPER_CAMERA, CameraConfig, PinholeCamera
from plm_highway.errors import BadInput
from plm_highway.road.geometry import reference_pose_at
from plm_highway.road.track import load_track

PAPER = CameraConfig.from_dict(PAPER_CAMERA)
# The same lens on the whole 800x800 sensor, uncropped.
SENSOR = replace(PAPER, height_px=800, width_px=800, sensor_width_px=0, sensor_height_px=0, crop_top_px=0,
                 crop_rows_px=0)


@pytest.fixture(scope="module")
def train_map():
    return ground_map(load_track("train"))


def poses(n: int = 6):
    spec = load_track("train")
    return [reference_pose_at(spec, arc_m) for arc_m in np.linspace(50.0, spec.length_m - 100.0, n)]


def test_original_geometry_is_what_the_notes_say():
    assert (PAPER.height_px, PAPER.width_px) == (160, 160)
    assert (PAPER.sensor_height_px, PAPER.sensor_width_px) == (800, 800)
    assert (PAPER.crop_top_px, PAPER.crop_top_px + PAPER.crop_rows_px) == (380, 520)
    assert PAPER.fov_deg == 80.0 and PAPER.mount_height_m == 1.83 and 0 < PAPER.pitch_deg < 5
    assert PAPER.focal_px == pytest.approx(400.0 / math.tan(math.radians(40.0)))


def test_cropped_frame_is_the_sensor_image_cropped_and_resized(train_map):
    cropped, sensor = PinholeCamera(train_map, PAPER), PinholeCamera(train_map, SENSOR)
    differences = []
    for x_m, y_m, heading_rad in poses():
        strip = sensor.render(x_m, y_m, heading_rad)[380:520]
        # INTER_AREA averages the 5 sensor columns per frame column; the cropped camera samples the centre of
        # them, so fine texture differs a little, the road (markings, edges) not.
        expected = cv2.resize(strip, (160, 160), interpolation=cv2.INTER_AREA).astype(float)
        differences.append(np.abs(cropped.render(x_m, y_m, heading_rad).astype(float) - expected).mean())
    assert max(differences) < 3.5
    assert np.mean(differences) < 3.0


def test_cropped_frame_is_not_the_whole_sensor_image_resized(train_map):
    """The comparison above can fail: resizing the whole 800x800 image (no crop) gives another frame."""
    cropped, sensor = PinholeCamera(train_map, PAPER), PinholeCamera(train_map, SENSOR)
    x_m, y_m, heading_rad = poses(1)[0]
    whole = cv2.resize(sensor.render(x_m, y_m, heading_rad), (160, 160), interpolation=cv2.INTER_AREA)
    assert np.abs(cropped.render(x_m, y_m, heading_rad).astype(float) - whole.astype(float)).mean() > 20.0


def test_the_strip_is_road_not_sky(train_map):
    plain = PinholeCamera(train_map, CameraConfig(height_px=160, width_px=160))
    paper = PinholeCamera(train_map, PAPER)
    x_m, y_m, heading_rad = poses(1)[0]
    plain_sky = np.mean(plain.render(x_m, y_m, heading_rad) == HORIZON_GRAY)
    paper_sky = np.mean(paper.render(x_m, y_m, heading_rad) == HORIZON_GRAY)
    assert plain_sky > 0.4  # the old 160x160 option: almost half sky
    assert paper_sky < 0.15  # the strip: haze only in the top rows, beyond the 60 m range


@pytest.mark.parametrize("fields", [
    {"sensor_width_px": 800},
    {"sensor_width_px": 800, "sensor_height_px": 800, "crop_top_px": 700, "crop_rows_px": 140},
    {"crop_rows_px": 140},
    {"sensor_width_px": 800.0, "sensor_height_px": 800, "crop_rows_px": 140},
])
def test_incomplete_or_out_of_range_crops_are_refused(fields):
    with pytest.raises(BadInput, match="sensor|crop"):
        CameraConfig.from_dict({"height_px": 160, "width_px": 160, **fields})


def test_default_camera_has_no_crop():
    assert not CameraConfig().cropped
    assert CameraConfig().focal_px == pytest.approx(100.0 / math.tan(math.radians(35.0)))


def test_paper_camera_runs_in_the_env_and_default_stays_default():
    import gymnasium

    import plm_highway  # noqa: F401  (registers the env)
    from plm_highway.envs import ENV_ID

    env = gymnasium.make(ENV_ID, config={"track": "train", "camera": PAPER_CAMERA})
    obs, _ = env.reset(seed=0)
    assert obs.shape == (160, 160) and np.mean(obs == HORIZON_GRAY) < 0.15
    obs, _ = gymnasium.make(ENV_ID, config={"track": "train"}).reset(seed=0)
    assert obs.shape == (66, 200)
