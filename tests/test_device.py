"""Devices: ``--device auto|cpu|cuda``, models, policies, checkpoints and training on any device.

Every test runs on the CPU; its CUDA variant runs where torch sees a GPU and is skipped elsewhere, with
the reason. ``cuda`` requests on a machine without CUDA are simulated (torch.cuda.is_available patched),
so the refusal is checked on every machine.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import torch

from plm_highway import cli
from plm_highway.errors import BadInput
from plm_highway.models.base_model import BaseModel
from plm_highway.models.checkpoints import (
    host_state_dict,
    load_base_model,
    load_plm_net,
    load_tapm,
    save_checkpoint,
    state_fingerprint,
)
from plm_highway.models.device import module_device, resolve_device
from plm_highway.models.inference import BaseModelPolicy, PLMNetPolicy
from plm_highway.models.plm_net import FusedPLMNet, PLMNet
from plm_highway.models.tapm import TAPM, TAPMConfig
from plm_highway.rollout.policies import make_policy

CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(
    not CUDA, reason=f"no CUDA device: torch {torch.__version__} (CUDA build: {torch.version.cuda}) sees no GPU"
)
DEVICES = ["cpu", pytest.param("cuda", marks=needs_cuda)]
LATENCIES_S = [0.0, 0.1, 0.15, 0.22, 0.35, 0.5]


def small_plm_net(seed: int = 0) -> PLMNet:
    torch.manual_seed(seed)
    bm = BaseModel()
    return PLMNet(bm, TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim))).eval()


def random_frames(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, 66, 200), dtype=np.uint8)


@pytest.fixture
def no_cuda(monkeypatch):
    """A machine where torch sees no GPU, whatever this one has."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


# --- choosing the device --------------------------------------------------------------------------------


def test_auto_takes_a_gpu_only_when_torch_sees_one(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu") and resolve_device(None) == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == torch.device("cuda")


def test_cpu_is_always_there():
    assert resolve_device("cpu") == torch.device("cpu") == resolve_device(torch.device("cpu"))


def test_cuda_without_cuda_is_refused_with_the_reason(no_cuda):
    with pytest.raises(BadInput, match=r"--device cuda: CUDA is not available \(.*\); use --device cpu"):
        resolve_device("cuda")


@pytest.mark.parametrize("name", ["gpu", "tpu", "mps", "cuda:x", ""])
def test_other_device_names_are_refused(name):
    with pytest.raises(BadInput, match="expected one of auto, cpu, cuda"):
        resolve_device(name)


@pytest.mark.parametrize("argv", [
    ["train", "bm", "--data", "{tmp}/data", "--out", "{tmp}/bm"],
    ["train", "tapm", "--data", "{tmp}/data", "--out", "{tmp}/tapm", "--bm", "{tmp}/bm"],
    ["bench", "models", "--json", "{tmp}/bench.json"],
    ["evaluate", "--max-steps", "5", "--out", "{tmp}/evaluation"],
    ["reproduce", "--max-steps", "5", "--out", "{tmp}/report"],
    ["sweep", "--max-steps", "5", "--out", "{tmp}/sweep"],
    ["population", "--pairs", "1", "--work", "{tmp}/work", "--out", "{tmp}/population"],
])
def test_commands_refuse_cuda_without_cuda_with_exit_2_and_write_nothing(no_cuda, tmp_path, capsys, argv):
    argv = [word.format(tmp=tmp_path) for word in argv] + ["--device", "cuda"]
    assert cli.main(argv) == cli.EXIT_BAD_INPUT
    error = capsys.readouterr().err
    assert "--device cuda: CUDA is not available" in error and "Traceback" not in error
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [["train", "bm", "--data", "d", "--out", "o"], ["bench", "models"], ["evaluate"],
                                  ["reproduce"], ["sweep"], ["population"]])
def test_device_option_takes_only_auto_cpu_or_cuda(capsys, argv):
    assert cli.main([*argv, "--device", "tpu"]) == cli.EXIT_BAD_INPUT
    assert "invalid choice: 'tpu'" in capsys.readouterr().err


# --- checkpoints: loaded onto any device, the same bytes saved from any ---------------------------------


def saved_bytes(directory, model) -> bytes:
    return save_checkpoint(directory, model, {}).read_bytes()


