"""Batch-invariant kernels: a sample's steering does not depend on the rest of its batch.

What makes this hold is MKL's and oneDNN's kernel choice, which no documentation promises, so it is
checked here for both presets (every layer shape the models have) and both model policies, at many
batch compositions: each sample of a batch must equal, bit for bit, the same sample run alone.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plm_highway.models.base_model import BaseModel, preset_config
from plm_highway.models.batch_invariant import batch_invariant_ops, conv2d, conv_stack, linear
from plm_highway.models.inference import BaseModelPolicy, PLMNetPolicy
from plm_highway.models.plm_net import PLMNet
from plm_highway.models.shipped import load_shipped_plm_net
from plm_highway.models.tapm import TAPM, TAPMConfig

# zero (the BM alone), grid points, between them, above the grid
LATENCIES_S = [0.0, 0.0, 0.01, 0.1, 0.15, 0.151, 0.2, 0.2499, 0.25, 0.3, 0.34, 0.35, 0.36, 0.5, 2.0]


@pytest.fixture(scope="module", params=["default", "paper"])
def plm_net(request):
    if request.param == "default":
        return load_shipped_plm_net("default")
    torch.manual_seed(0)  # random weights of the paper preset's shapes (160x160x3, its TAPM)
    bm = BaseModel(preset_config("paper"))
    plm_net = PLMNet(bm, TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim))).eval()
    frames, speeds, _ = inputs(plm_net, 8, seed=0)
    # Outputs inside tanh's range, not saturated at +-1 (where any sum order agrees): the largest
    # power-of-ten scale of each output layer that keeps them below 0.9.
    for weight, latency_s in ((bm.steering_head.weight, 0.0), (plm_net.tapm.heads_out.weight, 0.2)):
        while np.max(np.abs(PLMNetPolicy(plm_net).steer_batch(frames, speeds, np.full(8, latency_s)))) > 0.9:
            with torch.no_grad():
                weight.mul_(0.1)
        assert np.ptp(PLMNetPolicy(plm_net).steer_batch(frames, speeds, np.full(8, latency_s))) > 1e-4  # >1000 float32 steps apart
    return plm_net


def inputs(plm_net: PLMNet, n: int, seed: int):
    rng = np.random.default_rng(seed)
    height, width = plm_net.bm.config.image_size_px
    return (rng.integers(0, 256, (n, height, width), dtype=np.uint8), rng.uniform(5, 30, n),
            rng.choice(LATENCIES_S, n).astype(np.float32))


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                   HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 40), seed=st.integers(0, 2**32 - 1), bm_only=st.booleans())
def test_every_sample_of_a_batch_equals_it_run_alone(plm_net, n, seed, bm_only):
    policy = BaseModelPolicy(plm_net.bm, batch_invariant=True) if bm_only else PLMNetPolicy(plm_net,
                                                                                            batch_invariant=True)
    frames, speeds, latencies = inputs(plm_net, n, seed)
    alone = [policy.steer_batch(frames[i : i + 1], speeds[i : i + 1], latencies[i : i + 1])[0] for i in range(n)]
    assert policy.steer_batch(frames, speeds, latencies).tolist() == alone


def test_the_default_kernels_are_not_batch_invariant_which_is_why_the_mode_exists():
    # Guards the test above against passing because nothing differs: without the mode a batch of 16 differs.
    plm_net = load_shipped_plm_net("default")
    frames, speeds, latencies = inputs(plm_net, 16, seed=4)
    policy = BaseModelPolicy(plm_net.bm)
    alone = np.array([policy.steer_batch(frames[i : i + 1], speeds[i : i + 1], latencies[i : i + 1])[0]
                      for i in range(16)])
    batched = policy.steer_batch(frames, speeds, latencies)
    assert not np.array_equal(batched, alone)
    np.testing.assert_allclose(batched, alone, rtol=0, atol=1e-5)


@pytest.mark.parametrize("threads", [1, 2])
def test_the_mode_runs_on_one_thread_and_restores_the_thread_count(threads):
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        with batch_invariant_ops():
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == threads
    finally:
        torch.set_num_threads(previous)


@pytest.mark.parametrize("width,out", [(1, 144), (10, 1), (50, 1), (50, 10), (100, 2), (144, 100), (250, 5),
                                       (512, 100), (700, 1000), (1296, 1012), (17, 3)])
def test_a_product_row_is_the_same_at_any_row_count_and_position(width, out):
    generator = torch.Generator().manual_seed(width * 1000 + out)
    weight, bias = torch.randn(out, width, generator=generator), torch.randn(out, generator=generator)
    rows = torch.randn(40, width, generator=generator).relu()
    with batch_invariant_ops():  # one thread: MKL splits a product over two differently for different row counts
        alone = torch.cat([linear(rows[i : i + 1], weight, bias) for i in range(40)])
        for n in (2, 3, 4, 5, 7, 8, 9, 16, 17, 33):
            for start in (0, 1, 3):
                assert torch.equal(linear(rows[start : start + n], weight, bias), alone[start : start + n]), (n, start)
    torch.testing.assert_close(alone, torch.nn.functional.linear(rows, weight, bias), rtol=1e-5, atol=1e-4)


def test_a_convolution_sample_is_the_same_at_any_batch_size():
    generator = torch.Generator().manual_seed(1)
    images = torch.randn(20, 24, 31, 98, generator=generator)
    weight, bias = torch.randn(36, 24, 5, 5, generator=generator), torch.randn(36, generator=generator)
    with batch_invariant_ops():
        alone = torch.cat([conv2d(images[i : i + 1], weight, bias, 2) for i in range(20)])
        for n in (2, 3, 16, 17, 20):
            assert torch.equal(conv2d(images[:n], weight, bias, 2), alone[:n])
    torch.testing.assert_close(alone, torch.nn.functional.conv2d(images, weight, bias, 2), rtol=0, atol=1e-4)


@pytest.mark.parametrize("preset", ["default", "paper"])
def test_the_conv_stack_is_the_layer_by_layer_convolutions_bit_for_bit(preset):
    # conv_stack keeps the activations in oneDNN's blocked layout between layers; the values must be those of
    # the layers run one by one through oneDNN's convolution (the per-layer batch-invariant path), whatever the batch.
    torch.manual_seed(3)
    bm = BaseModel(preset_config(preset)).eval()
    height, width = bm.config.image_size_px
    pixels = torch.rand(5, bm.config.input_channels, height, width) * 2 - 1
    with torch.no_grad():
        layer_by_layer = pixels
        for layer in bm.convs:
            layer_by_layer = (conv2d(layer_by_layer, layer.weight, layer.bias, layer.stride)
                              if isinstance(layer, torch.nn.Conv2d) else layer(layer_by_layer))
        stacked = conv_stack(bm.convs, pixels)
        alone = torch.cat([conv_stack(bm.convs, pixels[i : i + 1]) for i in range(5)])
    assert torch.equal(stacked, layer_by_layer)
    assert torch.equal(stacked, alone)
    torch.testing.assert_close(stacked, bm.convs(pixels), rtol=1e-5, atol=1e-5)


KERNEL_VARIATION_CHECK = """
import numpy as np, torch
from plm_highway.models.inference import PLMNetPolicy
from plm_highway.models.shipped import load_shipped_plm_net
assert torch.backends.cpu.get_cpu_capability() == "DEFAULT", torch.backends.cpu.get_cpu_capability()
plm_net = load_shipped_plm_net("default")
rng = np.random.default_rng(7)
height, width = plm_net.bm.config.image_size_px
frames = rng.integers(0, 256, (9, height, width), dtype=np.uint8)
speeds, latencies = rng.uniform(5, 30, 9), rng.choice([0.0, 0.1, 0.2, 0.25, 0.5], 9)
for invariant in (True, False):
    policy = PLMNetPolicy(plm_net, batch_invariant=invariant)
    alone = np.array([policy.steer_batch(frames[i:i + 1], speeds[i:i + 1], latencies[i:i + 1])[0] for i in range(9)])
    batched = policy.steer_batch(frames, speeds, latencies)
    print(invariant, float(np.max(np.abs(batched - alone))))
"""


def test_the_properties_hold_with_the_generic_kernels_on_one_thread():
    # Another processor makes PyTorch pick other kernels; ATEN_CPU_CAPABILITY=default forces the generic ones
    # (no AVX2/AVX-512), which every x86-64 processor runs. The mode stays exact, the default kernels within
    # one forward pass's rounding (tests/test_batched.py, ONE_FORWARD_ATOL).
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {**os.environ, "ATEN_CPU_CAPABILITY": "default", "OMP_NUM_THREADS": "1",
           "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    result = subprocess.run([sys.executable, "-c", KERNEL_VARIATION_CHECK], env=env, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    differences = dict(line.split() for line in result.stdout.splitlines())
    assert float(differences["True"]) == 0.0
    assert float(differences["False"]) <= 1e-5
