"""Checkpoints: a ``state_dict`` (``NAME.pt``) with its JSON description beside it (``NAME.json``).

The JSON holds what is needed to rebuild the module (``architecture``: the config dataclass's
fields) and what is needed to trust it (``fingerprint`` of the weights, preset, image size, delta
grid, training summary, and for a TAPM the fingerprint of the BM whose features it was trained
on). Weights are loaded only with ``torch.load(..., weights_only=True)``: a checkpoint can never
run code.

A path names a checkpoint as a directory (``DIR/model.pt`` + ``DIR/model.json``, what training
writes) or as either file of a pair (``bm_default.pt`` / ``bm_default.json``, how checkpoints are
shipped in ``plm_highway/checkpoints``).

Loading checks, in this order, and refuses with a ValueError naming the file and the culprit:

1. the JSON: at most :data:`MAX_DESCRIPTION_BYTES`, UTF-8 (a byte-order mark is accepted), read
   within :data:`DESCRIPTION_LIMITS` (:mod:`plm_highway.io.bounded`: depth, values, no key twice),
   an object with the expected ``format`` and ``kind``;
2. ``architecture``: known fields of the right types within the bounds documented in
   :mod:`plm_highway.models.base_model` and :mod:`plm_highway.models.tapm`, before any layer is
   allocated;
3. the ``.pt``: at most :data:`MAX_WEIGHTS_BYTES` (any architecture within the bounds fits),
   memory-mapped rather than read, so a file of another architecture costs nothing before
   its keys and shapes are compared;
4. the ``state_dict``: every key of the architecture with its shape and dtype (missing, unexpected
   and misshapen keys are named, with both shapes), every value finite;
5. the weights' sha256 fingerprint equals the recorded ``fingerprint`` (a ``.pt`` swapped for
   other weights of the same shapes is refused), and for a TAPM the BM it is combined with has the
   recorded ``bm_fingerprint``;
6. the description's own seal (``description_sha256``, the sha256 of every other field): a latency
   grid, preset, label lead or any other field edited after saving is refused, even where the
   weights' shapes would still fit.

Saving refuses non-finite weights (a diverged training run). Devices: weights are saved from CPU copies of
the ``state_dict`` (a model on a GPU writes the same bytes as the same weights on the CPU) and loaded on the
CPU (``map_location="cpu"``, memory-mapped), checked, and then moved to the ``device`` the loader is asked
for (``load_base_model(path, device="cuda")``; default the CPU, for a TAPM its BM's device).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import torch
from torch import nn

from plm_highway.errors import BadInput
from plm_highway.io import JsonLimits, directory_kind, load_json, parse_json, read_bounded
from plm_highway.models.base_model import BaseModel, BaseModelConfig
from plm_highway.models.device import module_device, resolve_device
from plm_highway.models.plm_net import PLMNet
from plm_highway.models.tapm import TAPM, TAPMConfig

FORMAT = "plm_highway.checkpoint/1"
KIND_BASE_MODEL = "base_model"
KIND_TAPM = "tapm"
MAX_DESCRIPTION_BYTES = 4 * 1024 * 1024
MAX_WEIGHTS_BYTES = 1024**3
DESCRIPTION_LIMITS = JsonLimits(max_bytes=MAX_DESCRIPTION_BYTES, max_depth=16, max_nodes=100_000, max_int_digits=30)
SEAL_KEY = "description_sha256"
MAX_NAMED_KEYS = 8  # longer lists of missing/unexpected keys are cut, with the count


def _has_checkpoint_description(path: Path) -> bool:
    """Checkpoint directories written before output markers existed: a ``model.json`` of this format."""
    try:
        return load_json(path / "model.json", DESCRIPTION_LIMITS).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


CHECKPOINT = directory_kind("checkpoint", "a plm-highway checkpoint directory", _has_checkpoint_description)


def checkpoint_paths(path: str | Path) -> tuple[Path, Path]:
    """(weights .pt, description .json) for a checkpoint directory or either file of the pair."""
    path = Path(path)
    if path.suffix in (".pt", ".json"):
        return path.with_suffix(".pt"), path.with_suffix(".json")
    return path / "model.pt", path / "model.json"


def state_fingerprint(module: nn.Module) -> str:
    """sha256 over the state_dict's names, dtypes, shapes and bytes: identifies trained weights."""
    return state_dict_fingerprint(module.state_dict())


