"""Base Model, TAPM, PLM-Net forward and Algorithm 1 (plm_highway.models)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import plm_highway
from plm_highway import cli
from plm_highway.models import batch_invariant, shipped
from plm_highway.models.base_model import (
    BaseModel,
    BaseModelConfig,
    count_parameters,
    normalise_frames,
    preset_config,
)
from plm_highway.models.checkpoints import (
    checkpoint_paths,
    load_base_model,
    load_plm_net,
    load_tapm,
    save_checkpoint,
    state_dict_fingerprint,
    state_fingerprint,
)
from plm_highway.models.inference import BaseModelPolicy, NonFiniteSteeringError, PLMNetPolicy
from plm_highway.models.plm_net import (
    SPARSE_CHUNK,
    FusedPLMNet,
    Int8Linear,
    PLMNet,
    SparseInputLinear,
    fold_scalar_branches,
    interpolate_actions,
)
from plm_highway.models.shipped import load_shipped_plm_net, shipped_checkpoint_dir
from plm_highway.models.tapm import TAPM, TAPMConfig

PAPER_DELTA_REF_S = [0.0, 0.15, 0.20, 0.25, 0.30, 0.35]


def random_frames(n: int, image_size_px=(66, 200), seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (n, *image_size_px), dtype=torch.uint8, generator=generator)


def small_plm_net(seed: int = 0) -> PLMNet:
    torch.manual_seed(seed)
    bm = BaseModel()
    return PLMNet(bm, TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim))).eval()


# --- parameter counts (paper preset = the original's, see plm-net-original.md) -------------------


def test_paper_preset_image_features_are_13x13x64():
    assert preset_config("paper").image_feature_dim == 13 * 13 * 64 == 10_816


def test_paper_preset_bm_parameter_count_speed_only():
    assert count_parameters(BaseModel(preset_config("paper"))) == 5_800_550


def test_paper_preset_bm_parameter_count_with_acceleration():
    assert count_parameters(BaseModel(preset_config("paper", embed_acceleration=True))) == 5_874_566


def test_grayscale_steering_only_160px_bm_drops_the_parity_layers():
    # 1,200 conv1 weights for the 2 extra input channels + the 11-parameter throttle head.
    config = preset_config("paper", input_channels=1, throttle_head=False)
    assert count_parameters(BaseModel(config)) == 5_800_550 - 1_200 - 11


def test_paper_preset_tapm_trainable_parameter_count():
    # 100*1+100 + 500*10816+500 + 100*144+100 + 5 * (200*700+200 + 100*200+100 + 50*100+50 + 1*50+1)
    tapm = TAPM(TAPMConfig(image_feature_dim=10_816))
    assert count_parameters(tapm, trainable=True) == 6_250_205


def test_plm_net_freezes_the_bm_and_trains_only_the_tapm():
    plm_net = small_plm_net()
    assert count_parameters(plm_net, trainable=False) == count_parameters(plm_net.bm)
    assert count_parameters(plm_net, trainable=True) == count_parameters(plm_net.tapm)


def test_default_preset_follows_pilotnet_input():
    config = preset_config("default")
    assert config.image_size_px == (66, 200)
    assert config.image_feature_dim == 1 * 18 * 64


# --- Base Model ----------------------------------------------------------------------------------


def test_normalise_frames_stretches_each_image_to_minus_one_one():
    frames = torch.tensor([[[10, 20], [30, 110]], [[0, 255], [255, 0]], [[7, 7], [7, 7]]], dtype=torch.uint8)
    pixels = normalise_frames(frames)
    assert pixels.shape == (3, 1, 2, 2)
    torch.testing.assert_close(pixels[0, 0], torch.tensor([[-1.0, -0.8], [-0.6, 1.0]]))
    torch.testing.assert_close(pixels[1, 0], torch.tensor([[-1.0, 1.0], [1.0, -1.0]]))
    assert torch.all(pixels[2] == -1.0)  # a constant image carries no information


def test_bm_output_is_bounded_steering_per_sample():
    bm = BaseModel().eval()
    steering = bm(random_frames(4), torch.full((4,), 16.7))
    assert steering.shape == (4,)
    assert torch.all(steering.abs() <= 1)


def test_bm_forward_is_encode_then_steering_from_features():
    bm = BaseModel().eval()
    frames, speed = random_frames(3), torch.full((3,), 16.7)
    z_o, z_v = bm.encode(frames, speed)
    assert z_o.shape == (3, bm.image_feature_dim) and z_v.shape == (3, 144)
    assert torch.equal(bm.steering_from_features(z_o, z_v), bm(frames, speed))


def test_bm_with_acceleration_and_linear_convs_runs():
    bm = BaseModel(BaseModelConfig(conv_activation="none", embed_acceleration=True)).eval()
    assert bm(random_frames(2), torch.full((2,), 16.7), torch.zeros(2)).shape == (2,)


def test_paper_preset_runs_on_grayscale_160px_frames():
    bm = BaseModel(preset_config("paper")).eval()
    assert bm(random_frames(1, (160, 160)), torch.tensor([16.7])).shape == (1,)


def test_bm_rejects_frames_of_another_camera():
    with pytest.raises(ValueError, match=r"expected \(B, 66, 200\)"):
        BaseModel()(random_frames(1, (160, 160)), torch.tensor([16.7]))


# Architecture configs arrive from checkpoint JSON: each bad value is named, before any allocation.
BAD_BM_CONFIGS = [
    pytest.param({"conv_activation": "elu"}, r"conv_activation: 'elu' is not one of", id="activation"),
    pytest.param({"conv_activation": 3}, r"conv_activation: 3 is not one of", id="activation-type"),
    pytest.param({"image_height_px": 20}, r"image_height_px: must lie in \[61, 400\], got 20", id="too-small"),
    pytest.param({"image_height_px": 60}, r"image_height_px: must lie in \[61, 400\]", id="just-too-small"),
    pytest.param({"image_height_px": 3000, "image_width_px": 3000}, r"image_height_px: must lie in \[61, 400\], "
                 r"got 3000", id="3000px"),
    pytest.param({"image_width_px": 401}, r"image_width_px: must lie in \[61, 400\], got 401", id="just-too-wide"),
    pytest.param({"image_height_px": "66"}, r"image_height_px: expected an integer .*got str '66'", id="str-size"),
    pytest.param({"image_height_px": 66.0}, r"image_height_px: expected an integer .*got float", id="float-size"),
    pytest.param({"image_height_px": True}, r"image_height_px: expected an integer .*got bool", id="bool-size"),
    pytest.param({"input_channels": 0}, r"input_channels: must lie in \[1, 4\]", id="no-channels"),
    pytest.param({"input_channels": 64}, r"input_channels: must lie in \[1, 4\]", id="many-channels"),
    pytest.param({"embed_acceleration": "yes"}, r"embed_acceleration: expected true or false, got str",
                 id="str-bool"),
    pytest.param({"throttle_head": 1}, r"throttle_head: expected true or false, got int", id="int-bool"),
    pytest.param({"speed_scale_mps": 0}, r"speed_scale_mps: must be a finite number in \(0, 1000\]",
                 id="speed-scale-0"),
    pytest.param({"speed_scale_mps": float("nan")}, r"speed_scale_mps: must be a finite", id="speed-scale-nan"),
    pytest.param({"speed_scale_mps": [20]}, r"speed_scale_mps: expected a number .*got list", id="speed-scale-list"),
    pytest.param({"dropout": 1.0}, r"dropout: must be a finite number in \[0, 1\)", id="dropout-1"),
    pytest.param({"dropout": -0.1}, r"dropout: must be a finite number in \[0, 1\)", id="dropout-negative"),
]


@pytest.mark.parametrize("overrides, message", BAD_BM_CONFIGS)
def test_invalid_bm_config_is_rejected_naming_the_field(overrides, message):
    with pytest.raises(ValueError, match=message):
        BaseModelConfig(**overrides)


@pytest.mark.parametrize("side_px", [61, 400])
def test_image_size_bounds_are_inclusive(side_px):
    assert BaseModelConfig(image_height_px=side_px, image_width_px=side_px).image_feature_dim >= 64


def test_unknown_preset_is_rejected():
    with pytest.raises(ValueError, match="preset"):
        preset_config("huge")


# --- TAPM ------------------------------------------------------------------------------------------


def reference_head(tapm: TAPM, head: int, trunk: torch.Tensor) -> torch.Tensor:
    """Head ``head`` as a plain per-head MLP built from the grouped weights (eval mode)."""
    width = tapm.heads_in.out_features // tapm.config.n_heads
    rows = slice(head * width, (head + 1) * width)
    hidden = torch.relu(trunk @ tapm.heads_in.weight[rows].T + tapm.heads_in.bias[rows])
    hidden = torch.relu(hidden @ tapm.heads_hidden.weight[head] + tapm.heads_hidden.bias[head, 0])
    hidden = torch.tanh(hidden @ tapm.heads_tanh.weight[head] + tapm.heads_tanh.bias[head, 0])
    return torch.tanh(hidden @ tapm.heads_out.weight[head] + tapm.heads_out.bias[head, 0])[:, 0]


def test_batched_heads_equal_independent_per_head_mlps():
    torch.manual_seed(0)
    tapm = TAPM(TAPMConfig(image_feature_dim=32)).eval()
    a_bm, z_o, z_v = torch.rand(6) * 2 - 1, torch.randn(6, 32), torch.randn(6, 144)
    trunk = torch.relu(torch.cat([tapm.action_fc(a_bm[:, None]), tapm.image_fc(z_o), tapm.speed_fc(z_v)], 1))
    actions = tapm(a_bm, z_o, z_v)
    assert actions.shape == (6, 5)
    for head in range(5):
        torch.testing.assert_close(actions[:, head], reference_head(tapm, head, trunk), rtol=1e-5, atol=1e-6)


def test_a_loss_on_one_head_leaves_the_other_heads_weights_without_gradient():
    torch.manual_seed(0)
    tapm = TAPM(TAPMConfig(image_feature_dim=32))
    tapm(torch.rand(4), torch.randn(4, 32), torch.randn(4, 144))[:, 2].sum().backward()
    for layer in (tapm.heads_hidden, tapm.heads_tanh, tapm.heads_out):
        grad_norm_per_head = layer.weight.grad.flatten(1).norm(dim=1)
        assert grad_norm_per_head[2] > 0
        assert torch.all(grad_norm_per_head[[0, 1, 3, 4]] == 0)


def test_tapm_dropout_is_active_only_in_train_mode():
    torch.manual_seed(0)
    tapm = TAPM(TAPMConfig(image_feature_dim=32))
    inputs = (torch.rand(8), torch.randn(8, 32), torch.randn(8, 144))
    assert not torch.equal(tapm.train()(*inputs), tapm(*inputs))
    assert torch.equal(tapm.eval()(*inputs), tapm(*inputs))


BAD_TAPM_CONFIGS = [
    pytest.param({"delta_grid_s": ()}, r"delta_grid_s: expected 1 to 32 latencies, got 0", id="empty-grid"),
    pytest.param({"delta_grid_s": (0.2, 0.15)}, r"delta_grid_s: latencies must be strictly increasing",
                 id="decreasing"),
    pytest.param({"delta_grid_s": (0.0, 0.1)}, r"delta_grid_s: latencies must be finite numbers in \(0, 10\] s, "
                 r"got 0.0", id="zero"),
    pytest.param({"delta_grid_s": (0.1, float("nan"))}, r"delta_grid_s: .*got nan", id="nan"),
    pytest.param({"delta_grid_s": (0.1, 11.0)}, r"delta_grid_s: .*\(0, 10\] s, got 11.0", id="too-late"),
    pytest.param({"delta_grid_s": tuple(0.01 * (i + 1) for i in range(33))}, r"expected 1 to 32 latencies, got 33",
                 id="33-heads"),
    pytest.param({"delta_grid_s": "0.15"}, r"delta_grid_s: expected a list of latencies .*got str", id="str-grid"),
    pytest.param({"delta_grid_s": (0.1, "0.2")}, r"delta_grid_s: .*got '0.2'", id="str-in-grid"),
    pytest.param({"delta_grid_s": (True,)}, r"delta_grid_s: .*got True", id="bool-in-grid"),
    pytest.param({"image_feature_dim": 0}, r"image_feature_dim: must lie in \[1, 118336\]", id="no-features"),
    pytest.param({"image_feature_dim": 10**9}, r"image_feature_dim: must lie in \[1, 118336\], got 1000000000",
                 id="huge-features"),
    pytest.param({"image_feature_dim": "1152"}, r"image_feature_dim: expected an integer", id="str-features"),
    pytest.param({"speed_feature_dim": 10**6}, r"speed_feature_dim: must lie in \[1, 4096\]", id="huge-speed"),
    pytest.param({"dropout": "0.3"}, r"dropout: expected a number", id="str-dropout"),
]


@pytest.mark.parametrize("overrides, message", BAD_TAPM_CONFIGS)
def test_invalid_tapm_config_is_rejected_naming_the_field(overrides, message):
    with pytest.raises(ValueError, match=message):
        TAPMConfig(**{"image_feature_dim": 8, **overrides})


def test_a_subset_of_heads_equals_those_columns_of_all_heads():
    torch.manual_seed(0)
    tapm = TAPM(TAPMConfig(image_feature_dim=32)).eval()
    trunk = tapm.trunk(torch.rand(5) * 2 - 1, torch.randn(5, 500), torch.randn(5, 144))
    every_head = tapm.heads(trunk)
    for first, stop in ((0, 1), (1, 3), (3, 5), (0, 5), (4, 5)):
        torch.testing.assert_close(tapm.heads(trunk, first, stop), every_head[:, first:stop], rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match=r"range \[3, 6\)"):
        tapm.heads(trunk, 3, 6)


def test_configurable_delta_grid_sets_the_number_of_heads():
    tapm = TAPM(TAPMConfig(image_feature_dim=8, delta_grid_s=(0.1, 0.2, 0.4))).eval()
    assert tapm(torch.rand(2), torch.randn(2, 8), torch.randn(2, 144)).shape == (2, 3)


# --- Algorithm 1, hand-computed -------------------------------------------------------------------

# a_ref = [a_BM, a_0.15, a_0.20, a_0.25, a_0.30, a_0.35]
HAND_A_REF = [0.1, 0.4, 0.2, -0.2, 0.0, 0.5]
HAND_CASES = [
    (0.0, 0.1),  # latency 0: the BM's action
    (0.075, 0.25),  # half way between 0 and 0.15: (0.1 + 0.4) / 2
    (0.1, 0.3),  # 0.1 + (0.1 / 0.15) * (0.4 - 0.1) = 0.1 + 0.2
    (0.15, 0.4),  # on the grid: head 0.15
    (0.175, 0.3),  # (0.4 + 0.2) / 2
    (0.2, 0.2),  # on the grid: head 0.20
    (0.21, 0.12),  # 0.2 + (0.01 / 0.05) * (-0.2 - 0.2) = 0.2 - 0.08
    (0.27, -0.12),  # -0.2 + (0.02 / 0.05) * (0.0 + 0.2) = -0.2 + 0.08
    (0.34, 0.4),  # 0.0 + (0.04 / 0.05) * 0.5
    (0.35, 0.5),  # last head
    (0.5, 0.5),  # above the grid: clamped to the last head
]


@pytest.mark.parametrize("latency_s, expected", HAND_CASES)
def test_interpolation_matches_hand_computation_numpy(latency_s, expected):
    assert interpolate_actions(latency_s, PAPER_DELTA_REF_S, HAND_A_REF) == pytest.approx(expected, abs=1e-12)


def test_interpolation_matches_hand_computation_torch_batch():
    latencies = torch.tensor([case[0] for case in HAND_CASES], dtype=torch.float64)
    a_ref = torch.tensor(HAND_A_REF, dtype=torch.float64).expand(len(latencies), -1)
    result = interpolate_actions(latencies, torch.tensor(PAPER_DELTA_REF_S), a_ref)
    assert isinstance(result, torch.Tensor)
    torch.testing.assert_close(result, torch.tensor([case[1] for case in HAND_CASES], dtype=torch.float64))


def test_interpolation_uses_each_samples_own_actions():
    a_ref = np.array([[0.0, 0.3, 0.3, 0.3, 0.3, 0.3], [1.0, 0.0, 0.0, 0.0, 0.0, -1.0]])
    result = interpolate_actions(np.array([0.05, 0.325]), PAPER_DELTA_REF_S, a_ref)
    np.testing.assert_allclose(result, [0.1, -0.5])  # 0.3 * (0.05 / 0.15); -1 * (0.025 / 0.05)


@pytest.mark.parametrize("bad_latency_s", [float("nan"), -0.01, -1e-9])
def test_interpolation_rejects_nan_and_negative_latency(bad_latency_s):
    with pytest.raises(ValueError, match="latency_s"):
        interpolate_actions(bad_latency_s, PAPER_DELTA_REF_S, HAND_A_REF)


def test_interpolation_rejects_a_grid_that_does_not_increase():
    with pytest.raises(ValueError, match="increasing"):
        interpolate_actions(0.1, [0.0, 0.2, 0.2], [0.0, 1.0, 2.0])


# --- Algorithm 1, properties ----------------------------------------------------------------------

actions = st.floats(-1, 1, allow_nan=False, width=64)
a_refs = st.lists(actions, min_size=6, max_size=6)
latencies = st.floats(0, 0.35, allow_nan=False)


def neighbours(latency_s: float) -> tuple[int, int]:
    hi = int(np.searchsorted(PAPER_DELTA_REF_S, latency_s))
    return max(hi - 1, 0), max(hi, 1)


@given(a_refs, latencies)
def test_result_lies_between_the_neighbouring_grid_actions(a_ref, latency_s):
    lo, hi = neighbours(latency_s)
    result = float(interpolate_actions(latency_s, PAPER_DELTA_REF_S, a_ref))
    assert min(a_ref[lo], a_ref[hi]) <= result <= max(a_ref[lo], a_ref[hi])


@given(a_refs, st.integers(0, 5))
def test_grid_latency_returns_that_heads_action_exactly(a_ref, index):
    assert interpolate_actions(PAPER_DELTA_REF_S[index], PAPER_DELTA_REF_S, a_ref) == a_ref[index]


@given(a_refs)
def test_latency_zero_returns_the_bm_action(a_ref):
    assert interpolate_actions(0.0, PAPER_DELTA_REF_S, a_ref) == a_ref[0]


@given(a_refs, st.lists(latencies, min_size=2, max_size=20), st.booleans())
def test_monotone_in_latency_when_the_heads_are_monotone(a_ref, latency_list, decreasing):
    a_ref = sorted(a_ref, reverse=decreasing)
    latency_list = sorted(latency_list)
    results = interpolate_actions(np.array(latency_list), PAPER_DELTA_REF_S, a_ref)
    steps = np.diff(results)
    assert np.all(steps <= 0) if decreasing else np.all(steps >= 0)


@settings(max_examples=50)
@given(a_refs, st.floats(0.35, 10, allow_nan=False))
def test_latency_above_the_grid_uses_the_last_head(a_ref, latency_s):
    assert interpolate_actions(latency_s, PAPER_DELTA_REF_S, a_ref) == a_ref[-1]


@settings(max_examples=50)
@given(st.lists(st.tuples(a_refs, st.floats(0, 1, allow_nan=False)), min_size=1, max_size=8))
def test_algorithm_1_gives_the_same_values_on_numpy_and_torch(rows):
    from plm_highway.models.plm_net import interpolate_batch

    a_ref = np.array([row[0] for row in rows], dtype=np.float32)
    latency_s = np.array([row[1] for row in rows], dtype=np.float32)
    delta_ref_s = np.array(PAPER_DELTA_REF_S, dtype=np.float32)
    on_numpy = interpolate_batch(latency_s, delta_ref_s, a_ref)
    on_torch = interpolate_batch(*(torch.from_numpy(x) for x in (latency_s, delta_ref_s, a_ref)))
    assert on_numpy.dtype == np.float32
    assert np.array_equal(on_numpy, on_torch.numpy())  # exactly equal (0.0 and -0.0 may swap)


# --- PLM-Net ----------------------------------------------------------------------------------------


def test_plm_net_a_ref_starts_with_the_bm_action_and_has_one_action_per_head():
    plm_net = small_plm_net()
    frames, speed = random_frames(3), torch.full((3,), 16.7)
    with torch.inference_mode():
        output = plm_net(frames, speed, torch.zeros(3))
        assert output.a_ref.shape == (3, 6)
        assert torch.equal(output.a_ref[:, 0], plm_net.bm(frames, speed))
        assert torch.equal(output.steering, output.a_ref[:, 0])  # latency 0


def test_plm_net_interpolates_per_sample_and_counts_clamped_latencies():
    plm_net = small_plm_net()
    latency_s = torch.tensor([0.0, 0.15, 0.275, 0.35, 0.6, 2.0])
    with torch.inference_mode():
        output = plm_net(random_frames(6), torch.full((6,), 16.7), latency_s)
    a_ref = output.a_ref
    assert output.steering[1] == a_ref[1, 1]  # exactly the 0.15 s head
    torch.testing.assert_close(output.steering[2], (a_ref[2, 3] + a_ref[2, 4]) / 2)
    assert torch.equal(output.steering[3:], a_ref[3:, 5])  # on or above the last grid value
    assert output.n_clamped == 2


@pytest.mark.parametrize("grad", [False, True])
def test_plm_net_runs_the_convolutions_once(monkeypatch, grad):
    # With gradients through the conv modules, without them as one oneDNN stack (batch_invariant.conv_stack).
    plm_net = small_plm_net()
    calls = []
    plm_net.bm.convs[0].register_forward_hook(lambda *_: calls.append("module"))
    stack = batch_invariant.conv_stack
    monkeypatch.setattr(batch_invariant, "conv_stack", lambda *args: calls.append("stack") or stack(*args))
    with torch.set_grad_enabled(grad):
        plm_net(random_frames(2), torch.full((2,), 16.7), torch.tensor([0.1, 0.3]))
    assert calls == ["module" if grad else "stack"]


@pytest.mark.parametrize("bad_latency_s", [float("nan"), -0.05])
def test_plm_net_rejects_nan_and_negative_latency(bad_latency_s):
    with pytest.raises(ValueError, match="latency_s"):
        small_plm_net()(random_frames(2), torch.full((2,), 16.7), torch.tensor([0.1, bad_latency_s]))


def test_plm_net_keeps_the_bm_in_eval_mode_when_put_in_train_mode():
    plm_net = small_plm_net().train()
    assert plm_net.tapm.training and not plm_net.bm.training
    assert not any(p.requires_grad for p in plm_net.bm.parameters())


def test_plm_net_rejects_a_tapm_built_for_another_image_size():
    with pytest.raises(ValueError, match="image features of size 10816"):
        PLMNet(BaseModel(), TAPM(TAPMConfig(image_feature_dim=10_816)))


# --- checkpoints ------------------------------------------------------------------------------------


def saved_pair(tmp_path, seed: int = 0) -> tuple[PLMNet, object, object]:
    """A BM and TAPM saved as tmp_path/bm and tmp_path/tapm (directories, as training writes them)."""
    plm_net = small_plm_net(seed)
    bm_dir, tapm_dir = tmp_path / "bm", tmp_path / "tapm"
    save_checkpoint(bm_dir, plm_net.bm, {"preset": "default", "image_size_px": [66, 200]})
    save_checkpoint(tapm_dir, plm_net.tapm, {"bm_fingerprint": state_fingerprint(plm_net.bm)})
    return plm_net, bm_dir, tapm_dir


def edit_description(path, **changes) -> None:
    json_path = checkpoint_paths(path)[1]
    document = json.loads(json_path.read_text())
    for key, value in changes.items():
        if isinstance(value, dict):
            document[key].update(value)
        else:
            document[key] = value
    json_path.write_text(json.dumps(document))


def test_checkpoint_round_trip_gives_identical_outputs(tmp_path):
    plm_net, bm_dir, tapm_dir = saved_pair(tmp_path)
    loaded = load_plm_net(bm_dir, tapm_dir)
    assert not loaded.bm.training and not loaded.tapm.training
    frames, speed, latency_s = random_frames(3), torch.full((3,), 16.7), torch.tensor([0.0, 0.22, 0.4])
    with torch.inference_mode():
        assert torch.equal(
            loaded(frames, speed, latency_s).steering, plm_net(frames, speed, latency_s).steering
        )


def test_checkpoint_description_records_architecture_and_kind(tmp_path):
    _, bm_dir, tapm_dir = saved_pair(tmp_path)
    bm_document = json.loads((bm_dir / "model.json").read_text())
    tapm_document = json.loads((tapm_dir / "model.json").read_text())
    assert bm_document["kind"] == "base_model" and bm_document["architecture"]["image_height_px"] == 66
    assert tapm_document["kind"] == "tapm" and tapm_document["architecture"]["delta_grid_s"] == [
        0.15,
        0.2,
        0.25,
        0.3,
        0.35,
    ]


def test_checkpoint_files_can_be_named_by_either_file_of_the_pair(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    (bm_dir / "model.pt").rename(tmp_path / "bm_default.pt")
    (bm_dir / "model.json").rename(tmp_path / "bm_default.json")
    assert isinstance(load_base_model(tmp_path / "bm_default.pt"), BaseModel)
    assert isinstance(load_base_model(tmp_path / "bm_default.json"), BaseModel)


def test_bm_checkpoint_with_wrong_image_size_names_the_mismatching_key(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    edit_description(
        bm_dir, architecture={"image_height_px": 160, "image_width_px": 160}, image_size_px=[160, 160]
    )
    with pytest.raises(
        ValueError, match=r"key 'mlp.0.weight': expected shape \(512, 10960\), found \(512, 1296\)"
    ):
        load_base_model(bm_dir)


def test_bm_checkpoint_whose_image_size_field_disagrees_is_rejected(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    edit_description(bm_dir, image_size_px=[160, 160])
    with pytest.raises(ValueError, match="image_size_px"):
        load_base_model(bm_dir)


def test_tapm_checkpoint_with_another_delta_grid_names_the_mismatching_key(tmp_path):
    plm_net, _, tapm_dir = saved_pair(tmp_path)
    edit_description(tapm_dir, architecture={"delta_grid_s": [0.1, 0.2, 0.3]})
    with pytest.raises(
        ValueError, match=r"key 'heads_in.weight': expected shape \(600, 700\), found \(1000, 700\)"
    ):
        load_tapm(tapm_dir, plm_net.bm)


def test_missing_and_unexpected_keys_are_named(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    state = torch.load(bm_dir / "model.pt", weights_only=True)
    state["extra.weight"] = state.pop("steering_head.bias")
    torch.save(state, bm_dir / "model.pt")
    with pytest.raises(
        ValueError, match=r"missing keys \['steering_head.bias'\]; unexpected keys \['extra.weight'\]"
    ):
        load_base_model(bm_dir)


def test_tapm_checkpoint_for_another_image_size_is_rejected(tmp_path):
    _, _, tapm_dir = saved_pair(tmp_path)
    with pytest.raises(ValueError, match="image features of size 1152"):
        load_tapm(tapm_dir, BaseModel(preset_config("paper")))


def test_tapm_checkpoint_trained_on_another_bm_is_rejected(tmp_path):
    _, _, tapm_dir = saved_pair(tmp_path)
    with pytest.raises(ValueError, match="another BM"):
        load_tapm(tapm_dir, small_plm_net(seed=1).bm)


def test_checkpoint_of_the_wrong_kind_is_rejected(tmp_path):
    _, _, tapm_dir = saved_pair(tmp_path)
    with pytest.raises(ValueError, match="expected 'base_model'"):
        load_base_model(tapm_dir)


def test_unknown_architecture_field_is_rejected(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    edit_description(bm_dir, architecture={"wings": 2})
    with pytest.raises(ValueError, match=r"unknown architecture fields \['wings'\]"):
        load_base_model(bm_dir)


def test_missing_checkpoint_file_raises_file_not_found(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    (bm_dir / "model.pt").unlink()
    with pytest.raises(FileNotFoundError, match="model.pt"):
        load_base_model(bm_dir)


class NotATensor:
    pass


def test_weights_are_loaded_without_unpickling_code(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    torch.save({"steering_head.bias": NotATensor()}, bm_dir / "model.pt")
    with pytest.raises(ValueError, match="not a loadable state_dict"):
        load_base_model(bm_dir)


# --- shipped checkpoints ----------------------------------------------------------------------------


def test_shipped_checkpoint_dir_is_inside_the_package():
    assert shipped_checkpoint_dir() == Path(plm_highway.__file__).resolve().parent / "checkpoints"


def test_load_shipped_plm_net_explains_when_nothing_is_shipped(tmp_path, monkeypatch):
    monkeypatch.setattr(shipped, "shipped_checkpoint_dir", lambda: tmp_path)
    with pytest.raises(
        FileNotFoundError, match=r"no shipped PLM-Net checkpoints for preset 'default'.*bm_default.pt"
    ):
        load_shipped_plm_net()


def test_load_shipped_plm_net_loads_the_renamed_training_outputs(tmp_path, monkeypatch):
    _, bm_dir, tapm_dir = saved_pair(tmp_path)
    for source, name in ((bm_dir, "bm_default"), (tapm_dir, "tapm_default")):
        for suffix in (".pt", ".json"):
            (source / f"model{suffix}").rename(tmp_path / f"{name}{suffix}")
    monkeypatch.setattr(shipped, "shipped_checkpoint_dir", lambda: tmp_path)
    assert isinstance(load_shipped_plm_net(), PLMNet)


# --- policies -----------------------------------------------------------------------------------------


def test_policies_map_one_frame_to_a_steering_float():
    plm_net = small_plm_net()
    frame = random_frames(1)[0].numpy()
    bm_policy, plm_policy = BaseModelPolicy(plm_net.bm), PLMNetPolicy(plm_net)
    bm_steering = bm_policy(frame, 16.7, 0.2)
    assert isinstance(bm_steering, float) and -1 <= bm_steering <= 1
    # Latency 0 is the BM's action (the fused first layer may round differently in the last bit).
    assert plm_policy(frame, 16.7, 0.0) == pytest.approx(bm_steering, abs=1e-6)
    assert isinstance(plm_policy(frame, 16.7, 0.22), float)


def test_plm_net_policy_counts_clamped_latencies_until_reset():
    policy = PLMNetPolicy(small_plm_net())
    frame = random_frames(1)[0].numpy()
    for latency_s in (0.1, 0.36, 0.35, 0.5):
        policy(frame, 16.7, latency_s)
    assert policy.clamped_latency_count == 2
    policy.reset()
    assert policy.clamped_latency_count == 0


def test_policies_reject_wrong_frames_and_bad_latency():
    policy = PLMNetPolicy(small_plm_net())
    with pytest.raises(ValueError, match="frame"):
        policy(np.zeros((66, 200), dtype=np.float32), 16.7, 0.1)
    with pytest.raises(ValueError, match="latency_s"):
        BaseModelPolicy(policy.model.bm)(np.zeros((66, 200), dtype=np.uint8), 16.7, float("nan"))


def test_policy_accepts_a_non_contiguous_frame():
    policy = BaseModelPolicy(small_plm_net().bm)
    wide = np.zeros((66, 400), dtype=np.uint8)
    assert isinstance(policy(wide[:, ::2], 16.7), float)


# --- fused inference: equal to the reference forward --------------------------------------------------

GRID_LATENCIES_S = [0.0, 0.15, 0.2, 0.25, 0.3, 0.35]  # the grid points, with 0 (the BM)
BETWEEN_LATENCIES_S = [0.01, 0.075, 0.149, 0.151, 0.17, 0.2499, 0.27, 0.34]
ABOVE_LATENCIES_S = [0.3500001, 0.36, 0.5, 2.0, 100.0]


@pytest.fixture(scope="module")
def plm_pair():
    plm_net = small_plm_net()
    return plm_net, FusedPLMNet(plm_net)


def assert_fused_equals_reference(plm_net, fused, frames, speed, latency_s):
    with torch.inference_mode():
        reference = plm_net(frames, speed, latency_s)
        output = fused(frames, speed, latency_s)
    torch.testing.assert_close(output.steering, reference.steering, rtol=0, atol=1e-6)
    assert int(output.clamped.sum()) == output.n_clamped == reference.n_clamped
    return output, reference


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.sampled_from(GRID_LATENCIES_S + ABOVE_LATENCIES_S),
            st.floats(0, 0.35, allow_nan=False),
            st.floats(0.35, 20, allow_nan=False),
        ),
        min_size=1,
        max_size=6,
    ),
    st.integers(0, 2**16),
)
def test_fused_plm_net_equals_the_reference_forward(plm_pair, latencies, seed):
    plm_net, fused = plm_pair
    n = len(latencies)
    speed = torch.rand(n, generator=torch.Generator().manual_seed(seed)) * 30
    assert_fused_equals_reference(plm_net, fused, random_frames(n, seed=seed), speed, torch.tensor(latencies))


@pytest.mark.parametrize("latency_s", GRID_LATENCIES_S + BETWEEN_LATENCIES_S + ABOVE_LATENCIES_S)
def test_fused_plm_net_equals_the_reference_at_batch_size_one(plm_pair, latency_s):
    plm_net, fused = plm_pair
    output, reference = assert_fused_equals_reference(
        plm_net, fused, random_frames(1, seed=7), torch.tensor([16.7]), torch.tensor([latency_s])
    )
    if latency_s in GRID_LATENCIES_S[1:]:  # on a grid point: that head's action, as the reference returns
        head = GRID_LATENCIES_S.index(latency_s)
        torch.testing.assert_close(output.steering[0], reference.a_ref[0, head], rtol=0, atol=1e-6)


def test_fused_paper_preset_equals_the_reference():
    torch.manual_seed(3)
    bm = BaseModel(preset_config("paper"))
    plm_net = PLMNet(bm, TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim))).eval()
    latency_s = torch.tensor(GRID_LATENCIES_S + BETWEEN_LATENCIES_S[:3] + ABOVE_LATENCIES_S[:2])
    n = len(latency_s)
    assert_fused_equals_reference(
        plm_net, FusedPLMNet(plm_net), random_frames(n, (160, 160)), torch.full((n,), 16.7), latency_s
    )


@pytest.mark.parametrize(
    "latencies_s, head_range",
    [
        ([0.0], None),  # latency 0: a_BM, no head
        ([0.1], (0, 1)),  # between 0 and 0.15: the BM and head 0.15
        ([0.15], (0, 1)),
        ([0.22], (1, 3)),  # heads 0.20 and 0.25
        ([0.5], (3, 5)),  # above the grid: the last segment
        ([0.0, 0.1], (0, 1)),
        ([0.16, 0.31], (0, 5)),  # a batch: the heads every sample needs, contiguous
    ],
)
def test_fused_plm_net_runs_only_the_heads_that_bracket_the_latency(plm_pair, monkeypatch, latencies_s, head_range):
    _, fused = plm_pair
    ranges = []
    original = fused._heads

    def recording_heads(trunk, first, stop, batch_invariant=False):
        ranges.append((first, stop))
        return original(trunk, first, stop, batch_invariant)

    monkeypatch.setattr(fused, "_heads", recording_heads)
    n = len(latencies_s)
    with torch.inference_mode():
        fused(random_frames(n), torch.full((n,), 16.7), torch.tensor(latencies_s))
    assert ranges == ([] if head_range is None else [head_range])


@pytest.mark.parametrize("first, stop", [(0, 1), (0, 2), (1, 3), (2, 4), (3, 5), (0, 5), (1, 4)])
def test_packed_heads_equal_the_tapm_heads(plm_pair, first, stop):
    plm_net, fused = plm_pair
    trunk = torch.relu(torch.randn(4, 700, generator=torch.Generator().manual_seed(first * 10 + stop)))
    with torch.inference_mode():
        torch.testing.assert_close(
            fused._heads(trunk[:, fused.trunk_order], first, stop), plm_net.tapm.heads(trunk, first, stop),
            rtol=0, atol=1e-6,
        )


@pytest.mark.parametrize("bad_latency_s", [float("nan"), -0.05])
def test_fused_plm_net_rejects_nan_and_negative_latency(plm_pair, bad_latency_s):
    with pytest.raises(ValueError, match="latency_s"):
        plm_pair[1](random_frames(2), torch.full((2,), 16.7), torch.tensor([0.1, bad_latency_s]))


def test_fused_plm_net_runs_outside_inference_mode_without_gradients(plm_pair):
    plm_net, fused = plm_pair
    frames, speed, latency_s = random_frames(3, seed=5), torch.full((3,), 16.7), torch.tensor([0.0, 0.22, 0.4])
    output = fused(frames, speed, latency_s)  # no surrounding inference mode: it enters one itself
    assert not output.steering.requires_grad
    with torch.inference_mode():
        torch.testing.assert_close(output.steering, plm_net(frames, speed, latency_s).steering, rtol=0, atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(st.floats(-1, 1), st.floats(0, 60))
def test_folded_action_and_speed_branches_equal_the_tapm_layers(plm_pair, a_bm, speed_mps):
    plm_net, fused = plm_pair
    bm, tapm = plm_net.bm, plm_net.tapm
    weight, bias = fold_scalar_branches(bm, tapm)
    a_bm_t, speed_t = torch.tensor([a_bm], dtype=torch.float32), torch.tensor([speed_mps], dtype=torch.float32)
    with torch.inference_mode():
        z_v = bm.encode(random_frames(1), speed_t)[1]
        expected = torch.cat([tapm.action_fc(a_bm_t.view(-1, 1)), tapm.speed_fc(z_v)], dim=1)
        folded = torch.stack((a_bm_t, speed_t), dim=1) @ weight + bias
    # Folded in float64 and rounded once: within a few float32 roundings of the layer-by-layer values.
    torch.testing.assert_close(folded, expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("latency_s", GRID_LATENCIES_S + BETWEEN_LATENCIES_S + ABOVE_LATENCIES_S)
def test_fused_paper_preset_equals_the_reference_at_batch_size_one(paper_plm_net, latency_s):
    assert_fused_equals_reference(
        paper_plm_net, FusedPLMNet(paper_plm_net), random_frames(1, (160, 160), seed=11), torch.tensor([16.7]),
        torch.tensor([latency_s]),
    )


@pytest.fixture(scope="module")
def paper_plm_net():
    torch.manual_seed(4)
    bm = BaseModel(preset_config("paper"))
    return PLMNet(bm, TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim))).eval()


# --- the sparse-input image branch of the one-frame form ----------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 3 * SPARSE_CHUNK + 5), st.integers(1, 40), st.floats(0, 1), st.integers(0, 2**16))
def test_sparse_input_linear_equals_the_dense_product(in_features, out_features, density, seed):
    generator = torch.Generator().manual_seed(seed)
    weight = torch.randn(out_features, in_features, generator=generator) / in_features**0.5
    bias = torch.randn(out_features, generator=generator)
    x = torch.relu(torch.randn(1, in_features, generator=generator)) * (
        torch.rand(1, in_features, generator=generator) < density)
    exact = x.double() @ weight.double().T + bias.double()
    with torch.inference_mode():
        sparse = SparseInputLinear.of(weight, bias)(x)
    assert sparse.shape == (1, out_features) and sparse.dtype == torch.float32
    # Float rounding of sums of at most in_features terms, each at most |x| |w|.
    bound = 4 * in_features * torch.finfo(torch.float32).eps * (x.abs().double() @ weight.abs().double().T + bias.abs().double())
    assert bool(((sparse.double() - exact).abs() <= bound + 1e-7).all())


def test_sparse_input_linear_reads_only_the_rows_of_nonzero_inputs():
    weight, bias = torch.randn(8, 100), torch.randn(8)
    x = torch.zeros(1, 100)
    x[0, [3, 40, 41, 99]] = torch.tensor([0.5, 1.0, 2.0, 0.25])
    poisoned = weight.clone()
    poisoned[:, (x[0] == 0)] = float("nan")  # a dense product would turn every output NaN (0 * NaN)
    with torch.inference_mode():
        output = SparseInputLinear.of(poisoned, bias)(x)
        torch.testing.assert_close(output, torch.addmm(bias, x, weight.T), rtol=1e-6, atol=1e-6)
        # No nonzero input at all: the bias, as the dense product gives.
        assert torch.equal(SparseInputLinear.of(poisoned, bias)(torch.zeros(1, 100)), bias.unsqueeze(0))


@pytest.mark.parametrize("latency_s", [0.0, 0.1, 0.15, 0.22, 0.5])
def test_one_frame_plm_net_runs_the_bms_own_calls(plm_pair, monkeypatch, latency_s):
    """At batch size 1 on the CPU a_BM is the BM's own, bit for bit (latency 0 returns it), and the image
    branch is the sparse product (the fused first layer is not read)."""
    plm_net, fused = plm_pair
    frames, speed = random_frames(1, seed=21), torch.tensor([16.7])
    used = []
    first_layer = fused.first_layer

    class RecordedFirstLayer:
        def apply(self, *args):
            used.append("fused first layer")
            return first_layer.apply(*args)

    monkeypatch.setattr(fused, "first_layer", RecordedFirstLayer())
    sparse_calls = fused.sparse_image_fc()
    monkeypatch.setattr(fused, "sparse_image_fc", lambda: used.append("sparse") or sparse_calls)
    with torch.inference_mode():
        output = fused(frames, speed, [latency_s])
        reference = plm_net(frames, speed, torch.tensor([latency_s]))
        if latency_s == 0:
            assert torch.equal(output.steering, plm_net.bm(frames, speed))
    torch.testing.assert_close(output.steering, reference.steering, rtol=0, atol=1e-6)
    assert used == ([] if latency_s == 0 else ["sparse"])


# --- int8 TAPM: the BM exact, the TAPM approximate ------------------------------------------------------


def int8_error_bound(weight: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Worst case of per-row int8 weights (step max|w_row| / 127) times inputs quantised over their
    range [min(x, 0), max(x, 0)] in 127 steps: |w| * dx + |x| * dw + dw * dx per term, summed
    (a step, not half a step, per factor: the zero point's rounding can shift the grid by up to half a step).
    The input range is the whole batch's (dynamic quantisation is per tensor): a sample's error grows
    with the largest input of the batch it shares."""
    weight_step = weight.abs().amax(dim=1, keepdim=True) / 127  # (out, 1)
    x_step = (x.clamp_min(0).amax() - x.clamp_max(0).amin()).expand(len(x), 1) / 127  # (B, 1)
    return (
        x_step * weight.abs().sum(dim=1)
        + x.abs() @ weight_step.expand(-1, weight.shape[1]).T
        + x_step * weight_step.T * weight.shape[1]
    )