def test_the_state_dict_saved_is_the_modules_own_as_torch_writes_it(tmp_path):
    """host_state_dict keeps the dict's type and the _metadata torch.save writes (a plain dict of the same
    tensors would give other bytes)."""
    model = BaseModel()
    state, host = model.state_dict(), host_state_dict(model)
    assert type(host) is type(state) and host._metadata == state._metadata
    assert all(host[key].data_ptr() == state[key].data_ptr() for key in state)  # on the CPU: no copies
    ours, torchs, plain = io.BytesIO(), io.BytesIO(), io.BytesIO()
    torch.save(host, ours)
    torch.save(state, torchs)
    torch.save(dict(state), plain)
    assert ours.getvalue() == torchs.getvalue() != plain.getvalue()


@pytest.mark.parametrize("device", DEVICES)
def test_a_checkpoint_saved_after_moving_to_a_device_and_back_has_the_original_bytes(tmp_path, device):
    plm_net = small_plm_net()
    original = {name: saved_bytes(tmp_path / "original" / name, model)
                for name, model in (("bm", plm_net.bm), ("tapm", plm_net.tapm))}
    plm_net.to(device)
    for name, model in (("bm", plm_net.bm), ("tapm", plm_net.tapm)):
        assert saved_bytes(tmp_path / "on_device" / name, model) == original[name]  # saved from the device
    # Back on the CPU with fresh storages (a round trip through float64 on the CPU, where there is no GPU).
    plm_net.to(torch.float64).to("cpu").to(torch.float32)
    for name, model in (("bm", plm_net.bm), ("tapm", plm_net.tapm)):
        assert saved_bytes(tmp_path / "back" / name, model) == original[name]


@pytest.mark.parametrize("device", DEVICES)
def test_checkpoints_load_onto_the_device_asked_for(tmp_path, device):
    plm_net = small_plm_net(seed=3)
    save_checkpoint(tmp_path / "bm", plm_net.bm, {})
    save_checkpoint(tmp_path / "tapm", plm_net.tapm, {"bm_fingerprint": state_fingerprint(plm_net.bm)})
    loaded = load_plm_net(tmp_path / "bm", tmp_path / "tapm", device)
    assert {p.device.type for p in loaded.parameters()} == {device}
    assert loaded.delta_ref_s.device.type == device
    bm = load_base_model(tmp_path / "bm", device)
    assert module_device(load_tapm(tmp_path / "tapm", bm)) == module_device(bm)  # a TAPM follows its BM
    frames = torch.from_numpy(random_frames(3))
    speed, latency_s = torch.full((3,), 16.7), torch.tensor([0.0, 0.22, 0.4])
    with torch.inference_mode():
        expected = plm_net(frames, speed, latency_s).steering
        steering = loaded(frames.to(device), speed.to(device), latency_s.to(device)).steering.cpu()
    torch.testing.assert_close(steering, expected, rtol=0, atol=0 if device == "cpu" else 1e-5)


def test_a_checkpoint_is_not_loaded_for_a_device_that_is_not_there(tmp_path, no_cuda):
    save_checkpoint(tmp_path / "bm", BaseModel(), {})
    with pytest.raises(BadInput, match="CUDA is not available"):
        load_base_model(tmp_path / "bm", "cuda")


# --- the fused inference form and the policies on a device ----------------------------------------------


def test_the_fused_form_builds_every_tensor_on_the_models_device():
    """On the meta device (shapes, no data) any tensor built on the CPU makes an operation fail, as a CPU
    tensor next to CUDA weights does: the batch path must run there end to end."""
    fused = FusedPLMNet(small_plm_net().to("meta"))
    frames = torch.zeros(3, 66, 200, dtype=torch.uint8, device="meta")
    output = fused(frames, torch.zeros(3, device="meta"), np.array([0.1, 0.22, 0.5], np.float32))
    assert output.steering.device.type == "meta" and output.steering.shape == (3,) and output.n_clamped == 1


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("batch", [1, 6])
def test_the_fused_form_equals_the_reference_forward_on_the_device(device, batch):
    plm_net = small_plm_net(seed=1).to(device)
    fused = FusedPLMNet(plm_net)
    frames = torch.from_numpy(random_frames(batch, seed=batch)).to(device)
    speed = torch.full((batch,), 16.7, device=device)
    for latency_s in LATENCIES_S:
        latencies = torch.tensor([latency_s] * batch) if batch == 1 else torch.tensor(LATENCIES_S)
        with torch.inference_mode():
            reference = plm_net(frames, speed, latencies.to(device))
            output = fused(frames, speed, latencies.numpy())
        assert output.steering.device == frames.device and output.steering.dtype == torch.float32
        torch.testing.assert_close(output.steering, reference.steering, rtol=0, atol=1e-6)
        assert output.n_clamped == reference.n_clamped


