"""Which device the models run on: ``auto``, ``cpu`` or ``cuda`` (``cuda:N`` for one GPU of several).

``auto`` is CUDA when torch sees a GPU, else the CPU. Asking for ``cuda`` where there is none (a CPU
build of torch, or no GPU visible) is bad input, refused with the reason, not a fallback: a user who asks
for a GPU should not get hours on a CPU without being told.

What stays the same on every device: the models' weights and inputs are float32, checkpoints are read on
the CPU (memory-mapped, ``weights_only=True``), verified, then moved, and saved from CPU copies, so a
checkpoint's bytes do not depend on where the model ran; policies take numpy frames and return Python
floats or numpy arrays. What does not: the results' last bits. The CPU is bit-exact run to run (same
machine, same thread count); CUDA repeats itself on one GPU and software stack when deterministic
algorithms are on (training turns them on, see :func:`plm_highway.training.train.deterministic`), but
its sums run in another order than the CPU's, so a CUDA-trained model differs from a CPU-trained one
in its last bits and, after training amplifies them, in its weights.
"""

from __future__ import annotations

import torch

from plm_highway.errors import BadInput

DEVICE_CHOICES = ("auto", "cpu", "cuda")


def resolve_device(device: str | torch.device | None = "auto") -> torch.device:
    """``auto`` (or None), ``cpu``, ``cuda`` or ``cuda:N`` (or a torch.device) -> the torch.device to use.

    Raises :class:`~plm_highway.errors.BadInput` for another name, or for CUDA where torch has none.
    """
    if device is None or (isinstance(device, str) and device == "auto"):
        return torch.device("cuda") if torch.cuda.is_available() else torch.device("cpu")
    try:
        resolved = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise BadInput(f"--device {device!r}: expected one of {', '.join(DEVICE_CHOICES)} (or cuda:N)") from exc
    if resolved.type == "cpu":
        return resolved
    if resolved.type != "cuda":
        raise BadInput(f"--device {device!r}: expected one of {', '.join(DEVICE_CHOICES)} (or cuda:N)")
    if not torch.cuda.is_available():
        build = "this torch is a CPU build" if torch.version.cuda is None else "torch sees no GPU"
        raise BadInput(f"--device {device}: CUDA is not available ({build}, torch {torch.__version__}); "
                       f"use --device cpu, or auto to take a GPU only when there is one")
    if resolved.index is not None and resolved.index >= torch.cuda.device_count():
        raise BadInput(f"--device {device}: torch sees {torch.cuda.device_count()} GPU(s), numbered from 0")
    return resolved


def module_device(module: torch.nn.Module) -> torch.device:
    """The device of a module's first parameter (the CPU for a module without parameters)."""
    for parameter in module.parameters():
        return parameter.device
    return torch.device("cpu")


def describe_device(device: torch.device) -> str:
    """``cpu``, or ``cuda:0 (NVIDIA ...)``: what a result records about where it ran."""
    device = torch.device(device)
    if device.type != "cuda":
        return device.type
    index = torch.cuda.current_device() if device.index is None else device.index
    return f"cuda:{index} ({torch.cuda.get_device_name(index)})"
