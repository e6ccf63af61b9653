"""Batch-invariant kernels: a sample's outputs do not depend on the other samples in its batch.

PyTorch's CPU kernels pick their algorithm by shape, and the batch size is part of the shape:
at batch size 1 the two 3x3 convolutions run PyTorch's own im2col + GEMM, at larger batches
oneDNN (or NNPACK from 16 samples on); MKL's GEMM takes a matrix-vector path for 1-3 rows and
for a single output column a path whose summation order changes with the number of rows. Each
choice sums in its own order, so a sample's steering differs by ~1e-6 between batch size 1 and
16, which a closed loop amplifies (a rendered pixel moves a step sooner or later). This is the
idea of Thinking Machines' "batch-invariant ops" (He et al., 2025, "Defeating Nondeterminism in
LLM Inference"): give every sample the same reduction order whatever the batch size.

Inside :func:`batch_invariant_ops` (one torch thread):

- ``conv2d`` always runs oneDNN's direct convolution (``aten.mkldnn_convolution``), at every
  batch size: its per-output reduction order is set by the layer's shape, not by the batch size;
- ``linear`` runs as products of exactly 8 rows (:data:`ROWS_PER_PRODUCT`; zero rows fill the last),
  one shape whatever the batch size, with the inputs and weights padded by zero columns to a
  multiple of 16 values so that every row starts on a 64-byte boundary (MKL's path depends on
  alignment too). A row's sums then do not depend on its position in the product nor on the other rows.

Every other operation the models use is element-wise (exact IEEE operations, or ``tanh``, whose
vector and scalar kernels agree) or a min/max. What makes this hold is MKL's and oneDNN's kernel
choice, which no documentation promises: ``tests/test_batch_invariant.py`` checks it for the
layer shapes of both presets and both model policies at many batch compositions, and
``tests/test_batched.py`` checks whole closed-loop runs column by column. Cost: measured by
``plm-highway bench sweep`` (the one-env side with and without these kernels). Row by row (the
first form of this module) gave up the batched product's reuse of the weights: a third of a
16-env batched step went to the products.
"""

from __future__ import annotations

import contextlib
import threading
import weakref
from collections.abc import Iterator

import torch
import torch.nn.functional as F
from torch.overrides import TorchFunctionMode

ROW_ALIGNMENT = 16  # float32 values: 64 bytes
# Rows per matrix product. 8 keeps most of a batched product's speed (16 rows of the default preset's
# fused first layer: 1.17 ms, against 2.26 ms row by row and 0.83 ms in one product) at a moderate
# cost for a batch of one (0.54 ms against 0.12 ms for the one-row product); measured on 2 quiet cores.
ROWS_PER_PRODUCT = 8


def conv2d(input, weight, bias=None, stride=1, padding=0, dilation=1, groups=1):
    """``F.conv2d`` through oneDNN's direct convolution whatever the batch size (float32, numeric padding)."""
    if isinstance(padding, str) or input.dtype != torch.float32 or input.device.type != "cpu" or input.dim() != 4:
        return F.conv2d(input, weight, bias, stride, padding, dilation, groups)
    return torch.ops.aten.mkldnn_convolution(input.contiguous(), weight.contiguous(), bias, _pair(padding),
                                             _pair(stride), _pair(dilation), groups)


def linear(input, weight, bias=None):
    """``F.linear`` whose rows do not depend on how many rows are computed together, nor where.

    The rows go through products of exactly :data:`ROWS_PER_PRODUCT` rows (zero rows fill the last),
    so MKL sees one shape, hence one kernel and one summation order, at every batch size; a batch of
    one pays for ``ROWS_PER_PRODUCT`` rows (compute that a memory-bound one-row product mostly
    hides), a batch of 16 gets most of a 16-row product's reuse of the weights. The outputs are padded
    too, to a multiple of :data:`ROW_ALIGNMENT`: with 2 or 3 outputs MKL's AVX-512 path sums a row
    differently depending on the other rows of the product (measured on a Xeon with AVX-512; from
    16 outputs on, and at 1, 5 or 10, it does not).
    """
    rows = input.reshape(-1, input.shape[-1])
    n_rows, width = rows.shape
    n_out = weight.shape[0]
    padded_width = -(-width // ROW_ALIGNMENT) * ROW_ALIGNMENT
    padded_out = -(-n_out // ROW_ALIGNMENT) * ROW_ALIGNMENT
    padded_rows = -(-n_rows // ROWS_PER_PRODUCT) * ROWS_PER_PRODUCT
    # A fresh buffer whose rows all start on a 64-byte boundary: MKL's path depends on alignment too.
    buffer = rows.new_zeros(padded_rows, padded_width)
    buffer[:n_rows, :width] = rows
    weight = _padded(weight, (padded_out, padded_width))
    if bias is not None:
        bias = _padded(bias, (padded_out,))
    out = torch.cat([F.linear(buffer[start : start + ROWS_PER_PRODUCT], weight, bias)
                     for start in range(0, padded_rows, ROWS_PER_PRODUCT)])
    return out[:n_rows, :n_out].reshape(*input.shape[:-1], n_out)


_PADDED: dict[int, tuple[weakref.ref, int, tuple[int, ...], torch.Tensor]] = {}
_PADDED_LOCK = threading.Lock()


def _padded(tensor: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """``tensor`` with zeros appended along each dimension up to ``shape``, kept while ``tensor`` lives
    unchanged (a model's layers are padded once, not at every step)."""
    if tuple(tensor.shape) == shape:
        return tensor
    # Inference tensors (weights a model packs inside inference mode) have no version counter; they
    # are caches built once, never changed in place.
    version = -1 if torch.is_inference(tensor) else tensor._version
    with _PADDED_LOCK:
        entry = _PADDED.get(id(tensor))
        if entry is not None and entry[0]() is tensor and entry[1] == version and entry[2] == shape:
            return entry[3]
        pads = [amount for size, target in zip(reversed(tensor.shape), reversed(shape)) for amount in (0, target - size)]
        padded = F.pad(tensor, pads)
        for key in [k for k, (ref, *_) in _PADDED.items() if ref() is None]:
            del _PADDED[key]
        _PADDED[id(tensor)] = (weakref.ref(tensor), version, shape, padded)
        return padded


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
