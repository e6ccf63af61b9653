"""A forward-looking pinhole camera on the ego car, rendered by one perspective warp.

The ground is flat, so the map from image pixels to points on the ground is a homography that
depends only on the camera's mounting (fixed per camera). Per frame only the car's pose changes:
``frame = warpPerspective(ground_map, world_to_pixel @ pose @ image_to_ground)``.

A camera may also stand for a larger sensor image that is cropped to a band of rows and resized
(the original PLM-Net: an 800x800 image, rows 380-520, resized to 160x160): the crop and the
resize are one more affine map from frame pixels to sensor pixels, folded into the same homography,
so such a frame costs no more than any other of its size. The resize samples each frame pixel at its
centre (bilinear from the ground map), not an area average of the sensor pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from plm_highway.camera.ground_map import GroundMap
from plm_highway.errors import BadInput

HORIZON_GRAY = 180  # sky and haze beyond the visible range
WARP_FLAGS = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP


# Accepted range of each CameraConfig field (closed intervals).
CAMERA_RANGES = {
    "height_px": (8, 1024), "width_px": (8, 1024), "fov_deg": (10.0, 150.0), "mount_height_m": (0.1, 10.0),
    "pitch_deg": (-30.0, 80.0), "forward_offset_m": (-10.0, 10.0), "max_range_m": (1.0, 1000.0),
    "sensor_width_px": (0, 4096), "sensor_height_px": (0, 4096), "crop_top_px": (0, 4096), "crop_rows_px": (0, 4096),
}
SENSOR_FIELDS = ("sensor_width_px", "sensor_height_px", "crop_top_px", "crop_rows_px")


@dataclass(frozen=True)
class CameraConfig:
    height_px: int = 66
    width_px: int = 200
    fov_deg: float = 70.0  # horizontal field of view
    mount_height_m: float = 1.6
    pitch_deg: float = 6.0  # downwards
    forward_offset_m: float = 1.0  # camera ahead of the car's reference point
    max_range_m: float = 60.0  # ground farther than this is drawn as haze
    # A larger sensor image cropped to rows [crop_top_px, crop_top_px + crop_rows_px) and resized to the
    # frame size; 0 everywhere (the default) = the frame is the whole sensor image. fov_deg is the sensor's.
    sensor_width_px: int = 0
    sensor_height_px: int = 0
    crop_top_px: int = 0
    crop_rows_px: int = 0

    @classmethod
    def from_dict(cls, values: dict) -> CameraConfig:
        """Checked construction; every error names the field, its value and the accepted range
        (:data:`CAMERA_RANGES`; NaN and infinities are outside every range)."""
        if not isinstance(values, dict):
            raise BadInput(f"camera config: must be a dict of CameraConfig fields, got {values!r}")
        unknown = sorted(set(values) - set(cls.__dataclass_fields__))
        if unknown:
            raise BadInput(f"camera config: unknown keys {unknown}; allowed {sorted(cls.__dataclass_fields__)}")
        for name, value in values.items():
            low, high = CAMERA_RANGES[name]
            is_int_field = name in ("height_px", "width_px", *SENSOR_FIELDS)
            number_type_ok = isinstance(value, int) if is_int_field else isinstance(value, (int, float))
            if isinstance(value, bool) or not number_type_ok or not (low <= value <= high):
                kind = "an integer" if is_int_field else "a number"
                raise BadInput(f"camera config: {name} = {value!r} must be {kind} in [{low:g}, {high:g}]")
        config = cls(**values)
        sensor = [getattr(config, name) for name in SENSOR_FIELDS]
        if any(sensor) and not (config.sensor_width_px and config.sensor_height_px and config.crop_rows_px
                                and config.crop_top_px + config.crop_rows_px <= config.sensor_height_px):
            raise BadInput(f"camera config: a cropped sensor needs sensor_width_px, sensor_height_px and crop_rows_px "
                           f"> 0 and crop_top_px + crop_rows_px <= sensor_height_px; got "
                           f"{dict(zip(SENSOR_FIELDS, sensor, strict=True))}")
        if ground_rows(config).sum() == 0:
            raise BadInput(f"camera config: pitch_deg={config.pitch_deg} with fov_deg={config.fov_deg} sees no "
                             f"ground within max_range_m={config.max_range_m}")
        return config

    @property
    def cropped(self) -> bool:
        return self.sensor_width_px > 0

    @property
    def focal_px(self) -> float:
        """Focal length in pixels of the sensor image (the frame itself unless cropped)."""
        width_px = self.sensor_width_px if self.cropped else self.width_px
        return (width_px / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)


# The original PLM-Net camera (notes on the original code; paper Sec. 4.1, OSCAR's Ford Fusion): an 800x800
# image with an 80 deg field of view from 1.83 m, cropped to rows 380-520 (the road strip) and resized to
# 160x160. Its pitch is "small" in the notes; 2.3 deg puts the horizon at the strip's top row
# (atan(19.5 px / 476.7 px focal)), so the whole strip is road, as the original crop was chosen to be.
PAPER_CAMERA = {"height_px": 160, "width_px": 160, "fov_deg": 80.0, "mount_height_m": 1.83, "pitch_deg": 2.3,
                "sensor_width_px": 800, "sensor_height_px": 800, "crop_top_px": 380, "crop_rows_px": 140}


def frame_to_sensor(config: CameraConfig) -> np.ndarray:
    """3x3 affine from frame pixel (u, v, 1) to sensor pixel: the crop and resize undone, pixel centres
    matched (the identity for an uncropped camera)."""
    if not config.cropped:
        return np.eye(3)
    scale_u = config.sensor_width_px / config.width_px
    scale_v = config.crop_rows_px / config.height_px
    return np.array([[scale_u, 0.0, 0.5 * scale_u - 0.5],
                     [0.0, scale_v, config.crop_top_px + 0.5 * scale_v - 0.5],
                     [0.0, 0.0, 1.0]])


def image_to_ground(config: CameraConfig) -> np.ndarray:
    """3x3 homography from pixel (u, v, 1) to (forward_m, left_m, 1) on the ground, car frame.

    A pixel's ray is (a, b, 1) in camera axes (right, down, forward) with a = (u-cx)/f,
    b = (v-cy)/f; pitching the camera down by theta and intersecting with the ground gives
    forward = h (cos th - b sin th) / D + offset, left = -h a / D, D = b cos th + sin th.
    For a cropped camera (u, v) are first taken to sensor pixels by :func:`frame_to_sensor`.
    """
    f = config.focal_px
    width_px, height_px = ((config.sensor_width_px, config.sensor_height_px) if config.cropped
                           else (config.width_px, config.height_px))
    cx, cy = (width_px - 1) / 2.0, (height_px - 1) / 2.0
    h = config.mount_height_m
    th = math.radians(config.pitch_deg)
    c, s = math.cos(th), math.sin(th)
    off = config.forward_offset_m
    denominator = np.array([0.0, c / f, s - cy * c / f])
    forward = np.array([0.0, -h * s / f, h * c + h * s * cy / f]) + off * denominator
    left = np.array([-h / f, 0.0, h * cx / f])
    sensor_to_ground = np.stack([forward, left, denominator])
    # Uncropped cameras keep exactly the matrix they always had (no product with the identity).
    return sensor_to_ground @ frame_to_sensor(config) if config.cropped else sensor_to_ground


def ground_rows(config: CameraConfig) -> np.ndarray:
    """Boolean per image row: True where the row sees ground within ``max_range_m``."""
    homography = image_to_ground(config)
    v = np.arange(config.height_px, dtype=float)
    denominator = homography[2, 1] * v + homography[2, 2]
    forward_m = (homography[0, 1] * v + homography[0, 2]) / np.where(denominator > 0, denominator, 1.0)
    return (denominator > 1e-9) & (forward_m <= config.max_range_m)


def pose_matrix(x_m: float, y_m: float, heading_rad: float) -> np.ndarray:
    """3x3 affine from the car frame (forward, left) to the world (x, y)."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return np.array([[c, -s, x_m], [s, c, y_m], [0.0, 0.0, 1.0]])