@settings(max_examples=40, deadline=None)
@given(
    st.integers(1, 4), st.integers(1, 300), st.integers(1, 64), st.integers(0, 2**16), st.booleans(),
)
def test_int8_linear_stays_within_the_quantisation_bound(batch, in_features, out_features, seed, non_negative):
    generator = torch.Generator().manual_seed(seed)
    weight = torch.randn(out_features, in_features, generator=generator) / in_features**0.5
    bias = torch.randn(out_features, generator=generator)
    x = torch.randn(batch, in_features, generator=generator) * 3
    if non_negative:  # what the TAPM feeds it: features after a ReLU
        x = x.relu()
    exact = torch.nn.functional.linear(x, weight, bias)
    error = (Int8Linear(weight, bias)(x) - exact).abs()
    assert bool((error <= int8_error_bound(weight, x) + 1e-5).all()), float((error - int8_error_bound(weight, x)).max())


def test_int8_linear_is_exact_where_weights_and_inputs_are_on_the_grid():
    # Rows whose largest |weight| is 127 steps, integer inputs up to 127: nothing to round.
    weight = torch.tensor([[127.0, -3.0, 0.0], [1.0, 2.0, 127.0]]) / 127
    x = torch.tensor([[127.0, 5.0, 0.0], [0.0, 1.0, 2.0]])
    bias = torch.tensor([0.5, -0.25])
    torch.testing.assert_close(Int8Linear(weight, bias)(x), torch.nn.functional.linear(x, weight, bias), rtol=0, atol=1e-5)


