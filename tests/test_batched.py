"""Batched closed loop: N runs stepped together give the one-env runs, step by step."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plm_highway.rollout.cells import RunCell, run_cells
from plm_highway.rollout.closed_loop import LOG_COLUMNS, drive
from plm_highway.rollout.policies import make_policy

# Different seeds, latency profiles (a random one among them), tracks and lengths, so the batch shrinks.
MODEL_CELLS = [
    RunCell("plm steps s0", "plm", "test", "steps:0.0-0.35:1.0", 0, max_steps=30),
    RunCell("plm steps s1", "plm", "test", "steps:0.0-0.35:1.0", 1, max_steps=22),
    RunCell("bm const", "bm", "unseen", "const:0.25", 3, max_steps=26),
    RunCell("plm beyond grid", "plm", "test", "const:0.5", 2, max_steps=18),
    RunCell("plm biased", "plm", "test", "const:0.2", 0, latency_bias_s=0.05, max_steps=20),
    RunCell("expert", "expert", "train", "const:0.1", 4, max_steps=24),
]


def one_env(cell: RunCell):
    policy = make_policy(cell.policy, latency_bias_s=cell.latency_bias_s) if cell.policy == "plm" \
        else make_policy(cell.policy)
    return drive(cell.name, policy, cell.track, cell.latency, cell.seed, cell.camera, cell.env_config,
                 max_steps=cell.max_steps)


@pytest.fixture(scope="module")
def one_env_logs():
    return [one_env(cell) for cell in MODEL_CELLS]


@pytest.mark.slow
def test_batch_invariant_runs_equal_one_env_runs_bit_for_bit(one_env_logs):
    logs = run_cells(MODEL_CELLS, batch_size=4, batch_invariant=True)
    assert [log.name for log in logs] == [cell.name for cell in MODEL_CELLS]
    for log, reference in zip(logs, one_env_logs):
        assert log.steps == reference.steps
        for column in LOG_COLUMNS:
            np.testing.assert_array_equal(log.columns[column], reference.columns[column], err_msg=f"{log.name} {column}")
        assert (log.left_road, log.completed_fraction, log.extras) == \
            (reference.left_road, reference.completed_fraction, reference.extras)


@pytest.mark.slow
@pytest.mark.parametrize("batch_size,threads", [(len(MODEL_CELLS), 1), (3, 2)])
def test_named_policies_batched_equal_one_env_runs_bit_for_bit(one_env_logs, batch_size, threads):
    # The named policies run batch-invariant kernels: no flag needed, any batch size or thread split.
    logs = run_cells(MODEL_CELLS, batch_size=batch_size, threads=threads)
    for log, reference in zip(logs, one_env_logs):
        assert log.steps == reference.steps
        for column in LOG_COLUMNS:
            np.testing.assert_array_equal(log.columns[column], reference.columns[column], err_msg=f"{log.name} {column}")
        assert (log.left_road, log.completed_fraction, log.extras) == \
            (reference.left_road, reference.completed_fraction, reference.extras)


# One forward pass of a float32 network on identical inputs, with another summation order (PyTorch's own kernels
# pick it by batch size and processor): the steering (|steering| <= 1, a tanh) differs by a few float32 ulps of the
# pre-activations, ~1e-6; 1e-5 is about a hundred ulps at 1. A closed loop is not compared with this tolerance: it
# feeds each step's rounding back through the car and the camera, and how far it then drifts depends on the processor.
ONE_FORWARD_ATOL = 1e-5


class RecordingModel:
    """A model policy that records each call's inputs and steering (what a one-env run gave its model)."""

    def __init__(self, model):
        self.model, self.calls = model, []

    def __getattr__(self, name):
        return getattr(self.model, name)

    def __call__(self, frame, speed_mps, latency_s=0.0):
        steering = self.model(frame, speed_mps, latency_s)
        self.calls.append((np.array(frame), float(speed_mps), float(latency_s), steering))
        return steering


def default_kernel_plm():
    policy = make_policy("plm")
    policy.model_policy.batch_invariant = False
    return policy


@pytest.mark.slow
def test_a_default_kernel_policy_batched_matches_its_one_env_runs_step_by_step_to_one_forward_rounding():
    # Step by step on identical inputs: the frames, speeds and latencies each one-env run gave its model, as one
    # batch per step, against the steering each got alone.
    recorded = []
    for seed in range(4):
        policy = default_kernel_plm()
        policy.model_policy = RecordingModel(policy.model_policy)
        drive(f"seed {seed}", policy, "test", "steps:0.0-0.35:1.0", seed, max_steps=25)
        recorded.append(policy.model_policy.calls)
    model = default_kernel_plm().model_policy
    assert model.batch_invariant is False
    for step in range(min(len(calls) for calls in recorded)):
        frames, speeds, latencies, alone = zip(*(calls[step] for calls in recorded))
        batched = model.steer_batch(np.stack(frames), speeds, latencies)
        np.testing.assert_allclose(batched, alone, rtol=0, atol=ONE_FORWARD_ATOL, err_msg=f"step {step}")