def state_dict_fingerprint(state: dict[str, torch.Tensor]) -> str:
    """:func:`state_fingerprint` of a state_dict (e.g. as loaded, before it goes into a module)."""
    digest = hashlib.sha256()
    for key, tensor in sorted(state.items()):
        tensor = tensor.detach().contiguous().cpu()
        digest.update(f"{key}|{tensor.dtype}|{tuple(tensor.shape)}|".encode())
        digest.update(tensor.numpy().tobytes())
    return digest.hexdigest()


def save_checkpoint(path: str | Path, model: BaseModel | TAPM, description: dict) -> Path:
    """Write ``model``'s weights and ``description`` (plus kind, architecture, fingerprint); returns the .pt.

    Plain writes: call it inside a directory staged by :func:`plm_highway.io.write_output` (training
    does), so the checkpoint is published whole or not at all.
    """
    weights_path, json_path = checkpoint_paths(path)
    state = host_state_dict(model)
    problems = _non_finite(state)
    if problems:
        raise BadInput(f"{weights_path}: refusing to save non-finite weights ({'; '.join(problems)})")
    kind = KIND_BASE_MODEL if isinstance(model, BaseModel) else KIND_TAPM
    identity = {
        "format": FORMAT,
        "kind": kind,
        "architecture": dataclasses.asdict(model.config),
        "fingerprint": state_dict_fingerprint(state),
        "torch_version": torch.__version__,
    }
    # The identity fields are derived from the model and always win over the caller's.
    document = {"format": FORMAT, **description, **identity}
    document.pop(SEAL_KEY, None)
    document[SEAL_KEY] = description_seal(document)
    weights_path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, weights_path)
    json_path.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
    return weights_path


def host_state_dict(model: nn.Module) -> dict[str, torch.Tensor]:
    """``model.state_dict()`` with every tensor on the CPU (the same tensors where they are there already),
    keeping the dict's type and its ``_metadata``, which ``torch.save`` writes too: the bytes saved do not
    depend on the device the model is on."""
    state = model.state_dict()
    host = type(state)((key, tensor.cpu()) for key, tensor in state.items())
    metadata = getattr(state, "_metadata", None)
    if metadata is not None:
        host._metadata = metadata
    return host


def read_description(path: str | Path, kind: str) -> dict:
    """The checkpoint's JSON description, checked for format and kind (see the module docstring)."""
    weights_path, json_path = checkpoint_paths(path)
    for required in (json_path, weights_path):
        if not required.is_file():
            raise FileNotFoundError(f"{required}: checkpoint file not found")
    size_bytes = json_path.stat().st_size
    if size_bytes > MAX_DESCRIPTION_BYTES:
        raise BadInput(f"{json_path}: {size_bytes} bytes, a checkpoint description is at most {MAX_DESCRIPTION_BYTES}")
    document = parse_json(read_bounded(json_path, MAX_DESCRIPTION_BYTES, "checkpoint description"), str(json_path),
                          DESCRIPTION_LIMITS)
    if not isinstance(document, dict):
        raise BadInput(f"{json_path}: expected a JSON object, found {type(document).__name__}")
    if document.get("format") != FORMAT:
        raise BadInput(f"{json_path}: field 'format' is {document.get('format')!r}, expected {FORMAT!r}")
    if document.get("kind") != kind:
        raise BadInput(f"{json_path}: is a {document.get('kind')!r} checkpoint, expected {kind!r}")
    return document


def load_base_model(path: str | Path, device: str | torch.device = "cpu") -> BaseModel:
    """The BM described at ``path``, verified against its fingerprint, in eval mode, on ``device``."""
    document = read_description(path, KIND_BASE_MODEL)
    config = _config_from(BaseModelConfig, document, path)
    image_size_px = document.get("image_size_px")
    if image_size_px is not None and (
        not isinstance(image_size_px, list) or tuple(image_size_px) != config.image_size_px
    ):
        raise BadInput(
            f"{checkpoint_paths(path)[1]}: image_size_px {image_size_px} disagrees with the architecture's "
            f"{list(config.image_size_px)}"
        )
    device = resolve_device(device)  # refused before anything is read
    model = BaseModel(config)
    load_weights(model, path, document)
    return model.to(device).eval()


