"""Training sets D (BM) and D_TAPM (TAPM) as row selections over a dataset, and batching.

A :class:`LabelledRows` holds only small per-row arrays (frame index, speed, labels); frames stay
in the dataset's (memory-mapped) uint8 array and are read and converted one batch at a time.

Validation split (20%): by episode, so that no validation frame has a near-identical neighbour
in the training set. With fewer than :data:`MIN_EPISODES_FOR_EPISODE_SPLIT` episodes a 20% share
of episodes is too coarse, so the rows are cut into contiguous blocks of
:data:`SPLIT_BLOCK_S` seconds within their episodes and whole blocks are drawn instead; only the
frames at block edges have a neighbour on the other side.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch

from plm_highway.data.dataset import Dataset
from plm_highway.errors import BadInput
from plm_highway.training.labels import balance_by_histogram, future_steering_labels

MIN_EPISODES_FOR_EPISODE_SPLIT = 5
SPLIT_BLOCK_S = 10.0


@dataclass(frozen=True)
class LabelledRows:
    frame_index: np.ndarray  # (M,) int64 rows of the dataset's frames
    episode_id: np.ndarray  # (M,)
    t_s: np.ndarray  # (M,)
    speed_mps: np.ndarray  # (M,) float32
    steering: np.ndarray  # (M,) float32, the current expert label (what balancing looks at)
    targets: np.ndarray  # (M, K) float32: [steering] for the BM, future steering for the TAPM

    def __len__(self) -> int:
        return len(self.frame_index)

    def subset(self, rows: np.ndarray) -> LabelledRows:
        return LabelledRows(*(getattr(self, name)[rows] for name in self.__dataclass_fields__))


def bm_rows(dataset: Dataset, label_lead_s: float = 0.0) -> LabelledRows:
    """D = {(o_t, v_t), a_t}: every row, labelled with its own steering.

    With ``label_lead_s`` > 0 (label alignment) the label of the frame at t is the demonstrator's steering
    at t + ``label_lead_s`` of the same episode, and rows without that future are dropped: a driver who
    reacts ``label_lead_s`` late answers the frame at t with its steering at t + lead.
    """
    rows, labels = _labels_from(dataset, label_lead_s, ())
    return _rows(dataset, rows, labels[:, :1], current=labels[:, 0])


def tapm_rows(dataset: Dataset, horizons_s: tuple[float, ...], label_lead_s: float = 0.0) -> LabelledRows:
    """D_TAPM: rows with the expert's future steering at each horizon; rows without a future dropped.

    ``label_lead_s`` shifts every horizon and the current label (the one balancing looks at) alike, so a
    TAPM trained with the lead its BM was trained with predicts that BM's labels ``horizon`` ahead.
    """
    rows, labels = _labels_from(dataset, label_lead_s, tuple(horizons_s))
    return _rows(dataset, rows, labels[:, 1:], current=labels[:, 0])


def _labels_from(dataset: Dataset, label_lead_s: float, horizons_s: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Rows with every label, and their labels: column 0 at t + lead, then t + lead + each horizon.

    At lead 0 column 0 is the row's own steering exactly (interpolation at a sample returns it).
    """
    steps = dataset.steps
    labels, has_future = future_steering_labels(
        steps["episode_id"], steps["t_s"], steps["steering"], tuple(label_lead_s + h for h in (0.0, *horizons_s))
    )
    rows = np.flatnonzero(has_future)
    return rows, labels[rows]


def _rows(dataset: Dataset, rows: np.ndarray, targets: np.ndarray, current: np.ndarray) -> LabelledRows:
    steps = dataset.steps
    return LabelledRows(
        frame_index=rows.astype(np.int64),
        episode_id=steps["episode_id"][rows],
        t_s=steps["t_s"][rows],
        speed_mps=steps["speed_mps"][rows].astype(np.float32),
        steering=current.astype(np.float32),
        targets=targets.astype(np.float32),
    )


def balanced(rows: LabelledRows, max_per_bin: int | None, rng: np.random.Generator) -> LabelledRows:
    """Histogram-balanced on the current steering; ``None`` keeps every row."""
    if max_per_bin is None:
        return rows
    return rows.subset(balance_by_histogram(rows.steering, max_per_bin, rng))


def at_most(rows: LabelledRows, max_samples: int | None, rng: np.random.Generator) -> LabelledRows:
    """A seeded random subset of ``max_samples`` rows (in time order), for fast runs."""
    if max_samples is None or len(rows) <= max_samples:
        return rows
    return rows.subset(np.sort(rng.choice(len(rows), size=max_samples, replace=False)))


