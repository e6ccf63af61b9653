"""Checkpoints: a ``state_dict`` (``NAME.pt``) with its JSON description beside it (``NAME.json``).

The JSON holds what is needed to rebuild the module (``architecture``: the config dataclass's
fields) and what is needed to trust it (preset, image size, delta grid, training summary, and
for a TAPM the fingerprint of the BM whose features it was trained on). Weights are loaded only
with ``torch.load(..., weights_only=True)``: a checkpoint can never run code.

A path names a checkpoint as a directory (``DIR/model.pt`` + ``DIR/model.json``, what training
writes) or as either file of a pair (``bm_default.pt`` / ``bm_default.json``, how checkpoints are
shipped in ``plm_highway/checkpoints``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import torch
from torch import nn

from plm_highway.io import directory_kind
from plm_highway.models.base_model import BaseModel, BaseModelConfig
from plm_highway.models.plm_net import PLMNet
from plm_highway.models.tapm import TAPM, TAPMConfig

FORMAT = "plm_highway.checkpoint/1"
KIND_BASE_MODEL = "base_model"
KIND_TAPM = "tapm"


def _has_checkpoint_description(path: Path) -> bool:
    """Checkpoint directories written before output markers existed: a ``model.json`` of this format."""
    try:
        return json.loads((path / "model.json").read_text(encoding="utf-8")).get("format") == FORMAT
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
    digest = hashlib.sha256()
    for key, tensor in sorted(module.state_dict().items()):
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
    kind = KIND_BASE_MODEL if isinstance(model, BaseModel) else KIND_TAPM
    identity = {
        "format": FORMAT,
        "kind": kind,
        "architecture": dataclasses.asdict(model.config),
        "fingerprint": state_fingerprint(model),
        "torch_version": torch.__version__,
    }
    # The identity fields are derived from the model and always win over the caller's.
    document = {"format": FORMAT, **description, **identity}
    weights_path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(model.state_dict(), weights_path)
    json_path.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
    return weights_path


def read_description(path: str | Path, kind: str) -> dict:
    weights_path, json_path = checkpoint_paths(path)
    for required in (json_path, weights_path):
        if not required.is_file():
            raise FileNotFoundError(f"{required}: checkpoint file not found")
    try:
        document = json.loads(json_path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{json_path}: not valid JSON ({exc})") from exc
    if document.get("format") != FORMAT:
        raise ValueError(f"{json_path}: field 'format' is {document.get('format')!r}, expected {FORMAT!r}")
    if document.get("kind") != kind:
        raise ValueError(f"{json_path}: is a {document.get('kind')!r} checkpoint, expected {kind!r}")
    return document


def load_base_model(path: str | Path) -> BaseModel:
    """The BM described at ``path``, in eval mode."""
    document = read_description(path, KIND_BASE_MODEL)
    config = _config_from(BaseModelConfig, document, path)
    image_size_px = document.get("image_size_px")
    if image_size_px is not None and tuple(image_size_px) != config.image_size_px:
        raise ValueError(
            f"{checkpoint_paths(path)[1]}: image_size_px {image_size_px} disagrees with the architecture's "
            f"{list(config.image_size_px)}"
        )
    model = BaseModel(config)
    load_weights(model, path)
    return model.eval()


def load_tapm(path: str | Path, bm: BaseModel) -> TAPM:
    """The TAPM described at ``path``, checked against the BM it will read features from; eval mode."""
    document = read_description(path, KIND_TAPM)
    config = _config_from(TAPMConfig, document, path)
    json_path = checkpoint_paths(path)[1]
    if config.image_feature_dim != bm.image_feature_dim:
        raise ValueError(
            f"{json_path}: TAPM reads image features of size {config.image_feature_dim}, but the BM "
            f"({bm.config.image_height_px}x{bm.config.image_width_px} px) produces {bm.image_feature_dim}"
        )
    expected_bm = document.get("bm_fingerprint")
    if expected_bm is not None and expected_bm != state_fingerprint(bm):
        raise ValueError(
            f"{json_path}: TAPM was trained on the features of another BM (fingerprint "
            f"{expected_bm[:12]}..., this BM has {state_fingerprint(bm)[:12]}...)"
        )
    model = TAPM(config)
    load_weights(model, path)
    return model.eval()


def load_plm_net(bm_path: str | Path, tapm_path: str | Path) -> PLMNet:
    bm = load_base_model(bm_path)
    return PLMNet(bm, load_tapm(tapm_path, bm)).eval()


def load_weights(model: nn.Module, path: str | Path) -> None:
    """Load the .pt at ``path`` into ``model``; ValueError naming every missing/unexpected/misshapen key."""
    weights_path = checkpoint_paths(path)[0]
    try:
        state = torch.load(weights_path, map_location="cpu", weights_only=True)
    except Exception as exc:  # unpickling errors have no common base class worth naming
        raise ValueError(f"{weights_path}: not a loadable state_dict ({exc})") from exc
    if not isinstance(state, dict):  # a malformed file is bad input, like a shape mismatch
        raise ValueError(f"{weights_path}: expected a state_dict, found {type(state).__name__}")
    problems = _state_mismatches(model.state_dict(), state)
    if problems:
        raise ValueError(f"{weights_path}: weights do not match the architecture: " + "; ".join(problems))
    model.load_state_dict(state)


def _state_mismatches(expected: dict[str, torch.Tensor], found: dict[str, torch.Tensor]) -> list[str]:
    problems = []
    missing = sorted(set(expected) - set(found))
    unexpected = sorted(set(found) - set(expected))
    if missing:
        problems.append(f"missing keys {missing}")
    if unexpected:
        problems.append(f"unexpected keys {unexpected}")
    for key in sorted(set(expected) & set(found)):
        if tuple(expected[key].shape) != tuple(found[key].shape):
            problems.append(
                f"key {key!r}: expected shape {tuple(expected[key].shape)}, found {tuple(found[key].shape)}"
            )
    return problems


def _config_from(config_class, document: dict, path: str | Path):
    architecture = document.get("architecture")
    json_path = checkpoint_paths(path)[1]
    if not isinstance(architecture, dict):
        raise ValueError(f"{json_path}: field 'architecture' is missing")
    known = {field.name for field in dataclasses.fields(config_class)}
    unknown = sorted(set(architecture) - known)
    if unknown:
        raise ValueError(f"{json_path}: unknown architecture fields {unknown} for {config_class.__name__}")
    try:
        return config_class(**architecture)
    except TypeError as exc:  # a required field is missing
        raise ValueError(f"{json_path}: architecture: {exc}") from exc