def load_tapm(path: str | Path, bm: BaseModel, device: str | torch.device | None = None) -> TAPM:
    """The TAPM described at ``path``, verified against its fingerprint and the BM it will read; eval mode,
    on ``device`` (default: the BM's)."""
    document = read_description(path, KIND_TAPM)
    config = _config_from(TAPMConfig, document, path)
    json_path = checkpoint_paths(path)[1]
    if config.image_feature_dim != bm.image_feature_dim:
        raise BadInput(
            f"{json_path}: TAPM reads image features of size {config.image_feature_dim}, but the BM "
            f"({bm.config.image_height_px}x{bm.config.image_width_px} px) produces {bm.image_feature_dim}"
        )
    expected_bm = document.get("bm_fingerprint")
    if not isinstance(expected_bm, str):
        raise BadInput(
            f"{json_path}: field 'bm_fingerprint' is missing or not a string: cannot check which BM the TAPM "
            f"was trained on"
        )
    bm_fingerprint = state_fingerprint(bm)
    if expected_bm != bm_fingerprint:
        raise BadInput(
            f"{json_path}: TAPM was trained on the features of another BM (fingerprint "
            f"{expected_bm[:12]}..., this BM has {bm_fingerprint[:12]}...)"
        )
    device = module_device(bm) if device is None else resolve_device(device)
    model = TAPM(config)
    load_weights(model, path, document)
    return model.to(device).eval()


def load_plm_net(bm_path: str | Path, tapm_path: str | Path, device: str | torch.device = "cpu") -> PLMNet:
    """The BM and TAPM pair as one PLM-Net on ``device``."""
    bm = load_base_model(bm_path, device)
    return PLMNet(bm, load_tapm(tapm_path, bm)).eval()


def load_weights(model: nn.Module, path: str | Path, document: dict | None = None) -> None:
    """Load the .pt at ``path`` into ``model`` after the checks 3-5 of the module docstring.

    ``document`` is the checkpoint's description; its ``fingerprint`` must match the weights (read
    from ``path`` when not given).
    """
    weights_path, json_path = checkpoint_paths(path)
    if document is None:
        document = read_description(path, KIND_BASE_MODEL if isinstance(model, BaseModel) else KIND_TAPM)
    expected = model.state_dict()
    size_bytes = weights_path.stat().st_size
    if size_bytes > MAX_WEIGHTS_BYTES:
        raise BadInput(f"{weights_path}: {size_bytes} bytes, a checkpoint's weights are at most {MAX_WEIGHTS_BYTES}")
    try:
        state = torch.load(weights_path, map_location="cpu", weights_only=True, mmap=True)
    except Exception as exc:  # truncated zips, foreign pickles: no common base class worth naming
        raise BadInput(f"{weights_path}: not a loadable state_dict ({exc})") from exc
    if not isinstance(state, dict):  # a malformed file is bad input, like a shape mismatch
        raise BadInput(f"{weights_path}: expected a state_dict, found {type(state).__name__}")
    not_tensors = sorted(str(key) for key, value in state.items() if not isinstance(value, torch.Tensor))
    if not_tensors:
        raise BadInput(f"{weights_path}: entries that are not tensors: {_named(not_tensors)}")
    problems = _state_mismatches(expected, state)
    if problems:
        raise BadInput(f"{weights_path}: weights do not match the architecture: " + "; ".join(problems))
    problems = _non_finite(state)
    if problems:
        raise BadInput(f"{weights_path}: weights are not finite: " + "; ".join(problems))
    recorded = document.get("fingerprint")
    if not isinstance(recorded, str):
        raise BadInput(f"{json_path}: field 'fingerprint' is missing: the weights cannot be verified")
    found = state_dict_fingerprint(state)
    if found != recorded:
        raise BadInput(
            f"{weights_path}: the weights' fingerprint {found[:12]}... differs from the one recorded in "
            f"{json_path.name} ({recorded[:12]}...): the .pt was replaced or altered after it was saved"
        )
    check_seal(document, json_path)
    model.load_state_dict(state)


