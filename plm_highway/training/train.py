"""Supervised training of the Base Model and of the TAPM on a frozen BM (paper Section 3.3).

Paper values: MSE, Adam lr 1e-3, batch 32; the original also clipped gradients by value at 1 and
stopped early after 3 epochs without validation improvement (patience 3), keeping the best
weights. The TAPM's loss is the MSE averaged over its heads (Keras summed the per-head losses;
the factor N does not matter to Adam).

Repeatability: one seed drives numpy (balancing, subsetting, split), a torch.Generator (batch
order, augmentation) and torch's global RNG (weight init, dropout), with deterministic
algorithms on; the same seed on the same machine and thread count gives bit-identical weights
(and a byte-identical ``model.pt`` and ``model.json``: nothing time-dependent is recorded). The
command line trains with :data:`DEFAULT_THREADS` unless told otherwise, never with a count that
follows the CPU affinity, and records the count (``training.threads``).

Devices (``device``: ``cpu``, ``cuda``, ``auto``): the weights are initialised on the CPU and then moved,
batches are drawn and augmented on the CPU and then moved, so every device starts from the same weights
and sees the same samples in the same order. On CUDA, :func:`deterministic` also sets
``CUBLAS_WORKSPACE_CONFIG=:4096:8`` when it is unset (cuBLAS needs it for repeatable products; it takes
effect only if no CUDA product ran in the process before) and dropout draws from CUDA's generator (seeded
by the same seed): a run repeats itself on the same GPU and software, but not the CPU's bits.

Argument bounds (:class:`TrainConfig`, checked before the dataset is read): ``epochs`` in [1, 1000],
``batch_size`` in [1, 4096], ``learning_rate`` in [0, 1], ``patience_epochs`` in [1, 1000],
``val_fraction`` in (0, 0.5], ``seed`` in [0, 2**63 - 1], ``max_samples`` None or in [2, 10**9],
``balance_max_per_bin`` None or in [1, 10**9], ``grad_clip_value`` None or in (0, 1e6].
A dataset with no usable row, or whose rows cannot be split into training and validation, is
refused before anything is written.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F
from tqdm import tqdm

from plm_highway.data.dataset import Dataset, read_dataset
from plm_highway.errors import BadInput
from plm_highway.io import check_target, refuse_non_ascii_digits, write_output
from plm_highway.models.base_model import BaseModel, preset_config
from plm_highway.models.checkpoints import (
    CHECKPOINT,
    KIND_BASE_MODEL,
    load_base_model,
    read_description,
    save_checkpoint,
    state_fingerprint,
)
from plm_highway.models.config_checks import check_int, check_number
from plm_highway.models.device import describe_device, resolve_device
from plm_highway.models.tapm import DEFAULT_DELTA_GRID_S, TAPM, TAPMConfig, validate_delta_grid
from plm_highway.training.labels import save_balance_figure
from plm_highway.training.samples import (
    MIN_EPISODES_FOR_EPISODE_SPLIT,
    SPLIT_BLOCK_S,
    Augmentation,
    Batch,
    LabelledRows,
    at_most,
    balanced,
    bm_rows,
    iterate_batches,
    split_train_val,
    tapm_rows,
)

BALANCE_FIGURE_NAME = "steering_balance.png"
DEFAULT_THREADS = 2  # torch intra-op threads of `plm-highway train` (the shipped checkpoints' count)
MAX_EPOCHS = 1000
MAX_BATCH_SIZE = 4096
MAX_SEED = 2**63 - 1
MAX_ROWS = 10**9
MAX_LABEL_LEAD_S = 2.0  # far beyond any human reaction time; a longer lead labels frames with another road
# cuBLAS's documented setting for reproducible results (a workspace of 8 buffers of 4 MiB); torch refuses
# deterministic CUDA products without it or ":16:8".
CUBLAS_WORKSPACE_CONFIG = ":4096:8"


@dataclass(frozen=True)
class TrainConfig:
    epochs: int = 50
    batch_size: int = 32
    learning_rate: float = 1e-3
    patience_epochs: int = 3
    val_fraction: float = 0.2
    seed: int = 0
    max_samples: int | None = None
    # The original capped each of 35 bins at 2,000 samples (115k -> 67k); None disables balancing.
    balance_max_per_bin: int | None = 2000
    grad_clip_value: float | None = 1.0
    augmentation: Augmentation | None = field(default_factory=Augmentation)
    show_progress: bool = True
    # Label alignment: the frame at t is labelled with the demonstrator's steering at t + this lead
    # (0: the steering recorded with the frame, as the original paired them). See samples.bm_rows.
    label_lead_s: float = 0.0

    def __post_init__(self) -> None:
        # Named as the command line spells them: that is where they come from.
        check_int("--epochs", self.epochs, 1, MAX_EPOCHS)
        check_int("batch_size", self.batch_size, 1, MAX_BATCH_SIZE)
        check_number("learning_rate", self.learning_rate, 0.0, 1.0)
        check_int("patience_epochs", self.patience_epochs, 1, MAX_EPOCHS)
        check_number("val_fraction", self.val_fraction, 0.0, 0.5, low_open=True)
        check_int("--seed", self.seed, 0, MAX_SEED)
        if self.max_samples is not None:
            check_int("--max-samples", self.max_samples, 2, MAX_ROWS)
        if self.balance_max_per_bin is not None:
            check_int("--balance-max-per-bin", self.balance_max_per_bin, 1, MAX_ROWS)
        if self.grad_clip_value is not None:
            check_number("grad_clip_value", self.grad_clip_value, 0.0, 1e6, low_open=True)
        check_number("--label-lead-s", self.label_lead_s, 0.0, MAX_LABEL_LEAD_S)


@dataclass
class FitResult:
    epochs_run: int
    best_epoch: int
    best_val_loss: float
    stopped_early: bool
    train_loss_history: list[float]
    val_loss_history: list[float]


@contextlib.contextmanager
def deterministic(seed: int, device: torch.device | str = "cpu") -> Iterator[None]:
    """Seed torch's global RNG (every device's) and force deterministic algorithms for the block.

    On CUDA torch then refuses an operation that has no deterministic form rather than run it (none of
    the models' training operations is one), and cuBLAS needs ``CUBLAS_WORKSPACE_CONFIG``: set here when
    unset (it takes effect only where no CUDA product ran in the process before; set it in the environment
    to be sure).
    """
    if torch.device(device).type == "cuda":
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", CUBLAS_WORKSPACE_CONFIG)
    previous = torch.are_deterministic_algorithms_enabled()
    previous_fill = torch.utils.deterministic.fill_uninitialized_memory
    torch.use_deterministic_algorithms(True)
    # Filling every new tensor with NaN is a debugging aid of deterministic mode, not needed for
    # repeatability, and costs ~10% of a CPU training step.
    torch.utils.deterministic.fill_uninitialized_memory = False
    torch.manual_seed(seed)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(previous)
        torch.utils.deterministic.fill_uninitialized_memory = previous_fill


def freeze(model: torch.nn.Module) -> torch.nn.Module:
    """No gradients and eval mode (dropout off); the caller must not put it back in train mode."""
    return model.requires_grad_(False).eval()


def bm_loss(bm: BaseModel) -> Callable[[Batch], torch.Tensor]:
    def loss(batch: Batch) -> torch.Tensor:
        return F.mse_loss(bm(batch.frames, batch.speed_mps), batch.targets[:, 0])

    return loss


def tapm_loss(tapm: TAPM, frozen_bm: BaseModel) -> Callable[[Batch], torch.Tensor]:
    def loss(batch: Batch) -> torch.Tensor:
        # Inference mode: the frozen BM's forward pass records nothing for autograd (the same kernels, so the
        # same numbers); its outputs are cloned into ordinary tensors for the TAPM's graph.
        with torch.inference_mode():
            z_o, z_v = frozen_bm.encode(batch.frames, batch.speed_mps)
            a_bm = frozen_bm.steering_from_features(z_o, z_v)
        return F.mse_loss(tapm(a_bm.clone(), z_o.clone(), z_v.clone()), batch.targets)

    return loss


def fit(
    model: torch.nn.Module,
    loss_fn: Callable[[Batch], torch.Tensor],
    frames: np.ndarray,
    train_rows: LabelledRows,
    val_rows: LabelledRows,
    config: TrainConfig,
    name: str,
    device: torch.device | None = None,
) -> FitResult:
    """Adam on the trainable parameters with early stopping; leaves ``model`` at its best epoch.

    ``device``: where the batches go (the model must be there already; None: the CPU)."""
    optimizer = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=config.learning_rate)
    generator = torch.Generator().manual_seed(config.seed)
    train_history: list[float] = []
    val_history: list[float] = []
    best_state, best_val_loss, best_epoch = None, math.inf, 0
    for epoch in range(1, config.epochs + 1):
        description = f"{name} {epoch}/{config.epochs}"
        train_loss = train_epoch(
            model, loss_fn, optimizer, frames, train_rows, config, generator, description, device
        )
        train_history.append(train_loss)
        val_history.append(evaluate(model, loss_fn, frames, val_rows, config.batch_size, device))
        improved = val_history[-1] < best_val_loss
        if improved:
            best_state = {key: value.clone() for key, value in model.state_dict().items()}
            best_val_loss, best_epoch = val_history[-1], epoch
        if config.show_progress:
            tqdm.write(
                f"{name} epoch {epoch}: train loss {train_history[-1]:.5f}, val loss {val_history[-1]:.5f}"
                + (" (best)" if improved else "")
            )
        if epoch - best_epoch >= config.patience_epochs:
            break
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    return FitResult(
        epochs_run=len(train_history),
        best_epoch=best_epoch,
        best_val_loss=best_val_loss,
        stopped_early=len(train_history) < config.epochs,
        train_loss_history=train_history,
        val_loss_history=val_history,
    )


def train_epoch(
    model, loss_fn, optimizer, frames, rows, config: TrainConfig, generator, description: str = "",
    device: torch.device | None = None,
) -> float:
    """One pass over ``rows`` in random order (Adam steps, augmentation) with the batches on ``device`` (None:
    the CPU); returns the mean loss."""
    device = torch.device("cpu") if device is None else device
    model.train()
    total_loss, n_samples = 0.0, 0
    batches = iterate_batches(frames, rows, config.batch_size, generator, config.augmentation)
    progress = tqdm(
        batches,
        total=math.ceil(len(rows) / config.batch_size),
        desc=description,
        leave=False,
        disable=not config.show_progress,
    )
    for batch in progress:
        batch = batch.to(device)
        optimizer.zero_grad(set_to_none=True)
        loss = loss_fn(batch)
        loss.backward()
        if config.grad_clip_value is not None:
            torch.nn.utils.clip_grad_value_(model.parameters(), config.grad_clip_value)
        optimizer.step()
        total_loss += float(loss.detach()) * len(batch.targets)
        n_samples += len(batch.targets)
        progress.set_postfix(loss=f"{total_loss / n_samples:.5f}", refresh=False)
    return total_loss / max(n_samples, 1)


def evaluate(model, loss_fn, frames: np.ndarray, rows: LabelledRows, batch_size: int,
             device: torch.device | None = None) -> float:
    """Mean per-sample loss over ``rows`` in eval mode, in row order, without augmentation, on ``device``."""
    device = torch.device("cpu") if device is None else device
    model.eval()
    total_loss, n_samples = 0.0, 0
    with torch.no_grad():
        for batch in iterate_batches(frames, rows, batch_size):
            batch = batch.to(device)
            total_loss += float(loss_fn(batch)) * len(batch.targets)
            n_samples += len(batch.targets)
    return total_loss / max(n_samples, 1)


@dataclass(frozen=True)
class PreparedRows:
    train: LabelledRows
    val: LabelledRows
    counts: dict  # for the training summary
    steering_before_balancing: np.ndarray
    steering_after_balancing: np.ndarray

    def save_balance_figure(self, path: Path) -> Path:
        return save_balance_figure(self.steering_before_balancing, self.steering_after_balancing, path)


def prepare_rows(
    rows: LabelledRows, config: TrainConfig, rng: np.random.Generator, source: str = "dataset"
) -> PreparedRows:
    """Balance, subset and split ``rows``; ValueError (naming ``source``) if nothing usable is left."""
    if len(rows) == 0:
        raise BadInput(f"{source}: no usable rows to train on")
    steering_before = rows.steering
    rows = balanced(rows, config.balance_max_per_bin, rng)
    n_balanced = len(rows)
    rows = at_most(rows, config.max_samples, rng)
    try:
        train_rows, val_rows = split_train_val(rows, config.val_fraction, rng)
    except ValueError as exc:
        raise BadInput(f"{source}: {exc}") from exc
    counts = {
        "rows_labelled": len(steering_before),
        "rows_after_balancing": n_balanced,
        "rows_used": len(rows),
        "rows_train": len(train_rows),
        "rows_val": len(val_rows),
    }
    return PreparedRows(train_rows, val_rows, counts, steering_before, rows.steering)


def _write_checkpoint_dir(out_dir: Path, model, description: dict, prepared: PreparedRows, overwrite: bool,
                          balance_figure: bool = True) -> None:
    """The checkpoint, its description and (``balance_figure``) the balancing figure, published together once
    training succeeded."""
    with write_output(out_dir, CHECKPOINT, overwrite=overwrite) as staged:
        save_checkpoint(staged, model, description)
        if balance_figure:
            prepared.save_balance_figure(staged / BALANCE_FIGURE_NAME)


def train_base_model(
    data_dir: str | Path,
    out_dir: str | Path,
    preset: str = "default",
    config: TrainConfig = TrainConfig(),
    command: str = "",
    overwrite: bool = False,
    device: str | torch.device = "cpu",
    balance_figure: bool = True,
) -> dict:
    """Train a BM on the dataset at ``data_dir``; writes ``out_dir/model.pt`` + ``model.json``; returns the description.

    ``device``: ``cpu``, ``cuda`` or ``auto`` (see the module docstring). ``balance_figure=False`` leaves out the
    steering-balance figure (for callers that keep only the checkpoint files: drawing it costs about a second)."""
    device = resolve_device(device)
    dataset = read_dataset(data_dir)
    model_config = preset_config(preset)
    _check_frame_size(dataset, model_config.image_size_px, f"preset {preset!r}")
    check_target(out_dir, CHECKPOINT, overwrite=overwrite)
    out_dir = Path(out_dir)
    rng = np.random.default_rng(config.seed)
    prepared = prepare_rows(bm_rows(dataset, config.label_lead_s), config, rng, f"dataset {data_dir}")
    with deterministic(config.seed, device):
        bm = BaseModel(model_config).to(device)  # initialised on the CPU: the same weights on every device
        result = fit(bm, bm_loss(bm), dataset.frames, prepared.train, prepared.val, config, "BM", device)
    description = {
        "preset": preset,
        "image_size_px": list(model_config.image_size_px),
        "training": _training_summary(data_dir, dataset, config, result, prepared.counts, command, device),
    }
    _write_checkpoint_dir(out_dir, bm, description, prepared, overwrite, balance_figure)
    return description


def train_tapm(
    data_dir: str | Path,
    out_dir: str | Path,
    bm_path: str | Path,
    config: TrainConfig = TrainConfig(),
    delta_grid_s: tuple[float, ...] = DEFAULT_DELTA_GRID_S,
    command: str = "",
    overwrite: bool = False,
    device: str | torch.device = "cpu",
    balance_figure: bool = True,
) -> dict:
    """Train a TAPM on the frozen BM at ``bm_path``; writes ``out_dir/model.pt`` + ``model.json``.

    ``device``: ``cpu``, ``cuda`` or ``auto`` (see the module docstring); ``balance_figure`` as for
    :func:`train_base_model`."""
    device = resolve_device(device)
    bm = freeze(load_base_model(bm_path, device))
    bm_description = read_description(bm_path, KIND_BASE_MODEL)
    check_same_label_lead(bm_path, bm_description, config.label_lead_s)
    dataset = read_dataset(data_dir)
    _check_frame_size(dataset, bm.config.image_size_px, f"the BM at {bm_path}")
    check_target(out_dir, CHECKPOINT, overwrite=overwrite)
    tapm_config = TAPMConfig(image_feature_dim=bm.image_feature_dim, delta_grid_s=delta_grid_s)
    rng = np.random.default_rng(config.seed)
    rows = tapm_rows(dataset, tapm_config.delta_grid_s, config.label_lead_s)
    source = f"dataset {data_dir} (rows with a future label {tapm_config.delta_grid_s[-1]:g} s ahead)"
    prepared = prepare_rows(rows, config, rng, source)
    with deterministic(config.seed, device):
        tapm = TAPM(tapm_config).to(device)  # initialised on the CPU: the same weights on every device
        result = fit(tapm, tapm_loss(tapm, bm), dataset.frames, prepared.train, prepared.val, config, "TAPM",
                     device)
    description = {
        "preset": bm_description.get("preset"),
        "image_size_px": list(bm.config.image_size_px),
        "delta_grid_s": list(tapm_config.delta_grid_s),
        "bm_checkpoint": str(Path(bm_path).resolve()),
        "bm_fingerprint": state_fingerprint(bm),
        "training": _training_summary(data_dir, dataset, config, result, prepared.counts, command, device),
    }
    _write_checkpoint_dir(Path(out_dir), tapm, description, prepared, overwrite, balance_figure)
    return description


def check_same_label_lead(bm_path, bm_description: dict, label_lead_s: float) -> None:
    """A TAPM predicts its BM's labels ahead, so both must pair frames and labels with the same lead."""
    # Checkpoints trained before label alignment existed record no lead: they paired frames with their own steering.
    bm_lead_s = bm_description.get("training", {}).get("config", {}).get("label_lead_s", 0.0)
    if bm_lead_s != label_lead_s:
        raise BadInput(f"--label-lead-s {label_lead_s:g}: the BM at {bm_path} was trained with a label lead of "
                       f"{bm_lead_s:g} s; train the TAPM with the same lead")


def _check_frame_size(dataset: Dataset, image_size_px: tuple[int, int], owner: str) -> None:
    frame_size_px = tuple(dataset.frames.shape[1:])
    if frame_size_px != tuple(image_size_px):
        raise BadInput(
            f"dataset frames are {frame_size_px[0]}x{frame_size_px[1]} px but {owner} expects "
            f"{image_size_px[0]}x{image_size_px[1]} px (collect with the matching camera preset)"
        )


def _training_summary(
    data_dir, dataset: Dataset, config: TrainConfig, result: FitResult, counts: dict, command: str,
    device: torch.device,
) -> dict:
    return {
        "command": command,
        "data_dir": str(Path(data_dir).resolve()),
        "data_manifest": str((Path(data_dir) / "manifest.json").resolve()),
        "data_seed": dataset.manifest.get("seed"),
        "config": asdict(config),
        "validation_split": (
            f"by episode if >= {MIN_EPISODES_FOR_EPISODE_SPLIT} episodes, else by {SPLIT_BLOCK_S:g} s blocks"
        ),
        **counts,
        **asdict(result),
        # JSON has no infinity: a run whose validation loss never became finite records null.
        "best_val_loss": result.best_val_loss if math.isfinite(result.best_val_loss) else None,
        "threads": torch.get_num_threads(),
        # CPU and GPU runs of one seed differ in their last bits and then more: say where it ran.
        "device": describe_device(device),
    }


def parse_delta_grid(text: str) -> tuple[float, ...]:
    """``--delta-grid`` "0.15,0.2,..." -> latencies in seconds, checked like the TAPM's grid."""
    refuse_non_ascii_digits(text, "--delta-grid")
    parts = [part.strip() for part in text.split(",")]
    try:
        grid = [float(part) for part in parts if part]
    except ValueError as exc:
        raise BadInput(f"--delta-grid: expected comma-separated seconds, got {text!r}") from exc
    if not grid:
        raise BadInput(f"--delta-grid: expected at least one latency in seconds, got {text!r}")
    return validate_delta_grid(grid, field="--delta-grid")


def check_bm_preset(bm_path: str | Path, preset: str | None) -> None:
    """Refuse a BM trained with another preset than ``preset`` (None: any)."""
    if preset is None:
        return
    bm_preset = read_description(bm_path, KIND_BASE_MODEL).get("preset")
    if bm_preset != preset:
        raise BadInput(f"--preset {preset} given, but the BM at {bm_path} was trained with preset {bm_preset!r}")
