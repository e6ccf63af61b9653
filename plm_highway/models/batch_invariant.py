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
  a whole stack of convolutions (:func:`conv_stack`, which the Base Model's ``encode`` takes inside
  the mode and whenever no gradient is needed) keeps its activations in oneDNN's own blocked layout between layers: the same kernels
  and the same values bit for bit, without converting every activation to and from NCHW (12% of
  the stack's time at 16 frames of 66x200 px on an AVX-512 Xeon);
- ``linear`` runs as products of exactly 8 rows (:data:`ROWS_PER_PRODUCT`; zero rows fill the last;
  on weights packed once for MKL, :data:`MKL_PACKED_PRODUCTS`), one shape whatever the batch size,
  with the inputs and weights padded by zero columns (and the outputs to a multiple of 16) to a
  multiple of 16 values so that every row starts on a 64-byte boundary (MKL's path depends on
  alignment too). A row's sums then do not depend on its position in the product nor on the other rows.

On a GPU the mode runs the same 8-row products through ``F.linear`` (cuBLAS) and leaves the
convolutions to cuDNN; nothing here checks batch invariance there.

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
from torch import nn
from torch.overrides import TorchFunctionMode

ROW_ALIGNMENT = 16  # float32 values: 64 bytes
# Rows per matrix product. 8 keeps most of a batched product's speed (16 rows of the default preset's
# fused first layer: 1.17 ms, against 2.26 ms row by row and 0.83 ms in one product) at a moderate
# cost for a batch of one (0.54 ms against 0.12 ms for the one-row product); measured on 2 quiet cores.
ROWS_PER_PRODUCT = 8
# The products run on weights packed once for MKL's GEMM at ROWS_PER_PRODUCT rows (the packed-weight
# path PyTorch's own compiler uses on CPUs): an 8-row product of the default preset's fused first
# layer took 0.22 ms against 0.57 ms with F.linear, which packs the weight again at every call.
# Without MKL (or without the operator) the products are F.linear's.
MKL_PACKED_PRODUCTS = bool(torch._C.has_mkl) and hasattr(torch.ops.mkl, "_mkl_linear")


def conv2d(input, weight, bias=None, stride=1, padding=0, dilation=1, groups=1):
    """``F.conv2d`` through oneDNN's direct convolution whatever the batch size (float32, numeric padding)."""
    if isinstance(padding, str) or input.dtype != torch.float32 or input.device.type != "cpu" or input.dim() != 4:
        return F.conv2d(input, weight, bias, stride, padding, dilation, groups)
    return torch.ops.aten.mkldnn_convolution(input.contiguous(), weight.contiguous(), bias, _pair(padding),
                                             _pair(stride), _pair(dilation), groups)


def conv_stack(layers: nn.Sequential, pixels: torch.Tensor) -> torch.Tensor:
    """``layers(pixels)`` for a stack of ``Conv2d`` (zero padding), ``ReLU`` and a final ``Flatten``, the
    activations in oneDNN's blocked layout from the first convolution to the flattening (float32 on the CPU;
    anything else runs ``layers`` as they are). The Base Model's inference path at every batch size: at batch
    size 1 it also beats PyTorch's own choice (0.72 against 0.79 ms for the default preset's stack, 1.49
    against 1.71 ms for the paper preset's, one thread of an AVX-512 Xeon). No autograd."""
    if pixels.dtype != torch.float32 or pixels.device.type != "cpu":
        return layers(pixels)
    x = pixels.contiguous().to_mkldnn()
    for layer in layers:
        if isinstance(layer, nn.Conv2d) and layer.padding_mode == "zeros" and not isinstance(layer.padding, str):
            x = torch.mkldnn_convolution(x, _mkldnn_weight(layer.weight), layer.bias, _pair(layer.padding),
                                         _pair(layer.stride), _pair(layer.dilation), layer.groups)
        elif isinstance(layer, nn.ReLU):
            x = x.relu_()  # x is this function's own intermediate: in place saves an allocation per layer
        elif isinstance(layer, nn.Flatten) and layer is layers[-1]:
            return x.to_dense().flatten(layer.start_dim, layer.end_dim)
        else:
            raise TypeError(f"conv_stack: {layer!r} is not a layer it runs")
    return x.to_dense()


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
    if MKL_PACKED_PRODUCTS and buffer.device.type == "cpu":
        packed = _cached(weight, "mkl", lambda: torch.ops.mkl._mkl_reorder_linear_weight(weight, ROWS_PER_PRODUCT))
        products = [torch.ops.mkl._mkl_linear(buffer[start : start + ROWS_PER_PRODUCT], packed, weight, bias,
                                              ROWS_PER_PRODUCT) for start in range(0, padded_rows, ROWS_PER_PRODUCT)]
    else:
        products = [F.linear(buffer[start : start + ROWS_PER_PRODUCT], weight, bias)
                    for start in range(0, padded_rows, ROWS_PER_PRODUCT)]
    out = products[0] if len(products) == 1 else torch.cat(products)
    return out[:n_rows, :n_out].reshape(*input.shape[:-1], n_out)


_CACHE: dict[tuple[int, object], tuple[weakref.ref, int, torch.Tensor]] = {}
_CACHE_LOCK = threading.Lock()


def _cached(tensor: torch.Tensor, key, make) -> torch.Tensor:
    """``make()``, a form of ``tensor`` (padded, converted), kept while ``tensor`` lives unchanged: a model's
    layers are converted once, not at every step."""
    # Inference tensors (weights a model packs inside inference mode) have no version counter; they
    # are caches built once, never changed in place.
    version = -1 if torch.is_inference(tensor) else tensor._version
    with _CACHE_LOCK:
        entry = _CACHE.get((id(tensor), key))
        if entry is not None and entry[0]() is tensor and entry[1] == version:
            return entry[2]
        converted = make()
        for stale in [k for k, (ref, *_) in _CACHE.items() if ref() is None]:
            del _CACHE[stale]
        _CACHE[(id(tensor), key)] = (weakref.ref(tensor), version, converted)
        return converted


def _padded(tensor: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """``tensor`` with zeros appended along each dimension up to ``shape``."""
    if tuple(tensor.shape) == shape:
        return tensor
    pads = [amount for size, target in zip(reversed(tensor.shape), reversed(shape)) for amount in (0, target - size)]
    return _cached(tensor, shape, lambda: F.pad(tensor, pads))


def _mkldnn_weight(weight: torch.Tensor) -> torch.Tensor:
    return _cached(weight, "mkldnn", lambda: weight.detach().contiguous().to_mkldnn())


def _pair(value) -> list[int]:
    return [int(value), int(value)] if isinstance(value, int) else [int(v) for v in value]


_ACTIVE = threading.local()  # how deep this Python thread is inside batch_invariant_ops()


def is_active() -> bool:
    """Whether this Python thread runs inside :func:`batch_invariant_ops` (models take :func:`conv_stack` then)."""
    return getattr(_ACTIVE, "depth", 0) > 0


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
    _ACTIVE.depth = getattr(_ACTIVE, "depth", 0) + 1
    try:
        with _BatchInvariantMode():
            yield
    finally:
        _ACTIVE.depth -= 1
        if previous != 1:
            torch.set_num_threads(previous)