@pytest.fixture(scope="module")
def int8_fused(plm_pair):
    return FusedPLMNet(plm_pair[0], tapm_int8=True)


def test_int8_plm_net_computes_the_bm_exactly(plm_pair, int8_fused):
    """Like for like: the BM's part of the int8 form is the BM's own computation, bit for bit."""
    bm = plm_pair[0].bm
    for n in (1, 5):
        frames, speed = random_frames(n, seed=n), torch.linspace(5, 30, n)
        with torch.inference_mode():
            output = int8_fused(frames, speed, torch.zeros(n))  # latency 0: a_BM
            assert torch.equal(output.steering, bm(frames, speed))


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.one_of(st.sampled_from(GRID_LATENCIES_S + ABOVE_LATENCIES_S), st.floats(0, 0.5)), min_size=1,
             max_size=5),
    st.integers(0, 2**16),
)
def test_int8_plm_net_stays_close_to_the_reference(plm_pair, int8_fused, latencies, seed):
    plm_net = plm_pair[0]
    n = len(latencies)
    frames, speed, latency_s = random_frames(n, seed=seed), torch.full((n,), 16.7), torch.tensor(latencies)
    with torch.inference_mode():
        reference = plm_net(frames, speed, latency_s)
        output = int8_fused(frames, speed, latency_s)
    # Measured on these weights: at most ~4e-4 (the shipped checkpoints: ~9e-3, see bench models).
    torch.testing.assert_close(output.steering, reference.steering, rtol=0, atol=2e-3)
    assert output.n_clamped == reference.n_clamped
    assert bool((output.steering.abs() <= 1).all())  # interpolated tanh outputs


