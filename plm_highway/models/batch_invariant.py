"""Batch-invariant kernels: a sample's outputs do not depend on the other samples in its batch.

PyTorch's CPU kernels pick their algorithm by shape, and the batch size is part of the shape:
at batch size 1 the two 3x3 convolutions run PyTorch's own im2col + GEMM, at larger batches
oneDNN (or NNPACK from 16 samples on); MKL's GEMM takes a matrix-vector path for 1-3 rows and
for a single output column a path whose summation order changes with the number of rows. Each
choice sums in its own order, so a sample's steering differs by ~1e-6 between batch size 1 and
16, which a closed loop amplifies (a rendered pixel moves a step sooner or later). This is the
idea of Thinking Machines' "batch-invariant ops" (He et al., 2025, "Defeating Nondeterminism in
LLM Inference"): give every sample the same reduction order whatever the batch size.

Inside :func:`batch_invariant_ops`:

- ``conv2d`` always runs oneDNN's direct convolution (``aten.mkldnn_convolution``), at every
  batch size: its per-output reduction order is set by the layer's shape, not by the batch size
  or the thread count;
- ``linear`` with one output column runs row by row (each row is the batch-1 product); a product
  of fewer than :data:`MIN_GEMM_ROWS` rows is padded with zero rows to that many, so MKL always
  takes its matrix-matrix path, whose per-element order does not depend on the number of rows.

Every other operation the models use is element-wise (exact IEEE operations, or ``tanh``, whose
vector and scalar kernels agree) or a cheap min/max. What makes this hold is MKL's and oneDNN's
kernel choice, which no documentation promises: ``tests/test_batch_invariant.py`` checks it for
every layer shape of both presets and both models, at batch sizes 1-70 and one or two threads,
and the closed-loop tests check whole runs step by step. Cost: the convolutions cost what they
cost at that batch size with oneDNN; a one-row product costs a 4-row one (both read the weights once).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
import torch.nn.functional as F
from torch.overrides import TorchFunctionMode

MIN_GEMM_ROWS = 4  # MKL's sgemm takes another path for 1-3 rows (measured, MKL 2024.2, AVX2)
ROW_ALIGNMENT = 16  # float32 values: 64 bytes


def conv2d(input, weight, bias=None, stride=1, padding=0, dilation=1, groups=1):
    """``F.conv2d`` through oneDNN's direct convolution whatever the batch size (float32, numeric padding)."""
    if isinstance(padding, str) or input.dtype != torch.float32 or input.device.type != "cpu" or input.dim() != 4:
        return F.conv2d(input, weight, bias, stride, padding, dilation, groups)
    return torch.ops.aten.mkldnn_convolution(input.contiguous(), weight.contiguous(), bias, _pair(padding),
                                             _pair(stride), _pair(dilation), groups)


def linear(input, weight, bias=None):
    """``F.linear`` whose rows do not depend on how many rows are computed together, nor where."""
    rows = input.reshape(-1, input.shape[-1])
    n_rows, width = rows.shape
    padded_width = -(-width // ROW_ALIGNMENT) * ROW_ALIGNMENT
    if padded_width != width:  # every row starts on a 64-byte boundary: MKL's path depends on alignment
        rows = F.pad(rows, (0, padded_width - width))
        weight = F.pad(weight, (0, padded_width - width))
    if weight.shape[0] == 1:
        out = torch.cat([F.linear(rows[i : i + 1], weight, bias) for i in range(n_rows)])
    elif n_rows < MIN_GEMM_ROWS:
        padded = torch.cat([rows, rows.new_zeros(MIN_GEMM_ROWS - n_rows, rows.shape[1])])
        out = F.linear(padded, weight, bias)[:n_rows]
    else:
        out = F.linear(rows, weight, bias)
    return out.reshape(*input.shape[:-1], weight.shape[0])


def _pair(value) -> list[int]:
    return [int(value), int(value)] if isinstance(value, int) else [int(v) for v in value]


class _BatchInvariantMode(TorchFunctionMode):
    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if func is F.conv2d:
            return conv2d(*args, **kwargs)
        if func is F.linear:
            return linear(*args, **kwargs)
        return func(*args, **kwargs)


@contextlib.contextmanager
def batch_invariant_ops() -> Iterator[None]:
    """Run ``conv2d`` and ``linear`` batch-invariantly inside the block, on one torch thread.

    One thread because MKL splits a product over two threads differently for different row
    counts; to use more cores, run batches side by side (threads or processes), each on one.
    The mode is per Python thread; the torch thread count is the process's, restored after.
    """
    previous = torch.get_num_threads()
    if previous != 1:
        torch.set_num_threads(1)
    try:
        with _BatchInvariantMode():
            yield
    finally:
        if previous != 1:
            torch.set_num_threads(previous)
