"""A north-up, top-down colour view around the car, for ``render_mode="rgb_array"`` and videos."""

from __future__ import annotations

import math

import cv2
import numpy as np

from plm_highway.camera.ground_map import GroundMap

CAR_LENGTH_M, CAR_WIDTH_M = 5.0, 2.0


def _gray_to_colour_lut() -> np.ndarray:
    # Dark gray asphalt, green verges, white paint: the gray levels of the ground map, coloured.
    gray = np.arange(256, dtype=float)
    grass = np.array([70, 130, 60]) * (gray[:, None] / 105.0)
    asphalt = np.repeat(gray[:, None] * 1.1, 3, axis=1)
    paint = np.repeat(gray[:, None], 3, axis=1)
    lut = np.where(gray[:, None] < 85, asphalt, np.where(gray[:, None] < 170, grass, paint))
    return np.clip(lut, 0, 255).astype(np.uint8)


class TopDownView:
    def __init__(self, ground: GroundMap, width_px: int = 480, height_px: int = 360, px_per_m: float = 4.0):
        self.ground = ground
        self.size = (int(width_px), int(height_px))
        self.px_per_m = float(px_per_m)
        self._lut = _gray_to_colour_lut()

    def render(self, x_m: float, y_m: float, heading_rad: float) -> np.ndarray:
        zoom = self.px_per_m / self.ground.px_per_m
        col, row = self.ground.to_pixels(np.array(x_m), np.array(y_m))
        width, height = self.size
        # Map pixel (c, r) -> view pixel: scale about the car, car at the view's centre.
        affine = np.array([[zoom, 0.0, width / 2 - zoom * col], [0.0, zoom, height / 2 - zoom * row]])
        gray = cv2.warpAffine(self.ground.image, affine, self.size, flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
        image = self._lut[gray]
        self._draw_car(image, heading_rad)
        return image

    def _draw_car(self, image: np.ndarray, heading_rad: float) -> None:
        c, s = math.cos(heading_rad), math.sin(heading_rad)
        half_l, half_w = CAR_LENGTH_M / 2, CAR_WIDTH_M / 2
        corners = np.array([[half_l, half_w], [half_l, -half_w], [-half_l, -half_w], [-half_l, half_w]])
        world = corners @ np.array([[c, s], [-s, c]])  # rotate (forward, left) into (x, y)
        pixels = np.stack([world[:, 0], -world[:, 1]], axis=1) * self.px_per_m + np.array(self.size) / 2
        cv2.fillPoly(image, [np.round(pixels * 16).astype(np.int32)], (40, 90, 220), cv2.LINE_AA, shift=4)
