"""``plm-highway bench models``: parameter counts and batch-1 CPU inference time of BM and PLM-Net.

Both models are freshly initialised (timing does not depend on the weights' values) and in eval
mode under ``torch.inference_mode``. PLM-Net reuses the BM's convolution features (one conv pass)
and runs its heads batched. After ``--warmup`` frames per model, the two are timed in alternating
blocks of :data:`BLOCK_FRAMES` frames so that a slow spell of the machine hits both sides alike,
while each block still runs with its own weights warm in cache as a deployed model would.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

BLOCK_FRAMES = 50
TARGET_OVERHEAD_RATIO = 1.25
LATENCY_RANGE_S = (0.0, 0.35)
SPEED_MPS = 16.7


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", choices=("default", "paper"), default="default")
    parser.add_argument("--frames", type=int, default=500, help="timed frames per model (>= 500 for the report)")
    parser.add_argument("--warmup", type=int, default=50, help="untimed frames per model first")
    parser.add_argument("--json", help="write the results to this JSON file (atomically)")
    parser.add_argument("--threads", type=int, help="torch intra-op threads (default: the CPUs this process may use)")
    parser.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    import torch

    from plm_highway.data.atomic import write_text_atomic
    from plm_highway.training.cli import available_cpus

    if args.frames < 1 or args.warmup < 0:
        raise ValueError(f"--frames must be >= 1 and --warmup >= 0, got {args.frames} and {args.warmup}")
    torch.set_num_threads(args.threads or available_cpus())
    result = benchmark_models(args.preset, args.frames, args.warmup, args.seed)
    print(format_report(result))
    if args.json:
        write_text_atomic(args.json, json.dumps(result, indent=2) + "\n")
    return 0


def benchmark_models(preset: str = "default", n_frames: int = 500, n_warmup: int = 50, seed: int = 0) -> dict:
    import torch

    from plm_highway.models.base_model import BaseModel, count_parameters, preset_config
    from plm_highway.models.plm_net import PLMNet
    from plm_highway.models.tapm import TAPM, TAPMConfig

    torch.manual_seed(seed)
    bm = BaseModel(preset_config(preset))
    plm_net = PLMNet(bm, TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim))).eval()
    inputs = _inputs(bm.config.image_size_px, n_frames + n_warmup, seed)

    def run_bm(frame, speed, latency):
        return bm(frame, speed)

    def run_plm(frame, speed, latency):
        return plm_net(frame, speed, latency)

    with torch.inference_mode():
        for model in (run_bm, run_plm):
            for frame in inputs[:n_warmup]:
                model(*frame)
        bm_ms, plm_ms = _time_alternating(run_bm, run_plm, inputs[n_warmup:])
    return {
        "preset": preset,
        "image_size_px": list(bm.config.image_size_px),
        "bm_params": count_parameters(bm),
        "tapm_trainable_params": count_parameters(plm_net.tapm, trainable=True),
        # The one frozen BM the TAPM reads from (the paper's Table 2 counts it twice, see notes).
        "tapm_frozen_params": count_parameters(plm_net, trainable=False),
        "plm_net_params": count_parameters(plm_net),
        **_summary("bm", bm_ms),
        **_summary("plm", plm_ms),
        "overhead_ratio": float(np.mean(plm_ms) / np.mean(bm_ms)),
        "overhead_ratio_median": float(np.median(plm_ms) / np.median(bm_ms)),
        "target_overhead_ratio": TARGET_OVERHEAD_RATIO,
        "frames": n_frames,
        "warmup_frames": n_warmup,
        "batch_size": 1,
        "threads": torch.get_num_threads(),
        "torch_version": torch.__version__,
    }


def _inputs(image_size_px: tuple[int, int], n: int, seed: int) -> list[tuple]:
    import torch

    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, size=(n, 1, *image_size_px), dtype=np.uint8)
    latencies_s = rng.uniform(*LATENCY_RANGE_S, size=(n, 1)).astype(np.float32)
    speed = torch.tensor([SPEED_MPS])
    return [(torch.from_numpy(frames[i]), speed, torch.from_numpy(latencies_s[i])) for i in range(n)]


def _time_alternating(first, second, inputs: list[tuple]) -> tuple[np.ndarray, np.ndarray]:
    times_ms: tuple[list[float], list[float]] = ([], [])
    for start in range(0, len(inputs), BLOCK_FRAMES):
        block = inputs[start : start + BLOCK_FRAMES]
        for model, out in ((first, times_ms[0]), (second, times_ms[1])):
            for frame in block:
                t0_ns = time.perf_counter_ns()
                model(*frame)
                out.append((time.perf_counter_ns() - t0_ns) / 1e6)
    return np.asarray(times_ms[0]), np.asarray(times_ms[1])


def _summary(name: str, times_ms: np.ndarray) -> dict:
    return {
        f"{name}_ms_mean": float(np.mean(times_ms)),
        f"{name}_ms_median": float(np.median(times_ms)),
        f"{name}_ms_p95": float(np.percentile(times_ms, 95)),
    }


def format_report(result: dict) -> str:
    status = "meets" if result["overhead_ratio"] <= result["target_overhead_ratio"] else "MISSES"
    height, width = result["image_size_px"]
    return "\n".join(
        [
            f"preset {result['preset']} ({height}x{width} px), batch 1, {result['threads']} threads, "
            f"{result['frames']} frames after {result['warmup_frames']} warm-up",
            f"parameters: BM {result['bm_params']:,}; TAPM trainable {result['tapm_trainable_params']:,}, "
            f"frozen (BM) {result['tapm_frozen_params']:,}",
            f"BM      : mean {result['bm_ms_mean']:.3f} ms, median {result['bm_ms_median']:.3f} ms, "
            f"p95 {result['bm_ms_p95']:.3f} ms",
            f"PLM-Net : mean {result['plm_ms_mean']:.3f} ms, median {result['plm_ms_median']:.3f} ms, "
            f"p95 {result['plm_ms_p95']:.3f} ms",
            f"overhead ratio PLM-Net / BM: {result['overhead_ratio']:.3f} (median {result['overhead_ratio_median']:.3f}); "
            f"{status} the target <= {result['target_overhead_ratio']}",
        ]
    )
