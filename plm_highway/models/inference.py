"""Closed-loop policies: (frame uint8 (H, W), speed m/s, latency s) -> normalised steering.

Both policies run under ``torch.inference_mode`` with the model in eval mode and take the latency,
so that the evaluation code can swap them; the BM ignores it (it is the unmitigated baseline).

Two calls:

- ``policy(frame, speed_mps, latency_s) -> float``: one frame (batch size 1), as one env steps.
- ``policy.steer_batch(frames, speeds_mps, latencies_s) -> np.ndarray``: frames uint8 (B, H, W),
  speeds (B,), latencies (B,) -> steering (B,) float64, for B envs stepped together. One forward
  pass. Per sample it equals the batch-1 call up to float rounding, not bit for bit: the BLAS and
  oneDNN kernels pick their summation order by batch size (measured: |difference| below 1e-6
  on steering with the shipped checkpoints). With ``batch_invariant=True`` the policy runs its
  convolutions and products with :func:`~plm_highway.models.batch_invariant.batch_invariant_ops`
  (one torch thread): a sample's output is then bit-identical whatever else is in the
  batch (PLM-Net then evaluates every TAPM head, so that its products have one width whatever the
  batch's latencies).

``device``: where the model and its input tensors live (``"cpu"``, ``"cuda"``, ``"auto"``: see
:func:`~plm_highway.models.device.resolve_device`; None, the default: wherever the model already is). The
policy moves the model there; frames and speeds go there per call; steering comes back to the host (a
float, or a float64 numpy array). The batch-invariant kernels are CPU kernels: on a GPU
``batch_invariant=True`` runs the same 8-row products through cuBLAS and cuDNN's convolutions, with no
promise that a sample's result is independent of its batch (nothing here checks it on a GPU).

Inputs are checked: frames uint8 of the model's size, finite speeds, finite latencies >= 0, and
at most :data:`MAX_BATCH` samples. A non-finite steering output (NaN weights that slipped past the
checkpoint checks, an input the model cannot handle) raises :class:`NonFiniteSteeringError`
naming the sample: a run must stop there rather than drive on NaN.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np
import torch

from plm_highway.errors import BadInput
from plm_highway.models.base_model import BaseModel
from plm_highway.models.batch_invariant import batch_invariant_ops
from plm_highway.models.device import module_device, resolve_device
from plm_highway.models.plm_net import FusedPLMNet, PLMNet

MAX_BATCH = 4096


class NonFiniteSteeringError(ValueError):
    """A policy produced NaN or infinite steering."""


class _Policy:
    """Input checks, the batch-1 call and the non-finite check shared by both policies."""

    name = "policy"
    max_latency_s = math.inf  # latencies above this use the last head (PLM-Net); inf: never clamped

    def __init__(self, image_size_px: tuple[int, int], batch_invariant: bool, device: torch.device):
        self.image_size_px = tuple(image_size_px)
        self.batch_invariant = bool(batch_invariant)
        self.device = device
        self._on_host = device.type == "cpu"  # inputs and outputs need no copy
        self.clamped_latency_count = 0

    def reset(self) -> None:
        self.clamped_latency_count = 0

    def __call__(self, frame: np.ndarray, speed_mps: float, latency_s: float = 0.0) -> float:
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.shape != self.image_size_px:
            raise BadInput(f"frame: expected uint8 {self.image_size_px}, got {frame.dtype} {frame.shape}")
        return float(self.steer_batch(frame[None], [speed_mps], [latency_s])[0])

    def steer_batch(self, frames: np.ndarray, speeds_mps, latencies_s=None) -> np.ndarray:
        """Frames uint8 (B, H, W), speeds (B,) m/s, latencies (B,) s (default 0) -> steering (B,) float64."""
        frames_t, speeds_t, latencies = self._checked_batch(frames, speeds_mps, latencies_s)
        with torch.inference_mode(), (batch_invariant_ops() if self.batch_invariant else contextlib.nullcontext()):
            steering = self._forward(frames_t, speeds_t, latencies)
        steering_np = (steering if self._on_host else steering.cpu()).numpy().astype(np.float64)
        if not np.all(np.isfinite(steering_np)):
            i = int(np.flatnonzero(~np.isfinite(steering_np))[0])
            raise NonFiniteSteeringError(
                f"{self.name} policy: steering is {steering_np[i]} for sample {i} (speed {float(speeds_t[i])} m/s, "
                f"latency {float(latencies[i])} s); the model's weights or configuration are not usable"
            )
        return steering_np

    def _forward(self, frames: torch.Tensor, speeds_mps: torch.Tensor, latencies_s: np.ndarray) -> torch.Tensor:
        raise NotImplementedError

    def _checked_batch(self, frames, speeds_mps, latencies_s) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
        frames = np.asarray(frames)
        if frames.dtype != np.uint8 or frames.ndim != 3 or frames.shape[1:] != self.image_size_px:
            raise BadInput(
                f"frames: expected uint8 (B, {self.image_size_px[0]}, {self.image_size_px[1]}), "
                f"got {frames.dtype} {frames.shape}"
            )
        n = len(frames)
        if not 1 <= n <= MAX_BATCH:
            raise BadInput(f"frames: batch size must lie in [1, {MAX_BATCH}], got {n}")
        speeds = _column("speeds_mps", speeds_mps, n)
        if not np.all(np.isfinite(speeds)):
            raise BadInput(f"speeds_mps: must be finite, got {speeds[~np.isfinite(speeds)][0]}")
        latencies = np.zeros(n, np.float32) if latencies_s is None else _column("latencies_s", latencies_s, n)
        if not np.all(np.isfinite(latencies) & (latencies >= 0)):
            bad = latencies[~(np.isfinite(latencies) & (latencies >= 0))][0]
            raise BadInput(f"latency_s: must be a finite number >= 0 s, got {bad}")
        # Sharing memory with a contiguous frame batch: no copy at batch size 1 on the CPU.
        frames_t, speeds_t = torch.from_numpy(np.ascontiguousarray(frames)), torch.from_numpy(speeds)
        if not self._on_host:
            frames_t, speeds_t = frames_t.to(self.device), speeds_t.to(self.device)
        return frames_t, speeds_t, latencies


def _column(name: str, values, n: int) -> np.ndarray:
    try:
        column = np.asarray(values, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise BadInput(f"{name}: expected {n} numbers, got {values!r}") from exc
    if column.shape != (n,):
        raise BadInput(f"{name}: expected shape ({n},), one per frame, got {column.shape}")
    return column


class BaseModelPolicy(_Policy):
    name = "BM"

    def __init__(self, bm: BaseModel, batch_invariant: bool = False, device: str | torch.device | None = None):
        device = module_device(bm) if device is None else resolve_device(device)
        super().__init__(bm.config.image_size_px, batch_invariant, device)
        self.model = bm.to(device).eval()

    def _forward(self, frames, speeds_mps, latencies_s):
        return self.model(frames, speeds_mps)


class PLMNetPolicy(_Policy):
    """PLM-Net; counts the samples whose latency was above the TAPM grid (the last head was used).

    ``fused=True`` (default) runs :class:`~plm_highway.models.plm_net.FusedPLMNet`, the inference
    form; ``False`` runs :meth:`PLMNet.forward` itself (every head), the reference it is checked against.
    ``tapm_int8=True`` (fused only) runs the TAPM's image branch and heads' first layers in int8, an
    approximation that pays on the paper preset (see ``FusedPLMNet``); the BM's part stays exact. It
    has no batch-invariant form: ``batch_invariant`` needs it off.
    """

    name = "PLM-Net"

    def __init__(self, plm_net: PLMNet, batch_invariant: bool = False, fused: bool = True, tapm_int8: bool = False,
                 device: str | torch.device | None = None):
        device = module_device(plm_net) if device is None else resolve_device(device)
        super().__init__(plm_net.bm.config.image_size_px, batch_invariant, device)
        if tapm_int8 and not fused:
            raise BadInput("tapm_int8: the int8 TAPM is a form of the fused inference; it needs fused=True")
        if tapm_int8 and batch_invariant:
            raise BadInput("tapm_int8: the int8 TAPM has no batch-invariant form; it needs batch_invariant=False")
        self.model = plm_net.to(device).eval()
        self.fused = FusedPLMNet(plm_net, tapm_int8=tapm_int8) if fused else None
        self.max_latency_s = plm_net.last_grid_s

    def _forward(self, frames, speeds_mps, latencies_s):
        if self.fused is None:
            output = self.model(frames, speeds_mps, torch.from_numpy(latencies_s).to(frames.device))
            self.clamped_latency_count += output.n_clamped
            return output.steering
        output = self.fused(frames, speeds_mps, latencies_s, batch_invariant=self.batch_invariant)
        self.clamped_latency_count += output.n_clamped
        return output.steering
