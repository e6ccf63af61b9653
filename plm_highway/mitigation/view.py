"""The late frame as the camera would see the flat road from the car's present pose.

The kit's camera is a pinhole over flat ground (:mod:`plm_highway.camera.pinhole`): pixel and ground point are
related by one homography per camera, so a change of the car's pose between two frames is one homography between
them. A pixel of the present view is taken to the ground (present car frame), moved into the car frame at the
capture time and imaged by the camera as it stood then. Ground that the late frame did not see (beyond its range:
the strip the car drove towards while the frame was late) comes out as the haze at the late frame's horizon.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from plm_highway.camera.pinhole import WARP_FLAGS, CameraConfig, ground_rows, image_to_ground, pose_matrix


@functools.lru_cache(maxsize=8)
def _camera_maps(camera: CameraConfig) -> tuple[int, np.ndarray, np.ndarray]:
    """(first ground row, image->ground, ground->image) of ``camera``."""
    rows = ground_rows(camera)
    first = int(np.argmax(rows)) if rows.any() else camera.height_px
    to_ground = image_to_ground(camera)
    return first, to_ground, np.linalg.inv(to_ground)


def present_view_homography(camera: CameraConfig, pose: tuple[float, float, float]) -> np.ndarray:
    """3x3 map from a ground-row pixel of the present view (rows counted from the first ground row) to the pixel
    of the late frame that saw the same ground point; ``pose``: the car now in its frame at the capture,
    ``(forward_m, left_m, yaw_rad)`` (:func:`plm_highway.mitigation.odometry.relative_pose`)."""
    first, to_ground, to_image = _camera_maps(camera)
    shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, float(first)], [0.0, 0.0, 1.0]])
    return to_image @ pose_matrix(*pose) @ to_ground @ shift


def present_view(frame: np.ndarray, camera: CameraConfig, pose: tuple[float, float, float]) -> np.ndarray:
    """``frame`` (uint8, the camera's size) re-projected to the car's pose ``pose`` after its capture; the rows
    above the ground (sky) are kept as they were."""
    frame = np.asarray(frame)
    if frame.shape != (camera.height_px, camera.width_px) or frame.dtype != np.uint8:
        raise ValueError(f"present_view: frame is {frame.dtype} {frame.shape}, the camera gives uint8 "
                         f"{(camera.height_px, camera.width_px)}")
    if pose == (0.0, 0.0, 0.0):
        return frame
    first = _camera_maps(camera)[0]
    out = frame.copy()
    if first < camera.height_px:
        cv2.warpPerspective(frame, present_view_homography(camera, pose), (camera.width_px, camera.height_px - first),
                            out[first:], WARP_FLAGS, cv2.BORDER_REPLICATE)
    return out
