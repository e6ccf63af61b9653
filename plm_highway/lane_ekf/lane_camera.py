"""The camera lane measurement: lateral offset, heading offset and curvature from a dashcam frame.

The paper's pipeline (Sensors 2025, 25, 6251, Section 3.1, Eqs. (10)-(22)) segments the lane markings,
maps them onto the ground plane and fits a polynomial to each boundary. Here, on the kit's grayscale
frames:

1. **Segmentation**: paint is brighter than the road around it. A horizontal white top-hat (the image
   minus its grey opening, wider than a marking) keeps narrow bright features and drops the
   asphalt/verge step; pixels above ``contrast_gray`` are marking pixels. Each run of marking pixels
   in an image row gives one point (its contrast-weighted centroid, to sub-pixel precision).
2. **Inverse perspective mapping**: the flat-ground homography of the camera
   (:func:`plm_highway.camera.pinhole.image_to_ground`) maps each point to ``(forward, left)`` metres
   in the car frame (origin at the car's reference point, the centre of gravity).
3. **Fit**: all boundaries at once. With the lane centre line ``c(x) = c0 + c1 x + c2 x^2`` in the car
   frame, boundary ``k`` lies at ``c(x) + (k + 1/2) w`` (``k = 0`` the ego lane's left boundary,
   ``k = -1`` its right one). Points are assigned to their nearest boundary and ``(c0, c1, c2, w)`` is
   fitted by least squares, a few times with a shrinking outlier gate. This is the paper's average of the
   left and right polynomials (Eqs. (20)-(22)) when both are seen, and still works with one.

The fit runs in a frame turned to the lane's first heading (from a phase search that needs no guess of
which point belongs to which boundary, :func:`initial_centre_line`): there a parabola describes an arc
well even when the car is at 10 deg to the lane. Then, at the point of the centre line nearest the car,
``d`` (the car's offset from the lane centre, left positive), ``dpsi = -(lane heading)`` and
``kappa = y'' / (1 + y'^2)^(3/2)`` (the paper's Eqs. (15)-(17) without their small-angle shortcuts).
Lane identity is tracked: given the previous measurement, ``d`` is taken from the lane it followed, so
it stays continuous through a lane change; without one, the lane the car is in is taken.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from plm_highway.camera.ground_map import ASPHALT_GRAY, MARKING_GRAY, MARKING_WIDTH_M
from plm_highway.camera.pinhole import CameraConfig, ground_rows, image_to_ground

MAX_SLOPE = 0.3  # heading offsets searched: +-atan(0.3) = +-17 deg
MAX_BEND_1PM = 0.02  # c2 = kappa / 2 searched: curvature radii down to 25 m
MIN_PAINT_FRACTION = 0.6  # of a full stripe's contrast, for a row's run to count as a marking point
MIN_GATE_M = 0.05  # the outlier gate never closes below the width of the paint's blur


@dataclass(frozen=True)
class LaneDetectorConfig:
    lane_width_m: float = 3.5  # prior lane width: for assigning points to boundaries, and when one boundary is seen
    min_forward_m: float = 0.0  # ground points used, ahead of the car's reference point
    max_forward_m: float = 25.0
    contrast_gray: float = 40.0  # a marking pixel is this much brighter than the road beside it
    max_residual_m: float = 0.35  # points farther than this from their boundary are outliers
    min_points: int = 8
    fit_iterations: int = 5

    def __post_init__(self):
        if not (math.isfinite(self.lane_width_m) and 1.0 <= self.lane_width_m <= 10.0):
            raise ValueError(f"LaneDetectorConfig.lane_width_m={self.lane_width_m!r} must be in [1, 10] m")
        if not (0 <= self.min_forward_m < self.max_forward_m <= 200):
            raise ValueError(f"LaneDetectorConfig: need 0 <= min_forward_m < max_forward_m <= 200, got "
                             f"{self.min_forward_m!r}, {self.max_forward_m!r}")
        if not (self.contrast_gray > 0 and self.max_residual_m > 0 and self.min_points >= 4 and self.fit_iterations >= 1):
            raise ValueError("LaneDetectorConfig: contrast_gray, max_residual_m > 0; min_points >= 4; fit_iterations >= 1")


@dataclass(frozen=True)
class LaneMeasurement:
    offset_m: float  # d: car from the lane centre, left positive
    heading_rad: float  # dpsi: car heading minus lane heading
    curvature_1pm: float  # kappa of the lane centre, positive turning left
    lane_width_m: float
    n_points: int

    @property
    def vector(self) -> np.ndarray:
        """``[d, dpsi, kappa]``, the camera rows of Eq. (24)."""
        return np.array([self.offset_m, self.heading_rad, self.curvature_1pm])


class LaneDetector:
    """Measures the lane from frames of one camera (its mounting fixes the ground mapping)."""

    def __init__(self, camera: CameraConfig | None = None, config: LaneDetectorConfig = LaneDetectorConfig()):
        camera = CameraConfig() if camera is None else camera
        self.camera = camera
        self.config = config
        self._to_ground = image_to_ground(camera)
        v = np.arange(camera.height_px, dtype=float)
        denominator = self._to_ground[2, 1] * v + self._to_ground[2, 2]
        forward_m = (self._to_ground[0, 1] * v + self._to_ground[0, 2]) / np.where(denominator > 0, denominator, 1.0)
        self._rows = np.flatnonzero(ground_rows(camera) & (forward_m >= config.min_forward_m)
                                    & (forward_m <= config.max_forward_m))
        if len(self._rows) < 3:
            raise ValueError(f"camera {camera}: fewer than 3 image rows see the ground between "
                             f"{config.min_forward_m} and {config.max_forward_m} m")
        # A marking is widest in the nearest row; the opening must be wider than that.
        # Paint width in pixels per row: the ground's lateral metres per pixel are |dleft/du| = h / (f D).
        metres_per_px = np.abs(self._to_ground[1, 0]) / denominator[self._rows]
        self._marking_px = MARKING_WIDTH_M / metres_per_px
        widest_px = float(self._marking_px.max())
        self._kernel = np.ones((1, 2 * int(math.ceil(1.5 * widest_px)) + 3), np.uint8)

    def marking_points(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(forward_m, left_m)`` of the marking points in ``frame`` (car frame, metres)."""
        expected = (self.camera.height_px, self.camera.width_px)
        if frame.shape != expected:
            raise ValueError(f"frame of shape {frame.shape}; this detector's camera gives {expected}")
        band = np.ascontiguousarray(frame[self._rows])
        contrast = cv2.morphologyEx(band, cv2.MORPH_TOPHAT, self._kernel).astype(np.float32)
        mask = contrast > self.config.contrast_gray
        # Runs of marking pixels along each row: starts where the mask turns on, ends where it turns off.
        padded = np.zeros((mask.shape[0], mask.shape[1] + 2), np.int8)
        padded[:, 1:-1] = mask
        edges = np.diff(padded, axis=1)
        row_on, col_on = np.nonzero(edges == 1)
        row_off, col_off = np.nonzero(edges == -1)  # same order: row-major, one end per start
        if len(row_on) == 0:
            return np.empty(0), np.empty(0)
        cols = np.arange(mask.shape[1], dtype=np.float32)
        weighted = np.cumsum(np.pad(contrast * cols, ((0, 0), (1, 0))), axis=1)
        total = np.cumsum(np.pad(contrast, ((0, 0), (1, 0))), axis=1)
        mass = total[row_on, col_off] - total[row_on, col_on]
        u = (weighted[row_on, col_off] - weighted[row_on, col_on]) / mass
        # A full stripe of paint gives (paint - asphalt) x width; much less is the tip of a dash, whose
        # centroid is pulled sideways by the rounded end.
        whole = mass >= MIN_PAINT_FRACTION * (MARKING_GRAY - ASPHALT_GRAY) * np.maximum(self._marking_px[row_on], 1.0)
        u, v = u[whole], self._rows[row_on[whole]].astype(float)
        ground = self._to_ground @ np.stack([u, v, np.ones_like(u)])
        return ground[0] / ground[2], ground[1] / ground[2]

    def measure(self, frame: np.ndarray, previous: LaneMeasurement | None = None) -> LaneMeasurement | None:
        """The lane in ``frame``, tracked from ``previous`` if given; None if too few markings are seen."""
        forward_m, left_m = self.marking_points(frame)
        return fit_lane(forward_m, left_m, self.config, previous)


