"""The track drawn once, from above, as the grayscale ground texture the camera looks at.

Every camera frame is then one perspective warp of this image: drawing the road each frame
(what highway-env's GrayscaleObservation does) is what makes the stock observation slow.
"""

from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass

import cv2
import numpy as np

from plm_highway.errors import BadInput
from plm_highway.road.geometry import sample_reference
from plm_highway.road.spec import TrackSpec

# Gray levels of the ground (uint8).
OFFROAD_GRAY = 105
ASPHALT_GRAY = 60
MARKING_GRAY = 235
MARKING_WIDTH_M = 0.2
DASH_LENGTH_M = 3.0
DASH_PERIOD_M = 9.0  # 3 m painted, 6 m gap
TEXTURE_SIGMA_GRAY = 10.0
# The map resolution the env draws at: the coarsest that keeps the dashcam frames within
# FRAME_TOLERANCE_* of the frames of a 10 px/m map (test_camera.py checks both cameras on a 400-step
# run) *and* keeps lane markings at full paint brightness where the pinhole model puts them (the
# geometric camera tests). Measured on that run (mean absolute difference in gray levels, run mean /
# worst frame), 200x66 camera: 8 px/m 1.54 / 2.52, 6 px/m 2.27 / 3.73, 5 px/m 2.26 / 3.53,
# 4 px/m 2.67 / 3.86; 160x160: 8 px/m 1.13 / 2.33. Below 8 px/m a 0.2 m marking is one map pixel,
# which bilinear sampling spreads over two: its peak falls from 235 to ~175 and the marking tests
# fail, although the mean difference stays small. At 8 px/m markings are two pixels (0.25 m).
# A coarser map is also a smaller one: 0.64x the memory of 10 px/m.
DEFAULT_MAP_PX_PER_M = 8.0
# The map is one uint8 image (plus masks and a float32 texture while it is drawn: about 8 bytes per
# pixel at the peak): at most this many pixels, checked before any drawing (640 MB peak). The shipped
# train track is 68 million at 8 px/m; a closed circle of 1.5 km radius would be 625 million.
MAX_MAP_PIXELS = 80_000_000
MAP_PX_PER_M_RANGE = (1.0, 40.0)
FRAME_TOLERANCE_MEAN_GRAY = 2.5  # mean absolute pixel difference, averaged over a run's frames
FRAME_TOLERANCE_WORST_FRAME_GRAY = 4.0  # the same, in the worst frame of the run
# The ground texture is one noise field per track, drawn on the grid it had at 10 px/m (one noise
# sample per 0.5 m): every map resolution samples the same field, so frames at a coarser map
# differ from the 10 px/m ones only by resolution, not by a new random texture.
TEXTURE_REFERENCE_PX_PER_M = 10.0


