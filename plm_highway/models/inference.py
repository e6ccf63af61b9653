"""Closed-loop policies: (frame uint8 (H, W), speed m/s, latency s) -> normalised steering.

They run one frame at a time (batch size 1) under ``torch.inference_mode`` with the model in
eval mode. Both take the latency so that the evaluation code can swap them; the BM ignores it
(it is the unmitigated baseline). Both reject NaN or negative latency.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from plm_highway.models.base_model import BaseModel
from plm_highway.models.plm_net import PLMNet


class BaseModelPolicy:
    def __init__(self, bm: BaseModel):
        self.model = bm.eval()
        self.image_size_px = bm.config.image_size_px
        self.clamped_latency_count = 0  # always 0: the BM has no latency grid

    def reset(self) -> None:
        self.clamped_latency_count = 0

    def __call__(self, frame: np.ndarray, speed_mps: float, latency_s: float = 0.0) -> float:
        _check_latency(latency_s)
        with torch.inference_mode():
            return float(self.model(frame_batch(frame, self.image_size_px), speed_batch(speed_mps))[0])


class PLMNetPolicy:
    """PLM-Net; counts the steps whose latency was above the TAPM grid (the last head was used)."""

    def __init__(self, plm_net: PLMNet):
        self.model = plm_net.eval()
        self.image_size_px = plm_net.bm.config.image_size_px
        self.clamped_latency_count = 0

    def reset(self) -> None:
        self.clamped_latency_count = 0

    def __call__(self, frame: np.ndarray, speed_mps: float, latency_s: float) -> float:
        _check_latency(latency_s)
        with torch.inference_mode():
            output = self.model(
                frame_batch(frame, self.image_size_px),
                speed_batch(speed_mps),
                torch.tensor([latency_s], dtype=torch.float32),
            )
        self.clamped_latency_count += output.n_clamped
        return float(output.steering[0])


def frame_batch(frame: np.ndarray, image_size_px: tuple[int, int]) -> torch.Tensor:
    """uint8 (H, W) -> uint8 tensor (1, H, W), sharing memory when the frame is contiguous."""
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.shape != tuple(image_size_px):
        raise ValueError(f"frame: expected uint8 {tuple(image_size_px)}, got {frame.dtype} {frame.shape}")
    return torch.from_numpy(np.ascontiguousarray(frame)).unsqueeze(0)


def speed_batch(speed_mps: float) -> torch.Tensor:
    return torch.tensor([speed_mps], dtype=torch.float32)


def _check_latency(latency_s: float) -> None:
    if math.isnan(latency_s) or latency_s < 0:
        raise ValueError(f"latency_s: must be a number >= 0 s, got {latency_s}")