def fit_lane(forward_m: np.ndarray, left_m: np.ndarray, config: LaneDetectorConfig,
             previous: LaneMeasurement | None = None) -> LaneMeasurement | None:
    """Fit the lane centre line and width to marking points (see the module docstring)."""
    if len(forward_m) < config.min_points:
        return None
    width_m = config.lane_width_m if previous is None else previous.lane_width_m
    c0, slope, bend = initial_centre_line(forward_m, left_m, width_m)
    # Fit in a frame turned to the lane's first heading: there the lane is nearly along the axis, and a
    # parabola describes a circular arc well (in the car frame a curve seen at 10 deg needs a cubic term).
    turn = math.atan(slope)
    cos_t, sin_t = math.cos(turn), math.sin(turn)
    along_m = forward_m * cos_t + left_m * sin_t
    across_m = -forward_m * sin_t + left_m * cos_t
    centre = np.array([c0 * cos_t, 0.0, bend / cos_t ** 3])
    powers = np.stack([np.ones_like(along_m), along_m, along_m ** 2], axis=1)
    tolerance_m = config.max_residual_m
    for _ in range(config.fit_iterations):
        relative_m = across_m - powers @ centre
        boundary = np.round(relative_m / width_m - 0.5)
        residual_m = relative_m - (boundary + 0.5) * width_m
        used = np.abs(residual_m) <= tolerance_m
        used &= (boundary >= -2) & (boundary <= 1)  # the ego lane's boundaries and the next ones out
        if used.sum() < config.min_points:
            return None
        offsets = boundary[used] + 0.5
        # A boundary o metres left of a centre line of curvature 2 c2 bends by 2 c2 / (1 - 2 c2 o): take
        # the extra bend off with the last estimate, so every boundary has the centre line's shape.
        target_m = across_m[used] - 2.0 * centre[2] ** 2 * offsets * width_m * along_m[used] ** 2
        if len(np.unique(offsets)) >= 2:
            solution, *_ = np.linalg.lstsq(np.column_stack([powers[used], offsets]), target_m, rcond=None)
            centre, width_m = solution[:3], float(solution[3])
        else:  # one boundary only: the width cannot be fitted, keep the prior
            centre, *_ = np.linalg.lstsq(powers[used], target_m - offsets * width_m, rcond=None)
        if not (0.75 * config.lane_width_m <= width_m <= 1.25 * config.lane_width_m):
            return None
        # Shrink the gate to 3 robust standard deviations: drops the smeared points at dash ends.
        spread_m = 1.4826 * np.median(np.abs(residual_m[used] - np.median(residual_m[used])))
        tolerance_m = min(config.max_residual_m, max(MIN_GATE_M, 3.0 * spread_m))
    offset_m, heading_rad, curvature_1pm = lane_at_car(centre)
    heading_rad -= turn
    # The boundary comb repeats every lane width: with a previous measurement keep following its lane
    # (d stays continuous through a lane change), without one take the lane the car is in.
    reference_m = 0.0 if previous is None else previous.offset_m
    offset_m += width_m * round((reference_m - offset_m) / width_m)
    return LaneMeasurement(offset_m, heading_rad, curvature_1pm, width_m, int(used.sum()))