def split_train_val(
    rows: LabelledRows, val_fraction: float, rng: np.random.Generator
) -> tuple[LabelledRows, LabelledRows]:
    """(train, val) by episode or by contiguous time blocks (see module docstring)."""
    groups = _split_groups(rows)
    unique_groups, group_sizes = np.unique(groups, return_counts=True)
    if len(unique_groups) < 2:
        raise BadInput(f"cannot split {len(rows)} rows into train and validation: they form one block")
    order = rng.permutation(len(unique_groups))
    # Draw whole groups until the validation share is reached, always leaving one for training.
    n_val_groups = int(np.searchsorted(np.cumsum(group_sizes[order]), val_fraction * len(rows))) + 1
    is_val = np.isin(groups, unique_groups[order[: min(n_val_groups, len(unique_groups) - 1)]])
    return rows.subset(np.flatnonzero(~is_val)), rows.subset(np.flatnonzero(is_val))


def _split_groups(rows: LabelledRows) -> np.ndarray:
    if len(np.unique(rows.episode_id)) >= MIN_EPISODES_FOR_EPISODE_SPLIT:
        return rows.episode_id.astype(np.int64)
    block = np.floor(rows.t_s / SPLIT_BLOCK_S).astype(np.int64)
    # One id per (episode, block); an episode has far fewer than 2**32 blocks.
    return rows.episode_id.astype(np.int64) * (1 << 32) + block


@dataclass(frozen=True)
class Augmentation:
    """Per-sample random horizontal flip and brightness (gamma) change.

    Brightness is a gamma curve rather than a gain or offset because the model's per-image min-max
    stretch undoes any gain or offset exactly; a gamma changes the grey levels it sees.
    """

    flip_probability: float = 0.5
    gamma_range: tuple[float, float] = (0.6, 1.6)


@dataclass(frozen=True)
class Batch:
    frames: torch.Tensor  # (B, H, W) uint8
    speed_mps: torch.Tensor  # (B,) float32
    targets: torch.Tensor  # (B, K) float32

    def to(self, device: torch.device) -> Batch:
        """The batch on ``device`` (itself where it is there already). Batches are drawn and augmented on the
        CPU with the CPU generator, so every device trains on the same samples."""
        if self.frames.device == device:
            return self
        return Batch(self.frames.to(device), self.speed_mps.to(device), self.targets.to(device))


def flip_horizontally(
    frames: torch.Tensor, targets: torch.Tensor, flip: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mirror the flagged frames once and negate every label of those rows once.

    A mirrored road turns the other way, now and at every future horizon. (The original code
    applied its flip once per label column, which corrupted the labels.)
    """
    frames = torch.where(flip.view(-1, 1, 1), frames.flip(-1), frames)
    targets = torch.where(flip.view(-1, 1), -targets, targets)
    return frames, targets


def adjust_gamma(frames: torch.Tensor, gamma: torch.Tensor) -> torch.Tensor:
    """uint8 (B, H, W) -> uint8 with 255 * (x / 255) ** gamma per sample."""
    scaled = (frames.to(torch.float32) / 255.0).pow(gamma.view(-1, 1, 1))
    return (scaled * 255.0).round_().to(torch.uint8)


def augment(
    frames: torch.Tensor, targets: torch.Tensor, augmentation: Augmentation, generator: torch.Generator | None
) -> tuple[torch.Tensor, torch.Tensor]:
    n = len(frames)
    flip = torch.rand(n, generator=generator) < augmentation.flip_probability
    low, high = augmentation.gamma_range
    gamma = low + (high - low) * torch.rand(n, generator=generator)
    frames, targets = flip_horizontally(frames, targets, flip)
    return adjust_gamma(frames, gamma), targets


def iterate_batches(
    frames: np.ndarray,
    rows: LabelledRows,
    batch_size: int,
    generator: torch.Generator | None = None,
    augmentation: Augmentation | None = None,
) -> Iterator[Batch]:
    """Batches in random order when a generator is given (else in row order), read frame by batch."""
    order = (
        torch.randperm(len(rows), generator=generator).numpy()
        if generator is not None
        else np.arange(len(rows))
    )
    for start in range(0, len(rows), batch_size):
        chosen = order[start : start + batch_size]
        # Fancy indexing a memmap reads only these frames.
        batch_frames = torch.from_numpy(np.ascontiguousarray(frames[rows.frame_index[chosen]]))
        targets = torch.from_numpy(rows.targets[chosen])
        if augmentation is not None:
            batch_frames, targets = augment(batch_frames, targets, augmentation, generator)
        yield Batch(batch_frames, torch.from_numpy(rows.speed_mps[chosen]), targets)