@pytest.mark.parametrize("device", DEVICES)
def test_policies_run_on_the_device_and_answer_in_host_numbers(device):
    plm_net = small_plm_net(seed=2)
    with torch.inference_mode():
        frames = random_frames(4, seed=9)
        expected_bm = plm_net.bm(torch.from_numpy(frames), torch.full((4,), 16.7)).numpy()
    policies = {"bm": BaseModelPolicy(plm_net.bm, device=device), "plm": PLMNetPolicy(plm_net, device=device),
                "plm_reference": PLMNetPolicy(plm_net, fused=False, device=device)}
    assert all(module_device(policy.model).type == device for policy in policies.values())
    for name, policy in policies.items():
        one = policy(frames[0], 16.7, 0.0)
        assert type(one) is float, name
        batch = policy.steer_batch(frames, np.full(4, 16.7), np.zeros(4))
        assert isinstance(batch, np.ndarray) and batch.dtype == np.float64 and batch.shape == (4,)
        # Latency 0: every form answers with the BM's action.
        np.testing.assert_allclose(batch, expected_bm, rtol=0, atol=1e-6 if device == "cpu" else 1e-5)
    latencies = np.array([0.1, 0.2, 0.3, 0.5])
    np.testing.assert_allclose(policies["plm"].steer_batch(frames, np.full(4, 16.7), latencies),
                               policies["plm_reference"].steer_batch(frames, np.full(4, 16.7), latencies),
                               rtol=0, atol=1e-6)
    assert policies["plm"].clamped_latency_count == 1


def test_policies_stay_where_the_model_is_unless_told():
    plm_net = small_plm_net()
    assert PLMNetPolicy(plm_net).device == torch.device("cpu") == BaseModelPolicy(plm_net.bm).device


def test_the_int8_form_is_refused_off_the_cpu():
    with pytest.raises(BadInput, match="int8 TAPM runs on the CPU only"):
        FusedPLMNet(small_plm_net().to("meta"), tapm_int8=True)


@pytest.mark.parametrize("device", DEVICES)
def test_make_policy_puts_the_shipped_models_on_the_device(device):
    for name in ("bm", "plm"):
        policy = make_policy(name, device=device)
        assert module_device(policy.model_policy.model).type == device
        assert type(policy(random_frames(1)[0], {"speed_mps": 16.7, "observation_age_s": 0.2})) is float


def test_make_policy_refuses_cuda_without_cuda(no_cuda):
    with pytest.raises(BadInput, match="CUDA is not available"):
        make_policy("plm", device="cuda")
    make_policy("expert", device="cuda")  # the expert runs on the host: nothing to refuse


# --- training ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    from plm_highway.training.synthetic import make_synthetic_dataset

    return make_synthetic_dataset(tmp_path_factory.mktemp("data") / "synthetic", n_episodes=6, steps_per_episode=20)


@pytest.mark.parametrize("device", DEVICES)
def test_training_runs_on_the_device_records_it_and_repeats_itself(data_dir, tmp_path, device):
    from plm_highway.training.train import TrainConfig, train_base_model, train_tapm

    config = TrainConfig(epochs=1, max_samples=64, show_progress=False)
    for run in ("first", "second"):
        train_base_model(data_dir, tmp_path / run / "bm", config=config, device=device)
        train_tapm(data_dir, tmp_path / run / "tapm", tmp_path / run / "bm", config=config, device=device)
    for name in ("bm", "tapm"):
        description = json.loads((tmp_path / "first" / name / "model.json").read_text())
        assert description["training"]["device"].split(":")[0] == device
        # Deterministic algorithms on every device: the same seed gives the same bytes.
        assert (tmp_path / "first" / name / "model.pt").read_bytes() == (
            tmp_path / "second" / name / "model.pt").read_bytes()
    loaded = load_plm_net(tmp_path / "first" / "bm", tmp_path / "first" / "tapm")  # saved from the device, read on the CPU
    assert module_device(loaded) == torch.device("cpu")