def lane_at_car(centre: np.ndarray) -> tuple[float, float, float]:
    """``(d, dpsi, kappa)`` of the car (at the origin, heading along x) from a centre line ``c0 + c1 x + c2 x^2``.

    Taken at the point of the line nearest the car (one Newton step from ``x = 0``), so a heading offset
    does not turn into an offset error.
    """
    c0, c1, c2 = (float(c) for c in centre)
    # d/dx (x^2 + y^2) / 2 = x + y y' = 0, linearised at x = 0.
    foot_m = -c0 * c1 / (1.0 + c1 * c1 + 2.0 * c0 * c2)
    y_m = c0 + c1 * foot_m + c2 * foot_m ** 2
    slope = c1 + 2 * c2 * foot_m
    lane_heading = math.atan(slope)
    offset_m = foot_m * math.sin(lane_heading) - y_m * math.cos(lane_heading)
    return offset_m, -lane_heading, 2 * c2 / (1.0 + slope * slope) ** 1.5


def initial_centre_line(forward_m: np.ndarray, left_m: np.ndarray, width_m: float) -> np.ndarray:
    """A first ``(c0, c1, c2)`` that needs no guess of which point belongs to which boundary.

    Lane boundaries repeat every ``width_m`` across the road. Straightened by the right slope ``c1``
    and bend ``c2``, all marking points fall on that comb, so the phases ``2 pi (left - c1 x - c2 x^2) / w``
    agree: the grid point where their mean resultant is longest gives ``c1, c2``, and the mean phase
    gives ``c0`` modulo ``w``.
    """
    slopes = np.linspace(-MAX_SLOPE, MAX_SLOPE, 31)
    bends = np.linspace(-MAX_BEND_1PM, MAX_BEND_1PM, 9)
    best = _phase_resultant(forward_m, left_m, width_m, slopes, bends)
    # Refine around the best coarse cell (coarse to fine is ~6x cheaper than one fine grid).
    slope_step, bend_step = slopes[1] - slopes[0], bends[1] - bends[0]
    best = _phase_resultant(forward_m, left_m, width_m, best[1] + np.linspace(-slope_step, slope_step, 11),
                            best[2] + np.linspace(-bend_step, bend_step, 11))
    # Boundaries sit at c0 + (k + 1/2) w, i.e. at phase 2 pi (c0 / w + 1/2).
    c0 = width_m * (np.angle(best[0]) / (2 * np.pi) - 0.5)
    return np.array([c0, best[1], best[2]])


def _phase_resultant(forward_m, left_m, width_m, slopes, bends) -> tuple[complex, float, float]:
    """(mean resultant, slope, bend) of the longest mean resultant over the grid."""
    straightened = (left_m[None, None, :] - slopes[:, None, None] * forward_m
                    - bends[None, :, None] * forward_m ** 2)
    resultant = np.exp(2j * np.pi / width_m * straightened).mean(axis=2)
    i_slope, i_bend = np.unravel_index(np.argmax(np.abs(resultant)), resultant.shape)
    return resultant[i_slope, i_bend], float(slopes[i_slope]), float(bends[i_bend])