def description_seal(document: dict) -> str:
    """sha256 of the description without its seal, in canonical JSON: binds the latency grid, preset,
    label lead, image size, BM fingerprint and every other field to the weights' fingerprint."""
    body = {key: value for key, value in document.items() if key != SEAL_KEY}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode("utf-8")).hexdigest()


def check_seal(document: dict, json_path: Path) -> None:
    """Refuse a description edited after it was saved (the last check: the specific ones name more)."""
    recorded = document.get(SEAL_KEY)
    if not isinstance(recorded, str):
        raise BadInput(f"{json_path}: field {SEAL_KEY!r} is missing, so the description (latency grid, preset, "
                       "label lead, ...) cannot be verified against the weights: it was written before descriptions "
                       "were sealed, or edited. Retrain it (or, after checking it, seal it with "
                       "plm_highway.models.checkpoints.reseal)")
    found = description_seal(document)
    if found != recorded:
        raise BadInput(f"{json_path}: the description was changed after it was saved (its sha256 {found[:12]}... "
                       f"differs from the recorded {SEAL_KEY} {recorded[:12]}...): a checkpoint's latency grid, "
                       "preset, label lead and other fields stay as training wrote them")


def reseal(path: str | Path) -> str:
    """Seal a description written before seals existed (a maintainer's step, after checking it by hand):
    the file is rewritten with :data:`SEAL_KEY` added; returns the seal."""
    json_path = checkpoint_paths(path)[1]
    document = parse_json(read_bounded(json_path, MAX_DESCRIPTION_BYTES, "checkpoint description"), str(json_path),
                          DESCRIPTION_LIMITS)
    document.pop(SEAL_KEY, None)
    document[SEAL_KEY] = description_seal(document)
    json_path.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
    return document[SEAL_KEY]


def _state_mismatches(expected: dict[str, torch.Tensor], found: dict[str, torch.Tensor]) -> list[str]:
    problems = []
    missing = sorted(set(expected) - set(found))
    unexpected = sorted(set(found) - set(expected))
    if missing:
        problems.append(f"missing keys {_named(missing)}")
    if unexpected:
        problems.append(f"unexpected keys {_named(unexpected)}")
    for key in sorted(set(expected) & set(found)):
        if tuple(expected[key].shape) != tuple(found[key].shape):
            problems.append(
                f"key {key!r}: expected shape {tuple(expected[key].shape)}, found {tuple(found[key].shape)}"
            )
        elif expected[key].dtype != found[key].dtype:
            problems.append(f"key {key!r}: expected dtype {expected[key].dtype}, found {found[key].dtype}")
    return problems


def _non_finite(state: dict[str, torch.Tensor]) -> list[str]:
    problems = []
    for key, tensor in sorted(state.items()):
        if tensor.is_floating_point():
            n_bad = int((~torch.isfinite(tensor)).sum())
            if n_bad:
                problems.append(f"key {key!r} has {n_bad} NaN or infinite values")
    return problems


def _named(keys: list[str]) -> str:
    shown = repr(keys[:MAX_NAMED_KEYS])
    return shown if len(keys) <= MAX_NAMED_KEYS else f"{shown[:-1]}, ...] ({len(keys)} in all)"


def _config_from(config_class, document: dict, path: str | Path):
    architecture = document.get("architecture")
    json_path = checkpoint_paths(path)[1]
    if not isinstance(architecture, dict):
        raise BadInput(f"{json_path}: field 'architecture' is missing or not an object")
    known = {field.name for field in dataclasses.fields(config_class)}
    unknown = sorted(set(architecture) - known)
    if unknown:
        raise BadInput(f"{json_path}: unknown architecture fields {unknown} for {config_class.__name__}")
    try:
        return config_class(**architecture)
    except TypeError as exc:  # a required field is missing
        raise BadInput(f"{json_path}: architecture: {exc}") from exc
    except ValueError as exc:  # a field of the wrong type or out of bounds, named by the config
        raise BadInput(f"{json_path}: architecture field {exc}") from exc
