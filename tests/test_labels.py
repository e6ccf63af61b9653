"""Future-action labels by time, histogram balancing, splitting and augmentation (plm_highway.training)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.data.dataset import Dataset, read_dataset
from plm_highway.training.labels import balance_by_histogram, future_steering_labels, save_balance_figure
from plm_highway.training.samples import (
    Augmentation,
    LabelledRows,
    adjust_gamma,
    augment,
    bm_rows,
    flip_horizontally,
    iterate_batches,
    split_train_val,
    tapm_rows,
)
from plm_highway.training.synthetic import make_synthetic_dataset

# --- future labels by time ------------------------------------------------------------------------


def test_future_labels_are_looked_up_by_time_and_rows_without_a_future_are_dropped():
    # One episode at 20 Hz, steering = 10 * t, so the label at t + d is 10 * (t + d).
    t_s = np.arange(11) * 0.05  # 0.00 ... 0.50
    steering = (10 * t_s).astype(np.float32)
    labels, has_future = future_steering_labels(np.zeros(11, int), t_s, steering, (0.15, 0.20))
    # Rows up to t = 0.30 have t + 0.20 <= 0.50; the last four do not.
    assert has_future.tolist() == [True] * 7 + [False] * 4
    np.testing.assert_allclose(labels[0], [1.5, 2.0], atol=1e-6)
    np.testing.assert_allclose(labels[6], [4.5, 5.0], atol=1e-6)  # t = 0.30
    assert np.isnan(labels[7]).any()


def test_future_labels_never_cross_an_episode_boundary():
    # Episode 7 then episode 3, both starting their clocks at 0; rows are contiguous in the file.
    episode_id = np.array([7, 7, 7, 7, 3, 3, 3, 3])
    t_s = np.array([0.0, 0.05, 0.10, 0.15, 0.0, 0.05, 0.10, 0.15])
    steering = np.array([0.1, 0.2, 0.3, 0.4, -0.1, -0.2, -0.3, -0.4], dtype=np.float32)
    labels, has_future = future_steering_labels(episode_id, t_s, steering, (0.10,))
    # Episode 7's rows at 0.10 and 0.15 have no future inside episode 7, although rows follow.
    assert has_future.tolist() == [True, True, False, False, True, True, False, False]
    np.testing.assert_allclose(labels[[0, 1, 4, 5], 0], [0.3, 0.4, -0.3, -0.4], atol=1e-6)


def test_future_labels_work_when_episodes_are_interleaved():
    episode_id = np.array([0, 1, 0, 1, 0, 1])
    t_s = np.array([0.0, 0.0, 0.05, 0.05, 0.10, 0.10])
    steering = np.array([0.0, 1.0, 0.2, 0.9, 0.4, 0.8], dtype=np.float32)
    labels, has_future = future_steering_labels(episode_id, t_s, steering, (0.05,))
    assert has_future.tolist() == [True, True, True, True, False, False]
    np.testing.assert_allclose(labels[:4, 0], [0.2, 0.9, 0.4, 0.8], atol=1e-6)


def test_future_label_between_samples_is_interpolated_in_time():
    # A dropped frame: samples at 0.0, 0.1, 0.3 s. t = 0.0 + 0.15 lies a quarter of the way from 0.1 to 0.3.
    labels, has_future = future_steering_labels(
        np.zeros(3, int), np.array([0.0, 0.1, 0.3]), np.array([0.0, 0.2, 0.6], dtype=np.float32), (0.15,)
    )
    assert has_future.tolist() == [True, True, False]
    assert labels[0, 0] == pytest.approx(0.2 + 0.25 * 0.4)
    assert labels[1, 0] == pytest.approx(0.2 + 0.75 * 0.4)  # 0.25 s: three quarters from 0.1 to 0.3


def test_future_label_tolerates_accumulated_timestamp_rounding():
    t_s = np.cumsum(np.full(8, 0.05)) - 0.05  # 0.0, 0.05, ... with float drift
    steering = np.arange(8, dtype=np.float32)
    labels, has_future = future_steering_labels(np.zeros(8, int), t_s, steering, (0.15,))
    assert has_future.tolist() == [True] * 5 + [False] * 3  # the row at 0.20 reaches exactly the last sample
    np.testing.assert_allclose(labels[:5, 0], [3, 4, 5, 6, 7], atol=1e-5)


def test_time_going_backwards_inside_an_episode_is_rejected():
    with pytest.raises(ValueError, match="episode 4: t_s is not strictly increasing"):
        future_steering_labels(np.full(3, 4), np.array([0.0, 0.1, 0.1]), np.zeros(3, np.float32), (0.1,))


def test_tapm_rows_carry_the_dataset_rows_and_their_future_labels(tmp_path):
    dataset = read_dataset(make_synthetic_dataset(tmp_path / "data", n_episodes=2, steps_per_episode=20))
    rows = tapm_rows(dataset, (0.15, 0.20, 0.25, 0.30, 0.35))
    steering = dataset.steps["steering"]
    # Each episode of 20 steps loses its last 7 rows (0.35 s = 7 steps).
    assert len(rows) == 2 * 13
    assert rows.targets.shape == (26, 5)
    first_of_second_episode = 13
    assert rows.frame_index[first_of_second_episode] == 20
    np.testing.assert_allclose(
        rows.targets[first_of_second_episode], steering[[23, 24, 25, 26, 27]], atol=1e-6
    )
    np.testing.assert_array_equal(rows.steering, steering[rows.frame_index])


def test_bm_rows_with_a_label_lead_pair_each_frame_with_the_steering_that_many_steps_later(tmp_path):
    # The synthetic dataset runs at 20 Hz: a 0.10 s lead is 2 steps.
    dataset = read_dataset(make_synthetic_dataset(tmp_path / "data", n_episodes=2, steps_per_episode=20))
    steering = dataset.steps["steering"]
    rows = bm_rows(dataset, label_lead_s=0.10)
    # Each episode of 20 steps loses its last 2 rows; the second episode starts at frame 20.
    assert len(rows) == 2 * 18
    assert rows.frame_index.tolist() == list(range(18)) + list(range(20, 38))
    np.testing.assert_allclose(rows.targets[:, 0], steering[rows.frame_index + 2], atol=1e-6)
    # Balancing looks at the aligned label, not at the steering recorded with the frame.
    np.testing.assert_array_equal(rows.steering, rows.targets[:, 0])


def test_bm_rows_without_a_lead_keep_every_row_and_its_own_steering(tmp_path):
    dataset = read_dataset(make_synthetic_dataset(tmp_path / "data", n_episodes=2, steps_per_episode=20))
    rows = bm_rows(dataset)
    assert rows.frame_index.tolist() == list(range(40))
    np.testing.assert_array_equal(rows.targets[:, 0], dataset.steps["steering"])
    np.testing.assert_array_equal(rows.steering, dataset.steps["steering"])


def test_tapm_rows_with_a_label_lead_shift_every_horizon_by_it(tmp_path):
    dataset = read_dataset(make_synthetic_dataset(tmp_path / "data", n_episodes=2, steps_per_episode=20))
    steering = dataset.steps["steering"]
    rows = tapm_rows(dataset, (0.15, 0.25), label_lead_s=0.10)
    # t + 0.10 + 0.25 s is 7 steps ahead: each episode keeps 13 rows.
    assert len(rows) == 2 * 13
    np.testing.assert_allclose(rows.targets[:, 0], steering[rows.frame_index + 5], atol=1e-6)
    np.testing.assert_allclose(rows.targets[:, 1], steering[rows.frame_index + 7], atol=1e-6)
    np.testing.assert_allclose(rows.steering, steering[rows.frame_index + 2], atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(episode_lengths=st.lists(st.integers(1, 30), min_size=1, max_size=5), lead_steps=st.integers(0, 10))
def test_an_aligned_label_is_the_same_episodes_steering_lead_steps_later(episode_lengths, lead_steps):
    # 30 Hz episodes of random lengths, steering = a distinct value per row: every aligned label must
    # name the row lead_steps later in the same episode, and no row whose episode ends sooner may stay.
    dt_s = 1 / 30
    n_rows = sum(episode_lengths)
    steps = {
        "episode_id": np.repeat(np.arange(len(episode_lengths)), episode_lengths).astype(np.int32),
        "t_s": np.concatenate([np.arange(n) * dt_s for n in episode_lengths]),
        "speed_mps": np.full(n_rows, 16.7, np.float32),
        "steering": (np.arange(n_rows) / n_rows).astype(np.float32),
    }
    dataset = Dataset(manifest={}, frames=np.zeros((n_rows, 1, 1), np.uint8), steps=steps)
    rows = bm_rows(dataset, label_lead_s=lead_steps * dt_s)
    position = np.concatenate([np.arange(n) for n in episode_lengths])
    length = np.repeat(episode_lengths, episode_lengths)
    np.testing.assert_array_equal(rows.frame_index, np.flatnonzero(position + lead_steps < length))
    np.testing.assert_allclose(rows.targets[:, 0], steps["steering"][rows.frame_index + lead_steps], atol=1e-6)


# --- balancing ------------------------------------------------------------------------------------


def skewed_steering(rng: np.random.Generator) -> np.ndarray:
    return np.concatenate([rng.normal(0, 0.01, 5000), rng.uniform(-1, 1, 700)]).astype(np.float32)


def test_balancing_caps_every_bin_and_keeps_sparse_bins_whole():
    steering = skewed_steering(np.random.default_rng(0))
    kept = balance_by_histogram(steering, max_per_bin=100, rng=np.random.default_rng(1))
    counts_before, _ = np.histogram(steering, bins=35, range=(-1, 1))
    counts_after, _ = np.histogram(steering[kept], bins=35, range=(-1, 1))
    np.testing.assert_array_equal(counts_after, np.minimum(counts_before, 100))
    assert np.all(np.diff(kept) > 0)  # sorted, no duplicates


def test_balancing_is_seeded():
    steering = skewed_steering(np.random.default_rng(0))

    def kept(seed):
        return balance_by_histogram(steering, 100, np.random.default_rng(seed))

    np.testing.assert_array_equal(kept(5), kept(5))
    assert not np.array_equal(kept(5), kept(6))


def test_balance_figure_is_written_as_png(tmp_path):
    steering = skewed_steering(np.random.default_rng(0))
    path = save_balance_figure(
        steering,
        steering[balance_by_histogram(steering, 100, np.random.default_rng(0))],
        tmp_path / "figures" / "balance.png",
    )
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --- validation split -----------------------------------------------------------------------------


def rows_for(episode_id: np.ndarray, t_s: np.ndarray) -> LabelledRows:
    n = len(episode_id)
    zeros = np.zeros(n, np.float32)
    return LabelledRows(np.arange(n), episode_id, t_s, zeros, zeros, zeros[:, None])


def test_split_by_episode_keeps_each_episode_on_one_side():
    episode_id = np.repeat(np.arange(10), 50)
    train, val = split_train_val(
        rows_for(episode_id, np.tile(np.arange(50) * 0.05, 10)), 0.2, np.random.default_rng(0)
    )
    assert not set(train.episode_id) & set(val.episode_id)
    assert len(val) == 100 and len(train) == 400


def test_split_with_few_episodes_uses_contiguous_time_blocks():
    t_s = np.arange(1200) * 0.05  # one 60 s episode = six 10 s blocks
    train, val = split_train_val(rows_for(np.zeros(1200, int), t_s), 0.2, np.random.default_rng(0))
    assert not set(np.floor(train.t_s / 10)) & set(np.floor(val.t_s / 10))
    assert len(val) == 400  # whole blocks until >= 20%: two of six
    assert len(train) + len(val) == 1200


def test_split_refuses_a_single_block():
    with pytest.raises(ValueError, match="one block"):
        split_train_val(rows_for(np.zeros(10, int), np.arange(10) * 0.05), 0.2, np.random.default_rng(0))


# --- augmentation ---------------------------------------------------------------------------------


def test_flip_mirrors_the_image_once_and_negates_every_label_once():
    frames = torch.arange(2 * 3 * 4, dtype=torch.uint8).view(2, 3, 4)
    targets = torch.tensor([[0.1, 0.2, -0.3, 0.4, 0.5], [0.6, -0.7, 0.8, 0.9, 1.0]])
    flipped_frames, flipped_targets = flip_horizontally(frames, targets, torch.tensor([True, False]))
    np.testing.assert_array_equal(flipped_frames[0].numpy(), np.fliplr(frames[0].numpy()))
    assert torch.equal(flipped_targets[0], -targets[0])
    assert torch.equal(flipped_frames[1], frames[1]) and torch.equal(flipped_targets[1], targets[1])


@pytest.mark.parametrize("n_labels", [1, 2, 5])
def test_augment_with_certain_flip_and_unit_gamma_negates_all_labels_whatever_their_number(n_labels):
    # The original applied its flip once per label column; whatever the count, each label flips once.
    frames = torch.randint(0, 256, (4, 6, 8), dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    targets = torch.rand(4, n_labels) * 2 - 1
    out_frames, out_targets = augment(frames, targets, Augmentation(1.0, (1.0, 1.0)), torch.Generator())
    assert torch.equal(out_frames, frames.flip(-1))
    assert torch.equal(out_targets, -targets)


def test_augmentation_is_reproducible_with_the_callers_generator():
    frames = torch.randint(0, 256, (16, 6, 8), dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    targets = torch.rand(16, 3)

    def run(seed):
        return augment(frames, targets, Augmentation(), torch.Generator().manual_seed(seed))

    first, again, other = run(3), run(3), run(4)
    assert torch.equal(first[0], again[0]) and torch.equal(first[1], again[1])
    assert not torch.equal(first[0], other[0])


def test_gamma_changes_brightness_but_keeps_black_and_white():
    frames = torch.tensor([[[0, 64, 128, 255]]], dtype=torch.uint8)
    assert torch.equal(adjust_gamma(frames, torch.tensor([1.0])), frames)
    darker = adjust_gamma(frames, torch.tensor([2.0]))
    assert darker[0, 0].tolist() == [0, 16, 64, 255]  # 255 * (x / 255) ** 2, rounded


# --- batching ---------------------------------------------------------------------------------------


def test_batches_read_uint8_frames_from_the_memory_map(tmp_path):
    dataset = read_dataset(make_synthetic_dataset(tmp_path / "data", n_episodes=2, steps_per_episode=20))
    assert isinstance(dataset.frames, np.memmap)
    rows = bm_rows(dataset)
    batches = list(iterate_batches(dataset.frames, rows, batch_size=16))
    assert [len(batch.targets) for batch in batches] == [16, 16, 8]
    assert batches[0].frames.dtype == torch.uint8
    np.testing.assert_array_equal(batches[1].frames[0].numpy(), dataset.frames[16])
    assert batches[1].targets[0, 0] == dataset.steps["steering"][16]


def test_shuffled_batches_cover_every_row_once(tmp_path):
    dataset = read_dataset(make_synthetic_dataset(tmp_path / "data", n_episodes=2, steps_per_episode=20))
    rows = bm_rows(dataset)
    seen = torch.cat([b.targets[:, 0] for b in iterate_batches(dataset.frames, rows, 7, torch.Generator())])
    np.testing.assert_array_equal(np.sort(seen.numpy()), np.sort(rows.targets[:, 0]))
