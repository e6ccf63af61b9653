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
to it up to float rounding (measured: at most ~1.2e-7 apart on steering) and cheaper where PLM-Net's cost over
the BM lies: at batch size 1 on the CPU the BM's part is the BM's own calls and the TAPM's image
branch reads only the weight rows of the nonzero image features (z_o follows a ReLU: about 90% zeros
with the shipped checkpoints); in batches (and on a GPU) the BM's first FC layer and the TAPM's image
branch, which read the same features, run as one matrix product; only the heads that bracket each
sample's latency run (Algorithm 1 reads no others: one or two heads at batch size 1 instead of five),
the action and speed branches fold into one small product, and at batch size 1 the interpolation
runs in Python floats. Every tensor it builds follows the model's device and dtype.
``FusedPLMNet(plm_net, tapm_int8=True)`` is an approximation on top: the TAPM's large layers in
int8, the BM's part unchanged (see the class).
"""

from __future__ import annotations

import bisect
import warnings
from typing import NamedTuple

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

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
    dtype, device = a_ref_t.dtype, a_ref_t.device
    delta_ref_t = torch.as_tensor(delta_ref_s, dtype=dtype, device=device)
    latency_t = torch.as_tensor(latency_s, dtype=dtype, device=device)
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
    n_clamped: int  # clamped.sum()


# Batch size 1's two possible masks, read-only so that callers cannot change the shared arrays.
_ONE_CLAMPED = (np.zeros(1, bool), np.ones(1, bool))
for _mask in _ONE_CLAMPED:
    _mask.setflags(write=False)


class FusedPLMNet:
    """Inference-only PLM-Net, equal to :meth:`PLMNet.forward`'s steering up to float rounding.

    What it saves over :meth:`PLMNet.forward` (measured in the closed loop's setting, batch size 1,
    where every operation runs with cold caches and costs several times its isolated time):

    - at batch size 1 on the CPU (the closed loop's case, where reading the weights is the cost): the
      BM's part runs as the BM's own calls (``a_BM`` is the BM's, bit for bit) and the TAPM's image
      branch as a :class:`SparseInputLinear`, which reads only the weight rows of z_o's nonzero
      entries (z_o follows a ReLU; with the shipped checkpoints on the simulator's frames about 90% of
      it is zero, so the paper preset's 21.6 MB image branch reads about 2.4 MB per frame);
    - in batches, under the batch-invariant kernels and on a GPU (where a product's weights are
      reused across the batch, or a sparse product would stall on ``nonzero``): one product for the
      BM's first FC layer and the TAPM's image branch (both read z_o);
    - only the one or two heads that bracket each sample's latency (Algorithm 1 reads no others),
      as four plain products;
    - the TAPM's action and speed branches folded into one (B, 2) x (2, 200) product
      (:func:`fold_scalar_branches`); the heads' input columns permuted so the trunk is one
      concatenation;
    - at batch size 1 the latency check, the segment search and the interpolation in Python floats
      instead of ~25 numpy calls (larger batches use the vectorised :func:`interpolate_batch`).

    Built from a trained, frozen ``plm_net`` on its device: the fused first layer, the folded branches and
    the packed heads are copies taken then (~5 MB for the default preset, ~44 MB for the paper preset;
    the sparse image branch, built at the first one-sample call, another 2.3 / 21.6 MB), so a
    ``plm_net`` whose weights change (or move to another device) afterwards needs a new ``FusedPLMNet``.
    Runs under ``torch.inference_mode`` (no gradients); the steering comes back on the model's device.

    ``tapm_int8=True`` is an approximation: the TAPM's two large layers (the image branch, FC 500 on
    z_o, and the heads' first layers) run as int8 products (:class:`Int8Linear`) and read a quarter
    of the bytes, which is where the paper preset's cost lies (its image branch alone is 21.6 MB of
    fp32 weights per frame). The BM's layers stay fp32 and are the BM's own calls, so ``a_BM``
    (and the steering at latency 0) is bit-identical to the BM's; the heads' outputs move by up to
    ~1e-2 with the shipped checkpoints (``bench models --closed-loop`` reports the closed-loop MAE
    with and without it). PyTorch's quantised kernels run on the CPU only.
    """

    def __init__(self, plm_net: PLMNet, tapm_int8: bool = False):
        bm, tapm = plm_net.bm.eval(), plm_net.tapm.eval()
        self.bm, self.tapm = bm, tapm
        self.tapm_int8 = bool(tapm_int8)
        first, image_fc = bm.mlp[0], tapm.image_fc
        self.device, self.dtype = first.weight.device, first.weight.dtype
        if self.tapm_int8 and self.device.type != "cpu":
            raise BadInput(f"tapm_int8: the int8 TAPM runs on the CPU only (PyTorch's quantised kernels); this "
                           f"PLM-Net is on {self.device}")
        self.bm_width = first.out_features
        # One sample on the CPU: the BM's own calls and the sparse image branch (see the class docstring).
        self.sparse_one_sample = self.device.type == "cpu" and not self.tapm_int8
        self._sparse_image_fc: SparseInputLinear | None = None
        with torch.no_grad():
            if self.tapm_int8:
                # Apart from the BM's first layer: int8 and fp32 cannot share one product.
                self.image_fc = Int8Linear(image_fc.weight, image_fc.bias)
            else:
                # The TAPM reads z_o only: its rows get zero weights for the speed (and acceleration)
                # features, so one product over the BM's concatenated MLP input yields both layers.
                padding = first.weight.new_zeros(image_fc.out_features, first.in_features - image_fc.in_features)
                self.first_layer = Fp32Linear.of(
                    torch.cat([first.weight, torch.cat([image_fc.weight, padding], dim=1)]),
                    torch.cat([first.bias, image_fc.bias]),
                )
            branch_weight, branch_bias = fold_scalar_branches(bm, tapm)
            self.branches = Fp32Linear(branch_weight.t().contiguous(), branch_bias, branch_weight)  # (in, out)
            # The trunk is built as [image 500, action 100, speed 100] (one concatenation of two
            # parts); the heads' input columns are permuted to match.
            n_action, n_image = tapm.action_fc.out_features, image_fc.out_features
            # trunk_order[i]: the column of TAPM.trunk's output that this trunk's column i holds.
            self.trunk_order = torch.cat([
                torch.arange(n_action, n_action + n_image), torch.arange(n_action),
                torch.arange(n_action + n_image, tapm.heads_in.in_features),
            ]).to(self.device)
            self._heads_in_weight = tapm.heads_in.weight[:, self.trunk_order].contiguous()
        # PLMNet.delta_ref_s's float32 values, on the host (built from the config: the buffer may be on a GPU).
        self.delta_ref_s = np.array((0.0, *tapm.config.delta_grid_s), dtype=np.float32)
        self._interior_grid_s = self.delta_ref_s[1:-1]
        self._grid_s = self.delta_ref_s.tolist()  # the float32 values as Python floats, exactly
        self.last_grid_s = plm_net.last_grid_s
        self.n_heads = tapm.config.n_heads
        # Per contiguous head range (at most n (n + 1) / 2 of them, built when first needed).
        self._sub_grids: dict[tuple[int, int], np.ndarray] = {}
        self._device_sub_grids: dict[tuple[int, int], torch.Tensor] = {}
        self._packed_heads: dict[tuple[int, int], tuple] = {}

    def __call__(self, frames: torch.Tensor, speed_mps: torch.Tensor, latency_s,
                 batch_invariant: bool = False) -> PLMNetSteering:
        """Frames uint8 (B, H, W), speed (B,) m/s, latency (B,) s (tensor or array) -> steering (B,).

        ``batch_invariant=True``: the form for :func:`~plm_highway.models.batch_invariant.batch_invariant_ops`
        (the caller enters it). Every head is evaluated whenever a latency is above 0, every product goes
        through ``F.linear`` (which those kernels replace) and batch size 1 takes the batch path, so a
        sample's steering does not depend on the batch's size nor on the other samples' latencies.
        """
        if batch_invariant and self.tapm_int8:
            raise ValueError("the int8 TAPM has no batch-invariant form")
        if torch.is_inference_mode_enabled():  # the policies' case: entering it again costs an op's time
            return self._steer(frames, speed_mps, latency_s, batch_invariant)
        with torch.inference_mode():
            return self._steer(frames, speed_mps, latency_s, batch_invariant)

    def _steer(self, frames: torch.Tensor, speed_mps: torch.Tensor, latency_s, batch_invariant: bool) -> PLMNetSteering:
        latency_np = np.asarray(latency_s, dtype=np.float32).reshape(-1)
        if len(latency_np) != len(frames):
            raise BadInput(f"latency_s: expected one latency per frame ({len(frames)}), got {len(latency_np)}")
        one_sample = len(latency_np) == 1 and not batch_invariant
        if one_sample:
            latency = float(latency_np[0])  # the float32 value, exactly
            if not latency >= 0:  # NaN fails the comparison too
                raise BadInput(f"latency_s: must be a number >= 0 s, got {latency}")
            clamped = _ONE_CLAMPED[latency > self.last_grid_s]
            n_clamped = int(latency > self.last_grid_s)
            any_latency = latency > 0
        else:
            clamped = check_latency_array(latency_np, self.last_grid_s)
            n_clamped = int(clamped.sum())
            any_latency = latency_np.any()
        z_o, z_v = self.bm.encode(frames, speed_mps)
        sparse = one_sample and self.sparse_one_sample
        if self.tapm_int8 or sparse:  # the BM's own calls: a_BM is the BM's, bit for bit
            a_bm = self.bm.steering_from_features(z_o, z_v)
        else:
            first_layer = self.first_layer.apply(self.bm.mlp_input(z_o, z_v), batch_invariant)
            a_bm = self.bm.steering_from_first_layer(first_layer[:, : self.bm_width])
        if not any_latency:  # every latency 0: Algorithm 1 returns a_BM, no head is needed
            return PLMNetSteering(a_bm, clamped, n_clamped)
        if batch_invariant:
            first_head, stop_head = 0, self.n_heads
        elif one_sample:
            # Segment [lo, lo + 1] of delta_ref, as interpolate_batch finds it (lo = 0: latency in (0, 0.15]).
            lo = min(bisect.bisect_left(self._grid_s, latency), len(self._grid_s) - 1) - 1
            first_head, stop_head = max(lo - 1, 0), lo + 1
        else:
            # Grid segment of each sample, as interpolate_batch finds it: a_ref entries lo and lo + 1,
            # i.e. heads lo - 1 (none for lo = 0: the BM) and lo.
            lo_np = np.searchsorted(self._interior_grid_s, np.minimum(latency_np, np.float32(self.last_grid_s)))
            first_head, stop_head = max(int(lo_np.min()) - 1, 0), int(lo_np.max()) + 1
        if self.tapm_int8:
            image_features = self.image_fc(z_o)
        elif sparse:
            image_features = self.sparse_image_fc()(z_o)
        else:
            image_features = first_layer[:, self.bm_width :]
        branches = self.branches.apply(torch.stack((a_bm, speed_mps.to(a_bm.dtype)), dim=1), batch_invariant)
        heads = self._heads(torch.cat([image_features, branches], dim=1).relu_(), first_head, stop_head,
                            batch_invariant)
        if one_sample:
            value = self._interpolate_one(latency, lo, float(a_bm), heads.tolist()[0])
            steering = torch.tensor([value], dtype=a_bm.dtype, device=a_bm.device)
            return PLMNetSteering(steering, clamped, n_clamped)
        # The sub-grid [0, heads' latencies] puts every sample in the same segment as the full grid
        # (all latencies lie above delta_ref[first_head + 1] when first_head > 0, and at most at
        # delta_ref[stop_head]), so the interpolation is the reference's, value for value.
        if a_bm.device.type != "cpu":  # on the device, where the actions are (the same IEEE operations)
            a_ref = torch.cat([a_bm[:, None], heads], dim=1)
            latency = torch.from_numpy(latency_np).to(a_bm.device)
            steering = interpolate_batch(latency, self._device_sub_grid(first_head, stop_head), a_ref)
            return PLMNetSteering(steering, clamped, n_clamped)
        a_ref = np.concatenate([a_bm.numpy()[:, None], heads.numpy()], axis=1)
        steering = interpolate_batch(latency_np, self._sub_grid(first_head, stop_head), a_ref)
        return PLMNetSteering(torch.from_numpy(steering), clamped, n_clamped)

    def sparse_image_fc(self) -> SparseInputLinear:
        """The TAPM's image branch as a :class:`SparseInputLinear` (built at the first call: 2.3 MB of
        weights for the default preset, 21.6 MB for the paper preset)."""
        if self._sparse_image_fc is None:
            image_fc = self.tapm.image_fc
            with torch.no_grad():
                self._sparse_image_fc = SparseInputLinear.of(image_fc.weight, image_fc.bias)
        return self._sparse_image_fc

    def _interpolate_one(self, latency: float, lo: int, a_bm: float, heads: list[float]) -> float:
        """:func:`interpolate_batch` for one sample in segment ``lo``, in float64 (the result is then
        rounded to float32: within a float32 rounding of the reference's float32 arithmetic)."""
        a_lo, a_hi = (a_bm, heads[0]) if lo == 0 else (heads[0], heads[1])
        delta_lo, delta_hi = self._grid_s[lo], self._grid_s[lo + 1]
        latency = min(latency, delta_hi)  # above the grid: the last head
        if latency == delta_hi:  # a grid point returns its action bit-exactly
            return a_hi
        value = a_lo + (latency - delta_lo) / (delta_hi - delta_lo) * (a_hi - a_lo)
        return min(max(value, min(a_lo, a_hi)), max(a_lo, a_hi))

    def _heads(self, trunk: torch.Tensor, first_head: int, stop_head: int, batch_invariant: bool = False
               ) -> torch.Tensor:
        """:meth:`TAPM.heads` in eval mode, as four plain products: (B, 700) -> (B, stop - first).

        ``trunk`` is ordered [image, action, speed] (see ``__init__``), not as :meth:`TAPM.trunk`.
        """
        key = (first_head, stop_head)
        if key not in self._packed_heads:
            self._packed_heads[key] = self._pack_heads(first_head, stop_head)
        heads_in, hidden_layer, tanh_layer, out_layer = self._packed_heads[key]
        hidden = heads_in.apply(trunk, batch_invariant).relu_()
        hidden = hidden_layer.apply(hidden, batch_invariant).relu_()
        return out_layer.apply(tanh_layer.apply(hidden, batch_invariant).tanh_(), batch_invariant).tanh_()

    def _pack_heads(self, first_head: int, stop_head: int) -> tuple:
        heads_in_bias, *later = _pack_heads(self.tapm, first_head, stop_head)
        width = len(heads_in_bias) // (stop_head - first_head)
        weight = self._heads_in_weight[first_head * width : stop_head * width]
        heads_in = Int8Linear(weight, heads_in_bias) if self.tapm_int8 else Fp32Linear.of(weight, heads_in_bias)
        return (heads_in, *(Fp32Linear.of(weight, bias) for weight, bias in later))

    def _sub_grid(self, first_head: int, stop_head: int) -> np.ndarray:
        key = (first_head, stop_head)
        if key not in self._sub_grids:
            self._sub_grids[key] = np.concatenate(
                [self.delta_ref_s[:1], self.delta_ref_s[first_head + 1 : stop_head + 1]]
            )
        return self._sub_grids[key]

    def _device_sub_grid(self, first_head: int, stop_head: int) -> torch.Tensor:
        key = (first_head, stop_head)
        if key not in self._device_sub_grids:
            self._device_sub_grids[key] = torch.from_numpy(self._sub_grid(first_head, stop_head)).to(self.device)
        return self._device_sub_grids[key]


def fold_scalar_branches(bm: BaseModel, tapm: TAPM) -> tuple[torch.Tensor, torch.Tensor]:
    """The TAPM's action and speed branches as one map of (a_BM, speed m/s): weight (2, 200), bias (200,).

    Both are affine in a scalar before their ReLU: a_BM -> FC 100 directly, and the speed through
    z_v = speed_embedding(speed / scale) (linear, no activation) -> FC 100, so
    ``[a_BM, speed] @ weight + bias`` equals ``[action_fc(a_BM), speed_fc(z_v)]``. Folded in
    float64 and rounded once: one (B, 2) product replaces the two layers and the embedding.
    """
    action_fc, speed_fc, embedding = tapm.action_fc, tapm.speed_fc, bm.speed_embedding
    n_action, n_speed = action_fc.out_features, speed_fc.out_features
    speed_weight = speed_fc.weight.double()
    weight = torch.zeros(2, n_action + n_speed, dtype=torch.float64, device=speed_weight.device)
    weight[0, :n_action] = action_fc.weight.double()[:, 0]
    weight[1, n_action:] = speed_weight @ embedding.weight.double()[:, 0] / bm.config.speed_scale_mps
    bias = torch.cat([action_fc.bias.double(), speed_weight @ embedding.bias.double() + speed_fc.bias.double()])
    dtype = action_fc.weight.dtype  # the model's (float32 unless it was converted)
    return weight.to(dtype), bias.to(dtype)


class Fp32Linear(NamedTuple):
    """A linear layer as one ``addmm`` (``F.linear`` dispatches a transpose and then ``addmm``), or through
    ``F.linear`` for batch-invariant runs (:mod:`plm_highway.models.batch_invariant` replaces it)."""

    weight: torch.Tensor  # (out, in), contiguous, as nn.Linear holds it
    bias: torch.Tensor  # (out,)
    weight_in_out: torch.Tensor  # (in, out), as addmm reads it

    @classmethod
    def of(cls, weight: torch.Tensor, bias: torch.Tensor) -> Fp32Linear:
        """From ``nn.Linear``'s layout, weight (out, in)."""
        weight = weight.detach().contiguous()
        return cls(weight, bias.detach().contiguous(), weight.t())

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return torch.addmm(self.bias, x, self.weight_in_out)

    def apply(self, x: torch.Tensor, batch_invariant: bool) -> torch.Tensor:
        return torch.nn.functional.linear(x, self.weight, self.bias) if batch_invariant else self(x)


# Nonzero inputs per partial sum of SparseInputLinear: the partial sums are then added in a second
# pass, which keeps the rounding error near a dense product's (one running sum over 1,000-6,000
# terms drifted 5-7x further from the exact value than MKL's dense product, measured at 10% and 50% nonzero).
SPARSE_CHUNK = 32


class SparseInputLinear(NamedTuple):
    """A linear layer on one sample whose input is mostly zero (features after a ReLU): it reads only the
    weight rows of the nonzero inputs, where a dense product reads every weight.

    ``F.embedding_bag`` with per-sample weights does the gather and the weighted sum in one pass over
    those rows (the weight is stored (in, out), a contiguous row per input feature): the nonzero inputs
    in bags of :data:`SPARSE_CHUNK`, each bag's weighted sum a partial sum, the partial sums then added.
    Equal to the dense product up to float rounding (another summation order: within a few 1e-7 of the
    exact sum at the paper preset's 10,816 inputs, as MKL's dense product is). At batch size 1 the cost
    is reading the weights, so it costs about the nonzero fraction of the dense product's time.
    """

    weight_in_out: torch.Tensor  # (in, out), contiguous: one row per input feature
    bias: torch.Tensor  # (out,)
    offsets: torch.Tensor  # (ceil(in / SPARSE_CHUNK),): the bags' starts, sliced per call

    @classmethod
    def of(cls, weight: torch.Tensor, bias: torch.Tensor) -> SparseInputLinear:
        """From ``nn.Linear``'s layout, weight (out, in)."""
        weight = weight.detach()
        offsets = torch.arange(0, weight.shape[1], SPARSE_CHUNK, device=weight.device)
        return cls(weight.t().contiguous(), bias.detach().contiguous(), offsets)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """x (1, in) -> (1, out)."""
        row = x.view(-1)
        nonzero = row.nonzero().view(-1)
        n_bags = -(-len(nonzero) // SPARSE_CHUNK)
        if n_bags == 0:  # every input zero: the bias alone, as the dense product gives
            return self.bias.unsqueeze(0).clone()
        partial = F.embedding_bag(nonzero, self.weight_in_out, self.offsets[:n_bags], mode="sum",
                                  per_sample_weights=row.index_select(0, nonzero))
        return torch.add(self.bias, partial.sum(0, keepdim=True))


class Int8Linear:
    """``F.linear`` with int8 weights (one scale per output row) and dynamically quantised inputs.

    PyTorch's dynamic quantised linear (fbgemm / oneDNN on x86): per call, the input is quantised
    to 7-bit unsigned integers over its own range (``reduce_range``: x86's 16-bit pair sums cannot
    overflow), multiplied in int8 and rescaled, the bias added in fp32. Reads a quarter of the fp32
    weight bytes, which pays where a layer is memory-bound (batch size 1, large weights).
    """

    def __init__(self, weight: torch.Tensor, bias: torch.Tensor):
        weight = weight.detach().float()
        scales = (weight.abs().amax(dim=1) / 127).clamp_min(torch.finfo(torch.float32).tiny).double()
        zero_points = torch.zeros(len(weight), dtype=torch.int64)
        with warnings.catch_warnings():
            # PyTorch 2.13 flags quantised tensor creation as deprecated; the packed weight is all we keep.
            warnings.simplefilter("ignore", UserWarning)
            quantised = torch.quantize_per_channel(weight, scales, zero_points, 0, torch.qint8)
            self._packed = torch.ops.quantized.linear_prepack(quantised, bias.detach().float().contiguous())
        self.out_features, self.in_features = weight.shape

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return torch.ops.quantized.linear_dynamic(x, self._packed, True)

    def apply(self, x: torch.Tensor, batch_invariant: bool) -> torch.Tensor:
        """As :meth:`Fp32Linear.apply`; there is no batch-invariant int8 product (the input's range is the batch's)."""
        if batch_invariant:
            raise ValueError("Int8Linear has no batch-invariant form")
        return self(x)


def _pack_heads(tapm: TAPM, first: int, stop: int) -> tuple:
    """Heads ``first .. stop - 1``, layer by layer: the first layer's bias, then (weight (out, in),
    bias) of the three later layers, as ``F.linear`` takes them (the first layer's weight columns
    are permuted by the caller).

    The grouped layers become block-diagonal matrices (head h's block maps head h's units only), so
    that the heads run as four products with no reshaping: at batch size 1 the number of operations,
    not their arithmetic, is the cost. The zero blocks add exact zeros.
    """
    width = tapm.heads_in.out_features // tapm.config.n_heads
    with torch.no_grad():
        layers: list = [tapm.heads_in.bias[first * width : stop * width].clone()]
        for grouped in (tapm.heads_hidden, tapm.heads_tanh, tapm.heads_out):
            blocks = [weight.T for weight in grouped.weight[first:stop]]  # (in, out) per head -> (out, in)
            layers.append((torch.block_diag(*blocks).contiguous(), grouped.bias[first:stop].reshape(-1).clone()))
    return tuple(layers)
