"""PLM-Net: the frozen Base Model, the TAPM, and Algorithm 1 (linear interpolation in latency).

delta_ref = [0, delta_TAPM...] and a_ref = [a_BM, a_TAPM...] (paper eq. 3). For a measured
latency delta the two neighbouring grid entries are interpolated linearly; a latency exactly on
the grid selects that entry's action unchanged, and latency 0 returns a_BM.

Outside the grid (the paper leaves this undefined): a latency above the last grid value uses the
last head's action (clamping; extrapolating a tanh-bounded prediction is not better founded), and
the number of clamped samples is reported so that a run can record it. NaN or negative latency
raises ValueError: it is a bug upstream, not a condition to mitigate.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from plm_highway.models.base_model import BaseModel
from plm_highway.models.tapm import TAPM


class PLMNetOutput(NamedTuple):
    steering: torch.Tensor  # (B,) the interpolated action a_PLM
    a_ref: torch.Tensor  # (B, N + 1): a_BM then one action per TAPM head
    n_clamped: int  # samples whose latency was above the last grid value


def validate_latency(latency_s: torch.Tensor) -> None:
    bad = torch.isnan(latency_s) | (latency_s < 0)
    if bool(bad.any()):
        first = float(latency_s.reshape(-1)[bad.reshape(-1)][0])
        raise ValueError(f"latency_s: must be a number >= 0 s, got {first}")


def count_clamped(latency_s: torch.Tensor, delta_ref_s: torch.Tensor) -> int:
    return int((latency_s > delta_ref_s[-1]).sum())


def interpolate_actions(latency_s, delta_ref_s, a_ref):
    """Algorithm 1 alone: actions ``a_ref`` (B, M) or (M,) known at latencies ``delta_ref_s`` (M,).

    ``latency_s`` is a scalar or (B,). Takes numpy arrays / floats (returns numpy) or torch tensors
    (returns torch, computed in ``a_ref``'s dtype). Latency above the last grid value clamps to
    it; NaN or negative latency raises ValueError.
    """
    as_numpy = not isinstance(a_ref, torch.Tensor)
    a_ref_t = torch.as_tensor(np.asarray(a_ref, dtype=np.float64) if as_numpy else a_ref)
    dtype = a_ref_t.dtype
    delta_ref_t = torch.as_tensor(delta_ref_s, dtype=dtype)
    latency_t = torch.as_tensor(latency_s, dtype=dtype)
    scalar_input = latency_t.dim() == 0
    latency_t = latency_t.reshape(-1)
    validate_latency(latency_t)
    _validate_reference(delta_ref_t, a_ref_t)
    result = interpolate_batch(latency_t, delta_ref_t, a_ref_t.expand(len(latency_t), -1))
    if scalar_input:
        result = result[0]
    return result.numpy() if as_numpy else result


def interpolate_batch(latency_s: torch.Tensor, delta_ref_s: torch.Tensor, a_ref: torch.Tensor) -> torch.Tensor:
    """Vectorised Algorithm 1 on validated inputs: latency (B,), delta_ref (M,), a_ref (B, M) -> (B,)."""
    latency = torch.minimum(latency_s, delta_ref_s[-1])  # above the grid: the last head
    # Segment [lo, hi] with delta_ref[lo] < latency <= delta_ref[hi]; latency 0 falls in the first.
    hi = torch.searchsorted(delta_ref_s, latency).clamp_(1, len(delta_ref_s) - 1)
    lo = hi - 1
    delta_lo = delta_ref_s[lo]
    weight = (latency - delta_lo) / (delta_ref_s[hi] - delta_lo)
    a_lo = a_ref.gather(1, lo.unsqueeze(1)).squeeze(1)
    a_hi = a_ref.gather(1, hi.unsqueeze(1)).squeeze(1)
    value = a_lo + weight * (a_hi - a_lo)
    # Rounding must not step outside the neighbours, and a grid point returns its action bit-exactly.
    value = torch.minimum(torch.maximum(value, torch.minimum(a_lo, a_hi)), torch.maximum(a_lo, a_hi))
    return torch.where(weight >= 1, a_hi, value)


def _validate_reference(delta_ref_s: torch.Tensor, a_ref: torch.Tensor) -> None:
    if delta_ref_s.dim() != 1 or len(delta_ref_s) < 2:
        raise ValueError(f"delta_ref_s: expected at least 2 latencies, got shape {tuple(delta_ref_s.shape)}")
    if not bool((delta_ref_s[1:] > delta_ref_s[:-1]).all()):
        raise ValueError(f"delta_ref_s: must be strictly increasing, got {delta_ref_s.tolist()}")
    if a_ref.shape[-1] != len(delta_ref_s) or a_ref.dim() > 2:
        raise ValueError(f"a_ref: expected (B, {len(delta_ref_s)}) or ({len(delta_ref_s)},), got {tuple(a_ref.shape)}")


class PLMNet(nn.Module):
    """BM + TAPM + Algorithm 1. The BM stays frozen and in eval mode whatever mode this module is in."""

    def __init__(self, bm: BaseModel, tapm: TAPM):
        super().__init__()
        if tapm.config.image_feature_dim != bm.image_feature_dim:
            raise ValueError(
                f"TAPM expects image features of size {tapm.config.image_feature_dim}, "
                f"the BM produces {bm.image_feature_dim} (different image size?)"
            )
        self.bm = bm.requires_grad_(False).eval()
        self.tapm = tapm
        delta_ref_s = torch.tensor((0.0, *tapm.config.delta_grid_s), dtype=torch.float32)
        self.register_buffer("delta_ref_s", delta_ref_s, persistent=False)

    def train(self, mode: bool = True) -> PLMNet:
        super().train(mode)
        self.bm.eval()
        return self

    def forward(
        self, frames: torch.Tensor, speed_mps: torch.Tensor, latency_s: torch.Tensor
    ) -> PLMNetOutput:
        """Frames uint8 (B, H, W), speed (B,), latency (B,) in s -> :class:`PLMNetOutput`."""
        latency_s = latency_s.to(torch.float32).reshape(-1)
        validate_latency(latency_s)
        z_o, z_v = self.bm.encode(frames, speed_mps)  # the one convolution pass
        a_bm = self.bm.steering_from_features(z_o, z_v)
        a_ref = torch.cat([a_bm.unsqueeze(1), self.tapm(a_bm, z_o, z_v)], dim=1)
        steering = interpolate_batch(latency_s, self.delta_ref_s, a_ref)
        return PLMNetOutput(steering, a_ref, count_clamped(latency_s, self.delta_ref_s))