def test_int8_plm_net_paper_preset_stays_close_to_the_reference(paper_plm_net):
    latency_s = torch.tensor([0.0, 0.1, 0.15, 0.22, 0.35, 0.5])
    n = len(latency_s)
    frames, speed = random_frames(n, (160, 160), seed=2), torch.full((n,), 16.7)
    fused = FusedPLMNet(paper_plm_net, tapm_int8=True)
    with torch.inference_mode():
        reference = paper_plm_net(frames, speed, latency_s).steering
        torch.testing.assert_close(fused(frames, speed, latency_s).steering, reference, rtol=0, atol=2e-3)
        one_by_one = torch.cat([fused(frames[i : i + 1], speed[i : i + 1], latency_s[i : i + 1]).steering
                                for i in range(n)])
    torch.testing.assert_close(one_by_one, reference, rtol=0, atol=2e-3)
    assert torch.equal(one_by_one[0], paper_plm_net.bm(frames[:1], speed[:1])[0])  # latency 0: the BM's own


def test_int8_needs_the_fused_form():
    with pytest.raises(ValueError, match="tapm_int8"):
        PLMNetPolicy(small_plm_net(), fused=False, tapm_int8=True)


# --- batched policies -----------------------------------------------------------------------------------


def batch_inputs(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    latencies = np.concatenate([GRID_LATENCIES_S, BETWEEN_LATENCIES_S, ABOVE_LATENCIES_S])
    return (
        random_frames(n, seed=seed).numpy(),
        rng.uniform(5, 30, n),
        rng.choice(latencies, n),
    )


@pytest.mark.parametrize("policy_class", [BaseModelPolicy, PLMNetPolicy])
@pytest.mark.parametrize("batch_size", [1, 8, 32])
def test_a_batch_equals_batch_one_calls_per_sample(plm_pair, policy_class, batch_size):
    plm_net = plm_pair[0]
    policy = policy_class(plm_net.bm if policy_class is BaseModelPolicy else plm_net)
    frames, speeds, latencies = batch_inputs(batch_size, seed=batch_size)
    batched = policy.steer_batch(frames, speeds, latencies)
    assert batched.shape == (batch_size,) and batched.dtype == np.float64
    one_by_one = np.array([policy(frames[i], speeds[i], latencies[i]) for i in range(batch_size)])
    # One forward pass: the kernels sum in another order than at batch size 1 (see inference.py).
    np.testing.assert_allclose(batched, one_by_one, rtol=0, atol=1e-5)


@pytest.mark.parametrize("policy_class", [BaseModelPolicy, PLMNetPolicy])
def test_a_batch_invariant_policy_is_bit_identical_to_batch_one_calls(plm_pair, policy_class):
    plm_net = plm_pair[0]
    model = plm_net.bm if policy_class is BaseModelPolicy else plm_net
    policy = policy_class(model, batch_invariant=True)
    frames, speeds, latencies = batch_inputs(8, seed=3)
    one_by_one = [policy_class(model, batch_invariant=True)(frames[i], speeds[i], latencies[i]) for i in range(8)]
    assert policy.steer_batch(frames, speeds, latencies).tolist() == one_by_one
    default_kernels = [policy_class(model)(frames[i], speeds[i], latencies[i]) for i in range(8)]
    np.testing.assert_allclose(one_by_one, default_kernels, rtol=0, atol=1e-5)


def test_batch_counts_clamped_latencies_and_exposes_the_grid_end(plm_pair):
    policy = PLMNetPolicy(plm_pair[0])
    frames, speeds, _ = batch_inputs(4)
    policy.steer_batch(frames, speeds, [0.1, 0.35, 0.36, 3.0])
    assert policy.clamped_latency_count == 2
    assert policy.max_latency_s == pytest.approx(0.35)
    assert BaseModelPolicy(plm_pair[0].bm).max_latency_s == float("inf")


def test_reference_policy_equals_the_fused_policy(plm_pair):
    plm_net = plm_pair[0]
    frames, speeds, latencies = batch_inputs(16, seed=5)
    fused, reference = PLMNetPolicy(plm_net), PLMNetPolicy(plm_net, fused=False)
    np.testing.assert_allclose(
        fused.steer_batch(frames, speeds, latencies), reference.steer_batch(frames, speeds, latencies), atol=1e-6
    )
    assert fused.clamped_latency_count == reference.clamped_latency_count


BAD_BATCHES = [
    pytest.param(lambda f, s, lat: (f.astype(np.float32), s, lat), r"frames: expected uint8 \(B, 66, 200\)", id="float"),
    pytest.param(lambda f, s, lat: (f[:, :, :100], s, lat), r"frames: expected uint8", id="wrong-size"),
    pytest.param(lambda f, s, lat: (f[0], s, lat), r"frames: expected uint8 \(B, 66, 200\), got uint8 \(66, 200\)",
                 id="no-batch-axis"),
    pytest.param(lambda f, s, lat: (f[:0], s[:0], lat[:0]), r"batch size must lie in \[1, 4096\], got 0", id="empty"),
    pytest.param(lambda f, s, lat: (f, s[:2], lat), r"speeds_mps: expected shape \(3,\), one per frame, got \(2,\)",
                 id="few-speeds"),
    pytest.param(lambda f, s, lat: (f, s, lat[:, None]), r"latencies_s: expected shape \(3,\)", id="2d-latencies"),
    pytest.param(lambda f, s, lat: (f, [1.0, float("nan"), 2.0], lat), r"speeds_mps: must be finite, got nan",
                 id="nan-speed"),
    pytest.param(lambda f, s, lat: (f, s, [0.1, -0.1, 0.2]), r"latency_s: must be a finite number >= 0 s, got -0.1",
                 id="negative-latency"),
    pytest.param(lambda f, s, lat: (f, s, [0.1, float("inf"), 0.2]), r"latency_s: .*got inf", id="inf-latency"),
    pytest.param(lambda f, s, lat: (f, ["fast", 1, 2], lat), r"speeds_mps: expected 3 numbers", id="str-speed"),
]


@pytest.mark.parametrize("policy_class", [BaseModelPolicy, PLMNetPolicy])
@pytest.mark.parametrize("mutate, message", BAD_BATCHES)
def test_bad_batches_are_refused_naming_the_input(plm_pair, policy_class, mutate, message):
    plm_net = plm_pair[0]
    policy = policy_class(plm_net.bm if policy_class is BaseModelPolicy else plm_net)
    frames, speeds, latencies = batch_inputs(3)
    with pytest.raises(ValueError, match=message):
        policy.steer_batch(*mutate(frames, speeds, latencies))


@pytest.mark.parametrize("policy_class", [BaseModelPolicy, PLMNetPolicy])
def test_nan_steering_stops_with_a_clear_error(policy_class):
    plm_net = small_plm_net()
    with torch.no_grad():
        plm_net.bm.steering_head.bias.fill_(float("nan"))  # weights that slipped past the checkpoint checks
    policy = policy_class(plm_net.bm if policy_class is BaseModelPolicy else plm_net)
    frames, speeds, latencies = batch_inputs(3)
    with pytest.raises(NonFiniteSteeringError, match=r"policy: steering is nan for sample 0 \(speed"):
        policy.steer_batch(frames, speeds, latencies)
    with pytest.raises(NonFiniteSteeringError):
        policy(frames[0], 16.7, 0.2)


# --- checkpoint integrity and bad checkpoints ---------------------------------------------------------


def write_state(path, state: dict, document_path=None, fingerprint: bool = True) -> None:
    """Replace a checkpoint's .pt; with ``fingerprint`` also record the new weights' fingerprint in its JSON."""
    weights_path, json_path = checkpoint_paths(path)
    torch.save(state, weights_path)
    if fingerprint:
        edit_description(path, fingerprint=state_dict_fingerprint(state))


def swapped_weights(path, tmp_path):
    other = small_plm_net(seed=5)
    torch.save(other.bm.state_dict(), checkpoint_paths(path)[0])


def nan_weight(path, tmp_path):
    state = torch.load(checkpoint_paths(path)[0], weights_only=True)
    state["mlp.0.weight"][3, 7] = float("nan")
    state["steering_head.bias"][0] = float("inf")
    write_state(path, state)


def paper_state(path, tmp_path):
    write_state(path, BaseModel(preset_config("paper")).state_dict())


def tapm_state_in_bm(path, tmp_path):
    write_state(path, TAPM(TAPMConfig(image_feature_dim=1152)).state_dict())


def float64_state(path, tmp_path):
    state = torch.load(checkpoint_paths(path)[0], weights_only=True)
    write_state(path, {key: value.double() for key, value in state.items()})


def truncated_pt(path, tmp_path):
    weights_path = checkpoint_paths(path)[0]
    weights_path.write_bytes(weights_path.read_bytes()[: weights_path.stat().st_size // 2])


def not_a_dict(path, tmp_path):
    torch.save([torch.zeros(2)], checkpoint_paths(path)[0])


def json_text(text: str):
    def mutate(path, tmp_path):
        checkpoint_paths(path)[1].write_text(text)

    return mutate


def json_bytes(data: bytes):
    def mutate(path, tmp_path):
        checkpoint_paths(path)[1].write_bytes(data)

    return mutate


def json_edit(**changes):
    def mutate(path, tmp_path):
        edit_description(path, **changes)

    return mutate


def json_drop(key: str):
    def mutate(path, tmp_path):
        json_path = checkpoint_paths(path)[1]
        document = json.loads(json_path.read_text())
        del document[key]
        json_path.write_text(json.dumps(document))

    return mutate


def huge_json(path, tmp_path):
    json_path = checkpoint_paths(path)[1]
    document = json.loads(json_path.read_text())
    document["padding"] = "x" * (5 * 1024 * 1024)
    json_path.write_text(json.dumps(document))


def missing_pt(path, tmp_path):
    checkpoint_paths(path)[0].unlink()


# One line per bad checkpoint: (what is done to a valid BM checkpoint, exception, message).
BAD_BM_CHECKPOINTS = [
    pytest.param(swapped_weights, ValueError, r"model.pt: the weights' fingerprint .* differs from the one recorded "
                 r"in model.json .*replaced or altered", id="swapped-same-shape"),
    pytest.param(nan_weight, ValueError, r"weights are not finite: key 'mlp.0.weight' has 1 NaN or infinite values; "
                 r"key 'steering_head.bias' has 1", id="nan-and-inf"),
    pytest.param(paper_state, ValueError, r"key 'convs.0.weight': expected shape \(24, 1, 5, 5\), found "
                 r"\(24, 3, 5, 5\).*key 'mlp.0.weight': expected shape \(512, 1296\), found \(512, 10960\)",
                 id="other-architecture"),
    pytest.param(tapm_state_in_bm, ValueError, r"missing keys \['convs.0.bias', .*, \.\.\.\] \(22 in all\); "
                 r"unexpected keys \['action_fc.bias'", id="tapm-state"),
    pytest.param(float64_state, ValueError, r"key 'convs.0.bias': expected dtype torch.float32, found torch.float64",
                 id="float64"),
    pytest.param(truncated_pt, ValueError, r"model.pt: not a loadable state_dict", id="truncated-pt"),
    pytest.param(not_a_dict, ValueError, r"model.pt: expected a state_dict, found list", id="list-pt"),
    pytest.param(missing_pt, FileNotFoundError, r"model.pt: checkpoint file not found", id="missing-pt"),
    pytest.param(json_text("{not json"), ValueError, r"model.json: not valid JSON", id="json-garbage"),
    pytest.param(json_text("[1, 2]"), ValueError, r"model.json: expected a JSON object, found list", id="json-list"),
    pytest.param(json_bytes(b"\xff\xfe{\x00"), ValueError, r"model.json: not UTF-8 text", id="json-binary"),
    pytest.param(huge_json, ValueError, r"model.json: \d+ bytes, a checkpoint description is at most 4194304",
                 id="json-huge"),
    pytest.param(json_edit(format="other/2"), ValueError, r"field 'format' is 'other/2'", id="format"),
    pytest.param(json_edit(kind="tapm"), ValueError, r"is a 'tapm' checkpoint, expected 'base_model'", id="kind"),
    pytest.param(json_drop("architecture"), ValueError, r"field 'architecture' is missing", id="no-architecture"),
    pytest.param(json_edit(architecture={"image_height_px": 3000, "image_width_px": 3000}), ValueError,
                 r"model.json: architecture field image_height_px: must lie in \[61, 400\], got 3000", id="3000px"),
    pytest.param(json_edit(architecture={"image_height_px": "66"}), ValueError,
                 r"architecture field image_height_px: expected an integer", id="str-size"),
    pytest.param(json_edit(architecture={"embed_acceleration": "false"}), ValueError,
                 r"architecture field embed_acceleration: expected true or false, got str", id="str-bool"),
    pytest.param(json_edit(architecture={"speed_scale_mps": 0}), ValueError,
                 r"architecture field speed_scale_mps: must be a finite number in \(0, 1000\]", id="speed-scale-0"),
    pytest.param(json_edit(architecture={"wings": 2}), ValueError, r"unknown architecture fields \['wings'\]",
                 id="unknown-field"),
    pytest.param(json_edit(image_size_px="66x200"), ValueError, r"image_size_px 66x200 disagrees", id="size-str"),
    pytest.param(json_drop("fingerprint"), ValueError, r"field 'fingerprint' is missing: the weights cannot be "
                 r"verified", id="no-fingerprint"),
]


@pytest.mark.parametrize("mutate, exception, message", BAD_BM_CHECKPOINTS)
def test_bad_bm_checkpoints_are_refused_naming_the_culprit(tmp_path, mutate, exception, message):
    _, bm_dir, _ = saved_pair(tmp_path)
    mutate(bm_dir, tmp_path)
    with pytest.raises(exception, match=message):
        load_base_model(bm_dir)


@pytest.mark.parametrize("mutate, exception, message", BAD_BM_CHECKPOINTS)
def test_bad_bm_checkpoints_exit_2_on_the_command_line(tmp_path, capsys, mutate, exception, message):
    _, bm_dir, _ = saved_pair(tmp_path)
    mutate(bm_dir, tmp_path)
    out = tmp_path / "tapm_out"
    code = cli.main(["train", "tapm", "--bm", str(bm_dir), "--data", str(tmp_path / "data"), "--out", str(out),
                     "--quiet", "--threads", "1"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_BAD_INPUT
    assert re.search(message, err), err
    assert "Traceback" not in err and not out.exists()


def tapm_swapped(path, tmp_path):
    torch.save(small_plm_net(seed=9).tapm.state_dict(), checkpoint_paths(path)[0])


def tapm_nan(path, tmp_path):
    state = torch.load(checkpoint_paths(path)[0], weights_only=True)
    state["heads_out.bias"][2, 0, 0] = float("nan")
    write_state(path, state)


BAD_TAPM_CHECKPOINTS = [
    pytest.param(tapm_swapped, r"fingerprint .* differs from the one recorded", id="swapped-same-shape"),
    pytest.param(tapm_nan, r"key 'heads_out.bias' has 1 NaN or infinite values", id="nan"),
    pytest.param(json_drop("bm_fingerprint"), r"field 'bm_fingerprint' is missing", id="no-bm-fingerprint"),
    pytest.param(json_edit(bm_fingerprint="0" * 64), r"trained on the features of another BM", id="other-bm"),
    pytest.param(json_edit(architecture={"delta_grid_s": [0.1, "x"]}), r"architecture field delta_grid_s: .*got 'x'",
                 id="str-in-grid"),
    pytest.param(json_edit(architecture={"delta_grid_s": [0.1, 0.2, 0.3]}),
                 r"key 'heads_in.weight': expected shape \(600, 700\), found \(1000, 700\)", id="other-grid"),
    pytest.param(json_edit(architecture={"image_feature_dim": 10**9}), r"image_feature_dim: must lie in", id="huge"),
    pytest.param(json_drop("kind"), r"is a None checkpoint, expected 'tapm'", id="no-kind"),
]


@pytest.mark.parametrize("mutate, message", BAD_TAPM_CHECKPOINTS)
def test_bad_tapm_checkpoints_are_refused_naming_the_culprit(tmp_path, mutate, message):
    plm_net, _, tapm_dir = saved_pair(tmp_path)
    mutate(tapm_dir, tmp_path)
    with pytest.raises(ValueError, match=message):
        load_tapm(tapm_dir, plm_net.bm)


def test_a_manifest_with_a_byte_order_mark_loads(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    json_path = bm_dir / "model.json"
    json_path.write_bytes(b"\xef\xbb\xbf" + json_path.read_bytes())
    assert isinstance(load_base_model(bm_dir), BaseModel)


class CreatesMarker:
    """Unpickling this object calls open(marker, "w"): it creates the marker file if code runs."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def test_a_pickle_that_would_run_code_is_refused_and_never_runs(tmp_path):
    _, bm_dir, _ = saved_pair(tmp_path)
    marker = tmp_path / "marker"
    state = torch.load(bm_dir / "model.pt", weights_only=True)
    state["steering_head.bias"] = CreatesMarker(marker)
    torch.save(state, bm_dir / "model.pt")
    with pytest.raises(ValueError, match="not a loadable state_dict"):
        load_base_model(bm_dir)
    assert not marker.exists()
    # The payload is live: an unsafe load would have run it.
    torch.load(bm_dir / "model.pt", weights_only=False)
    assert marker.exists()


def test_non_finite_weights_are_not_saved(tmp_path):
    bm = BaseModel()
    with torch.no_grad():
        bm.mlp[0].bias[5] = float("nan")
    with pytest.raises(ValueError, match=r"refusing to save non-finite weights \(key 'mlp.0.bias' has 1"):
        save_checkpoint(tmp_path / "bm", bm, {})
    assert not (tmp_path / "bm").exists() or list((tmp_path / "bm").iterdir()) == []


def test_shipped_checkpoints_match_their_recorded_fingerprints():
    directory = shipped_checkpoint_dir()
    for name in ("bm_default", "tapm_default"):
        document = json.loads((directory / f"{name}.json").read_text())
        state = torch.load(directory / f"{name}.pt", weights_only=True)
        assert state_dict_fingerprint(state) == document["fingerprint"]
    assert isinstance(load_shipped_plm_net(), PLMNet)


# --- bench ----------------------------------------------------------------------------------------------


def test_bench_models_cli_prints_and_writes_the_figures(tmp_path, capsys):
    out = tmp_path / "bench.json"
    threads = str(torch.get_num_threads())  # leave this worker's thread count as it was
    args = ["bench", "models", "--preset", "default", "--frames", "6", "--warmup", "1", "--repeats", "2",
            "--train-batches", "1", "--threads", threads, "--device", "cpu", "--json", str(out)]
    assert cli.main(args) == 0
    result = json.loads(out.read_text())
    figures = result["presets"]["default"]
    for key in ("bm_ms_median", "plm_ms_median", "plm_int8_ms_median", "plm_reference_ms_median", "overhead_ratio",
                "overhead_ratio_cpu", "int8_overhead_ratio", "int8_overhead_ratio_cpu", "reference_overhead_ratio"):
        assert figures[key] > 0, key
    assert len(figures["repeats"]) == 2
    first_repeat = figures["repeats"][0]
    for key, side in (("overhead_ratio", "plm"), ("int8_overhead_ratio", "plm_int8")):
        assert figures[key] == pytest.approx(np.median([r[key] for r in figures["repeats"]]))
        assert first_repeat[key] == pytest.approx(first_repeat[f"{side}_ms_median"] / first_repeat["bm_ms_median"])
    assert figures["max_abs_difference_fused_vs_reference"] < 1e-6
    assert 0 < figures["max_abs_difference_int8_vs_reference"] < 1e-2
    assert set(figures["throughput_samples_per_s"]["plm"]) == {"1", "32", "256"}
    assert 0 < figures["image_features_nonzero_fraction"] < 0.5  # the shipped checkpoints on rendered frames
    assert result["conditions"]["weights"] == "shipped" and result["conditions"]["device"] == "cpu"
    assert all(v > 0 for v in figures["throughput_samples_per_s"]["bm"].values())
    assert figures["training_samples_per_s"]["bm"] > 0 and figures["training_samples_per_s"]["tapm"] > 0
    assert figures["bm_params"] == 851_371 and figures["tapm_frozen_params"] == 851_371
    assert figures["tapm_trainable_params"] == 1_418_205
    printed = capsys.readouterr().out
    assert "overhead PLM-Net (exact, fp32) / BM" in printed and "overhead PLM-Net (int8 TAPM) / BM" in printed
    assert "batched throughput" in printed and "training, samples/s" in printed
    table_row = next(line for line in printed.splitlines() if line.strip().startswith("default") and "(" in line)
    assert f"{figures['overhead_ratio']:.3f}" in table_row and f"{figures['int8_overhead_ratio']:.3f}" in table_row


@pytest.mark.parametrize(
    "args, message",
    [
        (["--frames", "0"], r"--frames: must lie in \[1, 100000\], got 0"),
        (["--repeats", "0"], r"--repeats: must lie in \[1, 100\]"),
        (["--warmup", "-1"], r"--warmup: must lie in"),
        (["--threads", "0"], r"--threads: must lie in"),
        (["--train-batches", "0"], r"--train-batches: must lie in"),
    ],
)
def test_bench_models_refuses_bad_arguments(capsys, args, message):
    assert cli.main(["bench", "models", *args]) == cli.EXIT_BAD_INPUT
    assert re.search(message, capsys.readouterr().err)


def test_bench_says_whether_the_approximation_stays_within_the_exact_forms_interval():
    from plm_highway.bench.models import mean_within_ci

    # MAEs 1, 2, 3: logs 0, 0.6931, 1.0986 (mean 0.5973, sd 0.5555); t(0.975, 2) = 4.3027 -> half width 1.3801
    # on the log scale: the interval [exp(-0.7828), exp(1.9774)] = [0.4571, 7.223]
    exact = [1.0, 2.0, 3.0]
    assert mean_within_ci([7.1, 7.2, 7.2], exact) and not mean_within_ci([7.3, 7.2, 7.3], exact)
    assert mean_within_ci([0.46, 0.46, 0.46], exact) and not mean_within_ci([0.45] * 3, exact)
    # the symmetric interval, 2 +- 2.484, would have taken in a mean of 0 (no error at all) and lacked 4.5 to 7.2
    assert not mean_within_ci([0.0] * 3, exact) and mean_within_ci([4.5] * 3, exact)
    assert not mean_within_ci([0.5], [0.5]) and not mean_within_ci([0.5], [0.5, 0.6])  # nothing to lie within


def test_bench_confidence_intervals_respect_the_quantity():
    import math

    from plm_highway.bench.models import _mean_ci

    # an MAE: the interval of the logarithms, exponentiated (never below 0)
    figure = _mean_ci([1.0, 2.0, 3.0], "positive")
    logs = [math.log(v) for v in (1.0, 2.0, 3.0)]
    centre, sd = sum(logs) / 3, (sum((x - sum(logs) / 3) ** 2 for x in logs) / 2) ** 0.5
    assert figure["mean"] == 2.0 and figure["n"] == 3 and figure["values"] == [1.0, 2.0, 3.0]
    assert figure["low"] == pytest.approx(math.exp(centre - 4.3027 * sd / 3**0.5), rel=1e-4)
    assert figure["high"] == pytest.approx(math.exp(centre + 4.3027 * sd / 3**0.5), rel=1e-4)
    assert _mean_ci([0.01, 0.5, 1.2], "positive")["low"] > 0  # the symmetric one would reach below 0
    # a paired difference, signed: mean 2, sample sd 1, n 3: half width t(0.975, 2) / sqrt(3) = 4.3027 / 1.7321
    difference = _mean_ci([1.0, 2.0, 3.0], "linear")
    assert (difference["low"], difference["high"]) == (pytest.approx(2 - 4.3027 / 3**0.5, abs=1e-4),
                                                       pytest.approx(2 + 4.3027 / 3**0.5, abs=1e-4))
    for scale in ("positive", "linear"):  # fewer than 3 seeds: no interval, not a zero-width or a huge one
        assert _mean_ci([0.5, 0.7], scale)["low"] is None and _mean_ci([0.5], scale)["high"] is None


def test_bench_closed_loop_table_prints_intervals_from_the_values_and_none_for_two_seeds():
    from plm_highway.bench.models import format_closed_loop_table

    def figure(values):  # as a result file holds it (the interval is recomputed from the values)
        return {"mean": sum(values) / len(values), "values": values}

    check = {"conditions": "ideal", "reference_forward_mae": figure([1.0, 2.0, 3.0]),
             "fused_mae": figure([1.0, 2.0, 3.0]),
             "fused_int8_mae": figure([1.0, 2.0, 3.5]), "int8_minus_fused_mae": figure([0.0, 0.0, 0.5])}
    row = format_closed_loop_table({"closed_loop": {"default": check}})[2]
    assert "| 2.00000 [0.45712, 7.22330] |" in row and "| yes |" in row
    assert "0.16667 [-0.55" in row  # the paired difference: symmetric, below 0
    two = {key: (figure(value["values"][:2]) if isinstance(value, dict) else value) for key, value in check.items()}
    row = format_closed_loop_table({"closed_loop": {"default": two}})[2]
    assert row.count("(n=2, no interval)") == 4 and "| no |" in row


@pytest.mark.slow
@pytest.mark.parametrize("conditions", ["ideal", "paper"])
def test_closed_loop_check_drives_each_preset_under_its_conditions(conditions):
    from plm_highway.bench.models import closed_loop_check

    check = closed_loop_check(conditions, seeds=2, max_steps=12)
    assert check["conditions"] == conditions and check["max_steps"] == 12
    assert check["checkpoints"] == f"shipped {'default' if conditions == 'ideal' else 'paper'}"
    for form in ("reference_forward", "fused", "fused_int8"):
        assert len(check[f"{form}_mae"]["values"]) == 2
    # The exact form is the reference up to float rounding; int8 moves the steering, within its bound.
    assert check["max_abs_steering_difference"] < 1e-4
    assert 0 < check["max_abs_steering_difference_int8"] < 0.05
