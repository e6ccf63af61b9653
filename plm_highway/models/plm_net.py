"""PLM-Net: the frozen Base Model, the TAPM, and Algorithm 1 (linear interpolation in latency).

delta_ref = [0, delta_TAPM...] and a_ref = [a_BM, a_TAPM...] (paper eq. 3). For a measured
latency delta the two neighbouring grid entries are interpolated linearly; a latency exactly on
the grid selects that entry's action unchanged, and latency 0 returns a_BM.

Outside the grid (the paper leaves this undefined): a latency above the last grid value uses the
last head's action (clamping; extrapolating a tanh-bounded prediction is not better founded), and
the number of clamped samples is reported so that a run can record it. NaN or negative latency
raises ValueError: it is a bug upstream, not a condition to mitigate.

:class:`PLMNet` is the model as specified (every head, the BM's and the TAPM's layers one after
the other) and what training and analysis use. :class:`FusedPLMNet` is its inference form, equal
to it up to float rounding (measured: at most a few 1e-8 apart) and cheaper where PLM-Net's cost over
the BM lies: the BM's first FC layer and the TAPM's image branch read the same features, so they
run as one matrix product (the image features are read once, one call instead of two), and only
the heads that bracket each sample's latency run (Algorithm 1 reads no others: one or two heads
at batch size 1 instead of five).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from plm_highway.errors import BadInput
from plm_highway.models.base_model import BaseModel
from plm_highway.models.tapm import TAPM


class PLMNetOutput(NamedTuple):
    steering: torch.Tensor  # (B,) the interpolated action a_PLM
    a_ref: torch.Tensor  # (B, N + 1): a_BM then one action per TAPM head
    n_clamped: int  # samples whose latency was above the last grid value


def check_latency(latency_s: torch.Tensor, last_grid_s: float) -> int:
    """Raise ValueError on NaN or negative latency; return how many latencies exceed the grid."""
    # One reduction covers both checks: a NaN propagates into the minimum, which then fails ">= 0".
    low, high = latency_s.aminmax()
    if not float(low) >= 0:
        bad = torch.isnan(latency_s) | (latency_s < 0)
        raise BadInput(f"latency_s: must be a number >= 0 s, got {float(latency_s[bad][0])}")
    return 0 if float(high) <= last_grid_s else int((latency_s > last_grid_s).sum())


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
    _validate_reference(delta_ref_t, a_ref_t, len(latency_t))
    check_latency(latency_t, float(delta_ref_t[-1]))
    result = interpolate_batch(latency_t, delta_ref_t, a_ref_t.expand(len(latency_t), -1))
    if scalar_input:
        result = result[0]
    return result.numpy() if as_numpy else result


def interpolate_batch(latency_s, delta_ref_s, a_ref):
    """Vectorised Algorithm 1 on validated inputs: latency (B,), delta_ref (M,), a_ref (B, M) -> (B,).

    All torch tensors or all numpy arrays (of one float dtype): the same element-wise IEEE
    arithmetic either way, so both give the same values (a zero's sign may differ). Numpy is the cheaper of the two at batch
    size 1 (an operation costs ~1 us instead of ~5 us), which is why inference uses it.
    """
    xp = torch if isinstance(a_ref, torch.Tensor) else np
    latency = xp.minimum(latency_s, delta_ref_s[-1])  # above the grid: the last head
    # Segment [lo, lo + 1] with delta_ref[lo] < latency <= delta_ref[lo + 1] (latency 0 falls in the
    # first): searching the interior grid points gives lo directly, with no clamping.
    lo = xp.searchsorted(delta_ref_s[1:-1], latency)
    # Both neighbours in one take/gather each: at batch size 1 the op count is the cost.
    neighbours = xp.stack((lo, lo + 1), 1)
    deltas = xp.take(delta_ref_s, neighbours)
    actions = torch.gather(a_ref, 1, neighbours) if xp is torch else np.take_along_axis(a_ref, neighbours, 1)
    delta_lo, delta_hi, a_lo, a_hi = deltas[:, 0], deltas[:, 1], actions[:, 0], actions[:, 1]
    weight = (latency - delta_lo) / (delta_hi - delta_lo)
    # Rounding must not step outside the neighbours, and a grid point returns its action bit-exactly.
    value = xp.clip(a_lo + weight * (a_hi - a_lo), xp.minimum(a_lo, a_hi), xp.maximum(a_lo, a_hi))
    return xp.where(latency == delta_hi, a_hi, value)


def _validate_reference(delta_ref_s: torch.Tensor, a_ref: torch.Tensor, n_latencies: int) -> None:
    n_ref = len(delta_ref_s)
    if delta_ref_s.dim() != 1 or n_ref < 2:
        raise BadInput(f"delta_ref_s: expected at least 2 latencies, got shape {tuple(delta_ref_s.shape)}")
    if not bool((delta_ref_s[1:] > delta_ref_s[:-1]).all()):
        raise BadInput(f"delta_ref_s: must be strictly increasing, got {delta_ref_s.tolist()}")
    if (
        a_ref.dim() not in (1, 2)
        or a_ref.shape[-1] != n_ref
        or (a_ref.dim() == 2 and len(a_ref) != n_latencies)
    ):
        raise BadInput(f"a_ref: expected ({n_latencies}, {n_ref}) or ({n_ref},), got {tuple(a_ref.shape)}")


def check_latency_array(latency_s: np.ndarray, last_grid_s: float) -> np.ndarray:
    """:func:`check_latency` on the host: raise on NaN or negative latency; return the above-grid mask."""
    if not bool(np.all(latency_s >= 0)):  # NaN fails the comparison too
        bad = latency_s[~(latency_s >= 0)]
        raise BadInput(f"latency_s: must be a number >= 0 s, got {float(bad[0])}")
    return latency_s > np.float32(last_grid_s)


class PLMNet(nn.Module):
    """BM + TAPM + Algorithm 1. The BM stays frozen and in eval mode whatever mode this module is in."""

    def __init__(self, bm: BaseModel, tapm: TAPM):
        super().__init__()
        if tapm.config.image_feature_dim != bm.image_feature_dim:
            raise BadInput(
                f"TAPM expects image features of size {tapm.config.image_feature_dim}, "
                f"the BM produces {bm.image_feature_dim} (different image size?)"
            )
        self.bm = bm.requires_grad_(False).eval()
        self.tapm = tapm
        delta_ref_s = torch.tensor((0.0, *tapm.config.delta_grid_s), dtype=torch.float32)
        self.register_buffer("delta_ref_s", delta_ref_s, persistent=False)
        # The last grid value as the float32 the interpolation compares with, so counting agrees with it.
        self.last_grid_s = float(delta_ref_s[-1])

    def train(self, mode: bool = True) -> PLMNet:
        super().train(mode)
        self.bm.eval()
        return self

    def forward(self, frames: torch.Tensor, speed_mps: torch.Tensor, latency_s: torch.Tensor) -> PLMNetOutput:
        """Frames uint8 (B, H, W), speed (B,), latency (B,) in s -> :class:`PLMNetOutput`."""
        latency_s = latency_s.to(torch.float32).reshape(-1)
        if len(latency_s) != len(frames):
            raise BadInput(
                f"latency_s: expected one latency per frame ({len(frames)}), got {len(latency_s)}"
            )
        n_clamped = check_latency(latency_s, self.last_grid_s)
        z_o, z_v = self.bm.encode(frames, speed_mps)  # the one convolution pass
        a_bm = self.bm.steering_from_features(z_o, z_v)
        a_ref = torch.cat([a_bm.unsqueeze(1), self.tapm(a_bm, z_o, z_v)], dim=1)
        return PLMNetOutput(interpolate_batch(latency_s, self.delta_ref_s, a_ref), a_ref, n_clamped)


class PLMNetSteering(NamedTuple):
    steering: torch.Tensor  # (B,) the interpolated action a_PLM
    clamped: np.ndarray  # (B,) bool: latency above the last grid value (the last head was used)


class FusedPLMNet:
    """Inference-only PLM-Net, equal to :meth:`PLMNet.forward`'s steering up to float rounding.

    Built from a trained, frozen ``plm_net``: the fused first layer, the action branch and the packed
    heads are copies taken then (~5 MB for the default preset, ~44 MB for the paper preset), so a
    ``plm_net`` whose weights change afterwards needs a new ``FusedPLMNet``. Runs under
    ``torch.inference_mode`` (no gradients).
    """

    def __init__(self, plm_net: PLMNet):
        bm, tapm = plm_net.bm.eval(), plm_net.tapm.eval()
        self.bm, self.tapm = bm, tapm
        first, image_fc = bm.mlp[0], tapm.image_fc
        self.bm_width = first.out_features
        # The TAPM reads z_o only: its rows get zero weights for the speed (and acceleration) features,
        # so one product over the BM's concatenated MLP input yields both layers.
        padding = torch.zeros(image_fc.out_features, first.in_features - image_fc.in_features)
        with torch.no_grad():
            self.weight = torch.cat([first.weight, torch.cat([image_fc.weight, padding], dim=1)]).contiguous()
            self.bias = torch.cat([first.bias, image_fc.bias])
            # a_BM -> FC 100 is a rank-1 map: a_BM * w + b, one fused op instead of a (B, 1) product.
            self.action_weight = tapm.action_fc.weight.view(1, -1).clone()
            self.action_bias = tapm.action_fc.bias.clone()
        self.delta_ref_s = plm_net.delta_ref_s.numpy().copy()  # float32
        self._interior_grid_s = self.delta_ref_s[1:-1]
        self.last_grid_s = plm_net.last_grid_s
        self.n_heads = tapm.config.n_heads
        # Per contiguous head range (at most n (n + 1) / 2 of them, built when first needed).
        self._sub_grids: dict[tuple[int, int], np.ndarray] = {}
        self._packed_heads: dict[tuple[int, int], tuple[tuple[torch.Tensor, torch.Tensor], ...]] = {}

    @torch.inference_mode()
    def __call__(self, frames: torch.Tensor, speed_mps: torch.Tensor, latency_s, all_heads: bool = False) -> PLMNetSteering:
        """Frames uint8 (B, H, W), speed (B,) m/s, latency (B,) s (tensor or array) -> steering (B,).

        ``all_heads=True`` evaluates every head whenever a latency is above 0, instead of only the heads
        that bracket the batch's latencies: the heads' products then have one width whatever the batch
        holds, so with batch-invariant kernels a sample's steering does not depend on the other
        samples' latencies (batch-invariant runs, :mod:`plm_highway.models.batch_invariant`).
        """
        latency_np = np.asarray(latency_s, dtype=np.float32).reshape(-1)
        if len(latency_np) != len(frames):
            raise BadInput(f"latency_s: expected one latency per frame ({len(frames)}), got {len(latency_np)}")
        clamped = check_latency_array(latency_np, self.last_grid_s)
        z_o, z_v = self.bm.encode(frames, speed_mps)
        first_layer = torch.nn.functional.linear(self.bm.mlp_input(z_o, z_v), self.weight, self.bias)
        a_bm = self.bm.steering_from_first_layer(first_layer[:, : self.bm_width])
        if not latency_np.any():  # every latency 0: Algorithm 1 returns a_BM, no head is needed
            return PLMNetSteering(a_bm, clamped)
        # Grid segment of each sample, as interpolate_batch finds it: a_ref entries lo and lo + 1,
        # i.e. heads lo - 1 (none for lo = 0: the BM) and lo.
        lo = np.searchsorted(self._interior_grid_s, np.minimum(latency_np, np.float32(self.last_grid_s)))
        if all_heads:
            first_head, stop_head = 0, self.n_heads
        else:
            first_head, stop_head = max(int(lo.min()) - 1, 0), int(lo.max()) + 1
        trunk = torch.cat([
            torch.addcmul(self.action_bias, a_bm.view(-1, 1), self.action_weight),
            first_layer[:, self.bm_width :],
            self.tapm.speed_fc(z_v),
        ], dim=1).relu_()
        heads = self._heads(trunk, first_head, stop_head)
        a_ref = np.concatenate([a_bm.numpy()[:, None], heads.numpy()], axis=1)
        # The sub-grid [0, heads' latencies] puts every sample in the same segment as the full grid
        # (all latencies lie above delta_ref[first_head + 1] when first_head > 0, and at most at
        # delta_ref[stop_head]), so the interpolation is the reference's, value for value.
        steering = interpolate_batch(latency_np, self._sub_grid(first_head, stop_head), a_ref)
        return PLMNetSteering(torch.from_numpy(steering), clamped)

    def _heads(self, trunk: torch.Tensor, first_head: int, stop_head: int) -> torch.Tensor:
        """:meth:`TAPM.heads` in eval mode, as four plain products: (B, 700) -> (B, stop - first)."""
        key = (first_head, stop_head)
        if key not in self._packed_heads:
            self._packed_heads[key] = _pack_heads(self.tapm, first_head, stop_head)
        (w_in, b_in), (w_hidden, b_hidden), (w_tanh, b_tanh), (w_out, b_out) = self._packed_heads[key]
        functional = torch.nn.functional
        hidden = functional.linear(trunk, w_in, b_in).relu_()
        hidden = functional.linear(hidden, w_hidden, b_hidden).relu_()
        hidden = functional.linear(hidden, w_tanh, b_tanh).tanh_()
        return functional.linear(hidden, w_out, b_out).tanh_()

    def _sub_grid(self, first_head: int, stop_head: int) -> np.ndarray:
        key = (first_head, stop_head)
        if key not in self._sub_grids:
            self._sub_grids[key] = np.concatenate(
                [self.delta_ref_s[:1], self.delta_ref_s[first_head + 1 : stop_head + 1]]
            )
        return self._sub_grids[key]


def _pack_heads(tapm: TAPM, first: int, stop: int) -> tuple[tuple[torch.Tensor, torch.Tensor], ...]:
    """(weight (out, in), bias) of heads ``first .. stop - 1``, layer by layer, as ``F.linear`` takes them.

    The grouped layers become block-diagonal matrices (head h's block maps head h's units only), so
    that the heads run as four products with no reshaping: at batch size 1 the number of operations,
    not their arithmetic, is the cost. The zero blocks add exact zeros.
    """
    width = tapm.heads_in.out_features // tapm.config.n_heads
    rows = slice(first * width, stop * width)
    with torch.no_grad():
        layers = [(tapm.heads_in.weight[rows].clone(), tapm.heads_in.bias[rows].clone())]
        for grouped in (tapm.heads_hidden, tapm.heads_tanh, tapm.heads_out):
            blocks = [weight.T for weight in grouped.weight[first:stop]]  # (in, out) per head -> (out, in)
            layers.append((torch.block_diag(*blocks).contiguous(), grouped.bias[first:stop].reshape(-1).clone()))
    return tuple(layers)
