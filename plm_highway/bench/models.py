"""``plm-highway bench models``: parameter counts and batch-1 CPU inference time of BM and PLM-Net.

Both models are freshly initialised (timing does not depend on the weights' values) and in eval
mode under ``torch.inference_mode``. PLM-Net reuses the BM's convolution features (one conv pass)
and runs its heads batched. After ``--warmup`` frames per model, the two are timed in alternating
blocks of :data:`BLOCK_FRAMES` frames so that a slow spell of the machine hits both sides alike,
while each block still runs with its own weights warm in cache as a deployed model would.

One torch thread by default: at batch size 1 the matrix-vector products gain nothing from a
second thread, and in the closed loop the simulator needs the other core. Besides wall time, the
calling thread's CPU time is recorded (``*_cpu_ms_*``; the whole CPU time with ``--threads 1``),
which other processes on a shared machine disturb far less. The 1-minute load average before
the run is recorded for the same reason.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import NamedTuple

import numpy as np

from plm_highway.bench import BENCH_RESULT

BLOCK_FRAMES = 50
TARGET_OVERHEAD_RATIO = 1.25
LATENCY_RANGE_S = (0.0, 0.35)
SPEED_MPS = 16.7


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", choices=("default", "paper"), default="default", help="model size preset")
    parser.add_argument(
        "--frames", type=int, default=500, help="timed frames per model (>= 500 for the report)"
    )
    parser.add_argument("--warmup", type=int, default=50, help="untimed frames per model first")
    parser.add_argument("--json", help="write the results to this JSON file (atomically)")
    parser.add_argument(
        "--threads", type=int, default=1, help="torch intra-op threads (default: %(default)s)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the random weights and inputs")


def run(args: argparse.Namespace) -> int:
    import torch

    from plm_highway.io import write_json

    if args.frames < 1 or args.warmup < 0 or args.threads < 1:
        raise ValueError(
            f"--frames and --threads must be >= 1 and --warmup >= 0, got {args.frames}, "
            f"{args.threads} and {args.warmup}"
        )
    torch.set_num_threads(args.threads)
    result = benchmark_models(args.preset, args.frames, args.warmup, args.seed)
    print(format_report(result))
    if args.json:
        write_json(args.json, result, BENCH_RESULT, overwrite=args.overwrite)
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
    load_average_1min = os.getloadavg()[0]

    def run_bm(frame, speed, latency):
        return bm(frame, speed)

    def run_plm(frame, speed, latency):
        return plm_net(frame, speed, latency)

    with torch.inference_mode():
        for model in (run_bm, run_plm):
            for frame in inputs[:n_warmup]:
                model(*frame)
        bm_times, plm_times = _time_alternating(run_bm, run_plm, inputs[n_warmup:])
    return {
        "preset": preset,
        "image_size_px": list(bm.config.image_size_px),
        "bm_params": count_parameters(bm),
        "tapm_trainable_params": count_parameters(plm_net.tapm, trainable=True),
        # The one frozen BM the TAPM reads from (the paper's Table 2 counts it twice, see notes).
        "tapm_frozen_params": count_parameters(plm_net, trainable=False),
        "plm_net_params": count_parameters(plm_net),
        **_summary("bm", bm_times),
        **_summary("plm", plm_times),
        "overhead_ratio": float(np.mean(plm_times.wall_ms) / np.mean(bm_times.wall_ms)),
        "overhead_ratio_median": float(np.median(plm_times.wall_ms) / np.median(bm_times.wall_ms)),
        "overhead_ratio_cpu": float(np.mean(plm_times.cpu_ms) / np.mean(bm_times.cpu_ms)),
        "target_overhead_ratio": TARGET_OVERHEAD_RATIO,
        "frames": n_frames,
        "warmup_frames": n_warmup,
        "batch_size": 1,
        "threads": torch.get_num_threads(),
        "load_average_1min": load_average_1min,
        "cpus": os.cpu_count(),
        "torch_version": torch.__version__,
    }


def _inputs(image_size_px: tuple[int, int], n: int, seed: int) -> list[tuple]:
    import torch

    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, size=(n, 1, *image_size_px), dtype=np.uint8)
    latencies_s = rng.uniform(*LATENCY_RANGE_S, size=(n, 1)).astype(np.float32)
    speed = torch.tensor([SPEED_MPS])
    return [(torch.from_numpy(frames[i]), speed, torch.from_numpy(latencies_s[i])) for i in range(n)]


class Timings(NamedTuple):
    wall_ms: np.ndarray
    cpu_ms: np.ndarray  # the calling thread's CPU time


def _time_alternating(first, second, inputs: list[tuple]) -> tuple[Timings, Timings]:
    samples: tuple[list, list] = ([], [])
    for start in range(0, len(inputs), BLOCK_FRAMES):
        block = inputs[start : start + BLOCK_FRAMES]
        for model, out in ((first, samples[0]), (second, samples[1])):
            for frame in block:
                out.append(_time_call(model, frame))
    return tuple(Timings(*(np.asarray(column) / 1e6 for column in zip(*times))) for times in samples)


def _time_call(model, frame: tuple) -> tuple[int, int]:
    """(wall ns, thread CPU ns) of one call."""
    wall0_ns, cpu0_ns = time.perf_counter_ns(), time.thread_time_ns()
    model(*frame)
    return time.perf_counter_ns() - wall0_ns, time.thread_time_ns() - cpu0_ns


def _summary(name: str, times: Timings) -> dict:
    return {
        f"{name}_ms_mean": float(np.mean(times.wall_ms)),
        f"{name}_ms_median": float(np.median(times.wall_ms)),
        f"{name}_ms_p95": float(np.percentile(times.wall_ms, 95)),
        f"{name}_cpu_ms_mean": float(np.mean(times.cpu_ms)),
    }


def format_report(result: dict) -> str:
    status = "meets" if result["overhead_ratio"] <= result["target_overhead_ratio"] else "MISSES"
    height, width = result["image_size_px"]
    lines = [
        (
            f"preset {result['preset']} ({height}x{width} px), batch 1, {result['threads']} threads, "
            f"{result['frames']} frames after {result['warmup_frames']} warm-up, "
            f"load average {result['load_average_1min']:.2f} on {result['cpus']} CPUs"
        ),
        (
            f"parameters: BM {result['bm_params']:,}; TAPM trainable {result['tapm_trainable_params']:,}, "
            f"frozen (BM) {result['tapm_frozen_params']:,}"
        ),
        (
            f"BM      : mean {result['bm_ms_mean']:.3f} ms, median {result['bm_ms_median']:.3f} ms, "
            f"p95 {result['bm_ms_p95']:.3f} ms; CPU {result['bm_cpu_ms_mean']:.3f} ms"
        ),
        (
            f"PLM-Net : mean {result['plm_ms_mean']:.3f} ms, median {result['plm_ms_median']:.3f} ms, "
            f"p95 {result['plm_ms_p95']:.3f} ms; CPU {result['plm_cpu_ms_mean']:.3f} ms"
        ),
        (
            f"overhead ratio PLM-Net / BM: {result['overhead_ratio']:.3f} (median "
            f"{result['overhead_ratio_median']:.3f}, CPU time {result['overhead_ratio_cpu']:.3f}); "
            f"{status} the target <= {result['target_overhead_ratio']}"
        ),
    ]
    return "\n".join(lines)
