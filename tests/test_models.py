"""Base Model, TAPM, PLM-Net forward and Algorithm 1 (plm_highway.models)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import plm_highway
from plm_highway import cli
from plm_highway.models import shipped
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
    state_fingerprint,
)
from plm_highway.models.inference import BaseModelPolicy, PLMNetPolicy
from plm_highway.models.plm_net import PLMNet, interpolate_actions
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


@pytest.mark.parametrize(
    "overrides, message",
    [({"conv_activation": "elu"}, "conv_activation"), ({"image_height_px": 20}, "too small")],
)
def test_invalid_bm_config_is_rejected(overrides, message):
    with pytest.raises(ValueError, match=message):
        BaseModelConfig(**overrides)


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


@pytest.mark.parametrize("grid", [(), (0.2, 0.15), (0.0, 0.1), (0.1, float("nan"))])
def test_invalid_delta_grids_are_rejected(grid):
    with pytest.raises(ValueError, match="delta_grid_s"):
        TAPMConfig(image_feature_dim=8, delta_grid_s=grid)


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


def test_plm_net_runs_the_convolutions_once():
    plm_net = small_plm_net()
    calls = []
    plm_net.bm.convs[0].register_forward_hook(lambda *_: calls.append(1))
    with torch.inference_mode():
        plm_net(random_frames(2), torch.full((2,), 16.7), torch.tensor([0.1, 0.3]))
    assert len(calls) == 1


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
    assert plm_policy(frame, 16.7, 0.0) == bm_steering  # latency 0 is the BM's action
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


# --- bench ----------------------------------------------------------------------------------------------


def test_bench_models_cli_prints_and_writes_the_figures(tmp_path, capsys):
    out = tmp_path / "bench.json"
    threads = str(torch.get_num_threads())  # leave this worker's thread count as it was
    assert (
        cli.main(
            ["bench", "models", "--frames", "5", "--warmup", "1", "--threads", threads, "--json", str(out)]
        )
        == 0
    )
    result = json.loads(out.read_text())
    for key in (
        "bm_ms_mean",
        "bm_ms_p95",
        "plm_ms_mean",
        "plm_ms_p95",
        "overhead_ratio",
        "overhead_ratio_cpu",
    ):
        assert result[key] > 0
    assert result["bm_params"] == 851_371 and result["tapm_frozen_params"] == 851_371
    assert result["tapm_trainable_params"] == 1_418_205
    assert "overhead ratio PLM-Net / BM" in capsys.readouterr().out