def test_training_refuses_cuda_without_cuda_before_writing(data_dir, tmp_path, no_cuda):
    from plm_highway.training.train import TrainConfig, train_base_model

    with pytest.raises(BadInput, match="CUDA is not available"):
        train_base_model(data_dir, tmp_path / "bm", config=TrainConfig(epochs=1, show_progress=False), device="cuda")
    assert not (tmp_path / "bm").exists()


# --- the closed loop on a device ---------------------------------------------------------------------------


class RecordingBackend:
    """Runs each chunk here, keeping what a worker would have been sent."""

    workers = 2

    def __init__(self):
        self.sent = []

    def map_unordered(self, function, items):
        for index, item in enumerate(items):
            self.sent.append(item)
            yield index, function(item)


def test_run_cells_sends_the_device_to_every_worker():
    from plm_highway.road.track import resolve_track
    from plm_highway.rollout.cells import run_cells
    from plm_highway.rollout.closed_loop import RunCell

    track = resolve_track("test")
    cells = [RunCell(f"expert {seed}", "expert", track, "const:0.1", seed, max_steps=3) for seed in range(3)]
    backend = RecordingBackend()
    logs = run_cells(cells, backend=backend, batch_size=2, device="cpu")
    assert [len(log.columns["steering"]) for log in logs] == [3, 3, 3]
    # resolved once, here: every worker gets the same torch.device, not a name to resolve again
    assert backend.sent and {chunk.device for chunk in backend.sent} == {torch.device("cpu")}


def test_run_cells_refuses_cuda_without_cuda_before_driving(no_cuda):
    from plm_highway.rollout.cells import run_cells

    with pytest.raises(BadInput, match="CUDA is not available"):
        run_cells([], device="cuda")


@needs_cuda
def test_the_models_on_cuda_steer_like_the_cpu_step_by_step():
    # Identical inputs (what a CPU run gave its model, step by step), one forward pass on each device: the GPU sums
    # float32 in another order, so the steering agrees to one forward pass's rounding (~1e-6 at |steering| <= 1; 1e-5
    # as in the policies' test above). A closed loop is not compared: it feeds each step's difference back through
    # the car and the camera, and how far it then drifts depends on the GPU.
    from plm_highway.rollout.closed_loop import drive

    calls = []
    cpu = make_policy("plm")
    model = cpu.model_policy

    class Recording:
        def __getattr__(self, name):
            return getattr(model, name)

        def __call__(self, frame, speed_mps, latency_s=0.0):
            steering = model(frame, speed_mps, latency_s)
            calls.append((np.array(frame), speed_mps, latency_s, steering))
            return steering

    cpu.model_policy = Recording()
    drive("cpu", cpu, "test", "steps:0.0-0.35:1.0", 0, max_steps=40)
    on_cuda = make_policy("plm", device="cuda").model_policy
    frames, speeds, latencies, on_cpu = zip(*calls)
    for start in range(0, len(calls), 8):  # batches of 8 steps
        steering = on_cuda.steer_batch(np.stack(frames[start:start + 8]), speeds[start:start + 8],
                                       latencies[start:start + 8])
        np.testing.assert_allclose(steering, on_cpu[start:start + 8], rtol=0, atol=1e-5, err_msg=f"step {start}")


@needs_cuda
def test_evaluate_runs_on_cuda_with_the_cpus_latency_realisation():
    from plm_highway.evaluation.evaluate import evaluate

    on_cpu, _ = evaluate(max_steps=40, seeds=2, device="cpu")
    on_cuda, _ = evaluate(max_steps=40, seeds=2, device="cuda")
    for cpu_seed, cuda_seed in zip(on_cpu["per_seed"], on_cuda["per_seed"]):
        assert cuda_seed["runs"].keys() == cpu_seed["runs"].keys()
        for role, run in cpu_seed["runs"].items():
            assert cuda_seed["runs"][role]["steps"] == run["steps"]
            assert np.isfinite(cuda_seed["runs"][role]["lateral_offset_rms_m"])