class PinholeCamera:
    """Renders grayscale dashcam frames of a :class:`GroundMap` from a car pose.

    Only the rows that see ground are warped; the rows above them (sky and haze) are filled. That is
    what the frame showed before, at a fraction of the cost: sky pixels map to points far outside the
    map, where OpenCV's warp takes its slow border path. Each frame is a new read-only array, so a
    frame handed to a policy cannot be changed behind the env's (or a latency buffer's) back.
    """

    def __init__(self, ground: GroundMap, config: CameraConfig = CameraConfig()):
        self.ground = ground
        self.config = config
        self._image_to_ground = image_to_ground(config)
        self._sky_rows = ~ground_rows(config)
        # Ground rows form one block at the bottom of the image (farther rows are higher up).
        self._first_ground_row = int(np.argmin(self._sky_rows)) if not self._sky_rows.all() else config.height_px
        if self._sky_rows[self._first_ground_row:].any():
            raise BadInput(f"camera config: pitch_deg={config.pitch_deg} puts sky below the ground in the image")
        shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, float(self._first_ground_row)], [0.0, 0.0, 1.0]])
        # Ground-row pixel (u, v') -> (forward, left, w) on the ground, as nine floats.
        self._ground_rows_to_ground = tuple((self._image_to_ground @ shift).ravel().tolist())
        self._size = (config.width_px, config.height_px)
        self._shape = (config.height_px, config.width_px)
        self._ground_size = (config.width_px, config.height_px - self._first_ground_row)
        self._map_scale = (ground.px_per_m, ground.x_min_m, ground.y_max_m)
        self._sky_frame = np.full(self._shape, HORIZON_GRAY, np.uint8)  # copied per frame, ground rows warped into it
        # Filled in place per frame (OpenCV copies it); a flat view avoids building a new array.
        self._homography = np.empty((3, 3))
        self._homography_flat = self._homography.reshape(-1)

    def homography(self, x_m: float, y_m: float, heading_rad: float) -> np.ndarray:
        """Ground-row pixel -> map pixel: ``world_to_pixel @ pose_matrix(x, y, heading) @ image_to_ground``,
        with the image rows counted from the first ground row, built from scalars."""
        return self._fill_homography(x_m, y_m, heading_rad).copy()

    def _fill_homography(self, x_m: float, y_m: float, heading_rad: float) -> np.ndarray:
        s, x_min_m, y_max_m = self._map_scale
        a, b = s * math.cos(heading_rad), s * math.sin(heading_rad)
        tx, ty = s * (x_m - x_min_m), s * (y_max_m - y_m)
        g00, g01, g02, g10, g11, g12, g20, g21, g22 = self._ground_rows_to_ground
        self._homography_flat[:] = (
            a * g00 - b * g10 + tx * g20, a * g01 - b * g11 + tx * g21, a * g02 - b * g12 + tx * g22,
            -b * g00 - a * g10 + ty * g20, -b * g01 - a * g11 + ty * g21, -b * g02 - a * g12 + ty * g22,
            g20, g21, g22,
        )
        return self._homography

    def render(self, x_m: float, y_m: float, heading_rad: float) -> np.ndarray:
        frame = self._sky_frame.copy()
        first = self._first_ground_row
        if first < self._shape[0]:
            cv2.warpPerspective(self.ground.image, self._fill_homography(x_m, y_m, heading_rad), self._ground_size,
                                frame[first:], WARP_FLAGS, cv2.BORDER_REPLICATE)
        frame.flags.writeable = False
        return frame