@dataclass(frozen=True)
class GroundMap:
    """A top-down grayscale image of the track and its world-to-pixel transform."""

    image: np.ndarray  # (rows, cols) uint8
    px_per_m: float
    x_min_m: float
    y_max_m: float

    @property
    def world_to_pixel(self) -> np.ndarray:
        """3x3 affine taking (x, y, 1) in metres (y up) to (col, row, 1) in the image (row down)."""
        s = self.px_per_m
        return np.array([[s, 0.0, -s * self.x_min_m], [0.0, -s, s * self.y_max_m], [0.0, 0.0, 1.0]])

    def to_pixels(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        return np.stack([(x_m - self.x_min_m) * self.px_per_m, (self.y_max_m - y_m) * self.px_per_m], axis=-1)


@functools.lru_cache(maxsize=8)
def ground_map(track: TrackSpec, px_per_m: float = DEFAULT_MAP_PX_PER_M, margin_m: float = 60.0) -> GroundMap:
    """Draw ``track`` (cached: every env on the same track in a process shares one map)."""
    low, high = MAP_PX_PER_M_RANGE
    if not (isinstance(px_per_m, (int, float)) and low <= px_per_m <= high):  # False for NaN
        raise BadInput(f"map_px_per_m {px_per_m!r} outside [{low:g}, {high:g}] px/m")
    ref = sample_reference(track, spacing_m=0.25)
    half_width_m = track.road_half_width_m
    edges_x = np.concatenate([ref.offset(half_width_m)[0], ref.offset(-half_width_m)[0]])
    edges_y = np.concatenate([ref.offset(half_width_m)[1], ref.offset(-half_width_m)[1]])
    x_min_m, x_max_m = edges_x.min() - margin_m, edges_x.max() + margin_m
    y_min_m, y_max_m = edges_y.min() - margin_m, edges_y.max() + margin_m
    cols = int(np.ceil((x_max_m - x_min_m) * px_per_m))
    rows = int(np.ceil((y_max_m - y_min_m) * px_per_m))
    if max(rows, cols) >= 32767 or rows * cols > MAX_MAP_PIXELS:  # OpenCV's warp limit on sources; memory
        raise BadInput(
            f"{track.source}: track {track.name!r} spans {x_max_m - x_min_m:,.0f} x {y_max_m - y_min_m:,.0f} m "
            f"with its margins; at {px_per_m:g} px/m its ground map would be {cols:,} x {rows:,} px, beyond the "
            f"limit of {MAX_MAP_PIXELS:,} px and 32,767 px a side: make the track more compact or lower map_px_per_m")
    gmap = GroundMap(np.empty((rows, cols), np.uint8), px_per_m, x_min_m, y_max_m)

    rng = np.random.default_rng(zlib.crc32(track.name.encode()))
    grid_shape = _texture_grid_shape(x_max_m - x_min_m, y_max_m - y_min_m)
    image = _texture(rng, grid_shape, rows, cols, OFFROAD_GRAY)
    asphalt = np.zeros((rows, cols), np.uint8)
    _fill_road(asphalt, gmap, ref, half_width_m, track)
    on_road = asphalt > 127
    image[on_road] = _texture(rng, grid_shape, rows, cols, ASPHALT_GRAY)[on_road]
    _draw_markings(image, gmap, ref, track)
    gmap.image[:] = image
    gmap.image.flags.writeable = False
    return gmap


def _texture_grid_shape(width_m: float, height_m: float) -> tuple[int, int]:
    reference_rows = int(np.ceil(height_m * TEXTURE_REFERENCE_PX_PER_M))
    reference_cols = int(np.ceil(width_m * TEXTURE_REFERENCE_PX_PER_M))
    scale = int(round(TEXTURE_REFERENCE_PX_PER_M / 2))
    return reference_rows // scale + 2, reference_cols // scale + 2


def _texture(rng: np.random.Generator, grid_shape: tuple[int, int], rows: int, cols: int,
             mean_gray: float) -> np.ndarray:
    # Smooth noise at ~0.5 m scale gives the ground visible motion without fake features; drawn
    # at 2 px/m and upscaled, because full-resolution float noise would cost gigabytes.
    noise = rng.standard_normal(grid_shape, dtype=np.float32)
    noise = cv2.GaussianBlur(noise, (0, 0), sigmaX=0.7)
    noise *= TEXTURE_SIGMA_GRAY / max(float(noise.std()), 1e-6)
    noise = cv2.resize(noise, (cols, rows), interpolation=cv2.INTER_LINEAR)
    noise += mean_gray  # in place: the full-size float texture is the largest temporary
    return np.clip(noise, 0, 255, out=noise).astype(np.uint8)


def _fill_road(mask: np.ndarray, gmap: GroundMap, ref, half_width_m: float, track: TrackSpec) -> None:
    # One polygon per segment keeps every polygon simple even on tracks that curl back.
    for index in range(len(track.segments)):
        sel = np.flatnonzero(ref.segment_index == index)
        sel = np.append(sel, min(sel[-1] + 1, len(ref.s_m) - 1))
        left = gmap.to_pixels(*[a[sel] for a in ref.offset(half_width_m)])
        right = gmap.to_pixels(*[a[sel] for a in ref.offset(-half_width_m)])
        polygon = np.concatenate([left, right[::-1]])
        cv2.fillPoly(mask, [np.round(polygon * 16).astype(np.int32)], 255, lineType=cv2.LINE_AA, shift=4)


def _draw_markings(image: np.ndarray, gmap: GroundMap, ref, track: TrackSpec) -> None:
    thickness_px = max(1, int(round(MARKING_WIDTH_M * gmap.px_per_m)))
    for boundary in range(track.lanes + 1):
        lateral_m = track.road_half_width_m - boundary * track.lane_width_m
        points = gmap.to_pixels(*ref.offset(lateral_m))
        outer = boundary in (0, track.lanes)
        painted = np.ones(len(points), bool) if outer else (np.mod(ref.s_m, DASH_PERIOD_M) < DASH_LENGTH_M)
        for run in _runs(painted):
            polyline = np.round(points[run] * 16).astype(np.int32)
            cv2.polylines(image, [polyline], False, MARKING_GRAY, thickness_px, cv2.LINE_AA, shift=4)


def _runs(mask: np.ndarray) -> list[slice]:
    """Contiguous True stretches of ``mask`` as slices."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    changes = np.flatnonzero(np.diff(padded))
    return [slice(start, stop) for start, stop in zip(changes[::2], changes[1::2])]