@pytest.mark.slow
def test_a_default_kernel_policy_batched_keeps_the_model_free_columns_of_its_one_env_runs():
    default_kernels = default_kernel_plm()
    cells = [RunCell(f"seed {seed}", default_kernels, "test", "steps:0.0-0.35:1.0", seed, max_steps=25)
             for seed in range(4)]
    references = [drive(c.name, default_kernels, c.track, c.latency, c.seed, max_steps=25) for c in cells]
    for log, reference in zip(run_cells(cells), references):
        assert log.steps == reference.steps
        # time, latency and its realisation do not depend on the model (the segment does: it is where the car is)
        for column in ("t_s", "latency_s", "observation_age_s"):
            np.testing.assert_array_equal(log.columns[column], reference.columns[column])


@pytest.mark.slow
def test_paper_conditions_batched_equal_one_env_runs(one_env_logs):
    # FIFO injection, image noise from the seed's own stream, PLM-Net told the requested latency.
    options = {"injection": "legacy-fifo", "image_noise_std": 3.0, "env_config": {"policy_frequency": 30,
                                                                                  "simulation_frequency": 30}}
    cells = [RunCell(f"seed {seed}", policy, "test", latency, seed, latency_source="requested", max_steps=20,
                     **options)
             for seed, (policy, latency) in enumerate([("plm", "frames:9-21:60@30"), ("bm", "const:0.2"),
                                                      ("plm", "steps:0.0-0.35:1.0"), ("expert", "const:0.1")])]
    logs = run_cells(cells, batch_size=3)
    for cell, log in zip(cells, logs):
        policy = make_policy(cell.policy, latency_source="requested") if cell.policy != "expert" \
            else make_policy("expert")
        reference = drive(cell.name, policy, cell.track, cell.latency, cell.seed, max_steps=20, **options)
        for column in LOG_COLUMNS:
            np.testing.assert_array_equal(log.columns[column], reference.columns[column], err_msg=f"{cell.name} {column}")


def test_the_plm_run_beyond_the_grid_counts_its_clamped_steps(one_env_logs):
    beyond = one_env_logs[3]
    # 0.5 s is beyond the 0.35 s grid once the history is that old (after the first 0.5 s = 10 steps)
    assert 0 < beyond.extras["latency_clamped_steps"] < beyond.steps


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(["test", "unseen"]), st.sampled_from(["const:0", "const:0.15", "sine:0.2:0.1:2"]),
                          st.integers(0, 2**32 - 1), st.integers(1, 12)), min_size=1, max_size=5),
       st.integers(1, 6))
def test_any_batch_of_expert_runs_equals_its_one_env_runs(specs, batch_size):
    cells = [RunCell(f"run {i}", "expert", track, latency, seed, max_steps=steps)
             for i, (track, latency, seed, steps) in enumerate(specs)]
    logs = run_cells(cells, batch_size=batch_size)
    for cell, log in zip(cells, logs):
        reference = one_env(cell)
        for column in LOG_COLUMNS:
            np.testing.assert_array_equal(log.columns[column], reference.columns[column])


def test_a_stateful_policy_object_in_two_cells_is_refused():
    class Counting:
        def reset(self):
            self.n = 0

        def __call__(self, frame, info):
            self.n += 1
            return 0.0

    shared = Counting()
    with pytest.raises(ValueError, match="one policy object in two cells"):
        run_cells([RunCell("a", shared, max_steps=2), RunCell("b", shared, max_steps=2)])
    logs = run_cells([RunCell("a", Counting(), max_steps=3), RunCell("b", Counting(), max_steps=2)])
    assert [log.steps for log in logs] == [3, 2]


def test_bad_cells_are_refused_before_any_run():
    with pytest.raises(ValueError, match="policy 'pid'"):
        run_cells([RunCell("a", "pid")])
    with pytest.raises(ValueError, match="max_steps 0"):
        run_cells([RunCell("a", "expert", max_steps=0)])
    with pytest.raises(ValueError, match="batch_size"):
        run_cells([RunCell("a", "expert")], batch_size=0)


@pytest.mark.slow
def test_a_policy_object_shared_by_cells_is_batched_and_batch_invariant_on_request(one_env_logs):
    shared = make_policy("plm")
    shared.model_policy.batch_invariant = False  # a caller's object with PyTorch's own kernels
    cells = [RunCell(c.name, shared, c.track, c.latency, c.seed, max_steps=c.max_steps) for c in MODEL_CELLS[:2]]
    logs = run_cells(cells, batch_invariant=True)
    for log, reference in zip(logs, one_env_logs[:2]):  # the one-env runs of the (batch-invariant) named policy
        for column in LOG_COLUMNS:
            np.testing.assert_array_equal(log.columns[column], reference.columns[column])
    assert shared.model_policy.batch_invariant is False  # the caller's object is left as it was
