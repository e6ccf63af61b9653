"""``plm-highway bench models``: PLM-Net's inference cost over the Base Model, batched throughput, training speed.

Per preset (``--preset default|paper|both``), on ``--device`` (``auto``: a CUDA GPU when torch sees one; on
the CPU torch runs on ``--threads`` threads, 1 by default: at batch size 1 a second thread gains nothing
and in the closed loop the simulator needs the other core):

Weights and frames (``--weights``): ``shipped`` (default) times each preset's shipped checkpoints on frames
the simulator renders under that preset's conditions (the expert driving the test track; ``collect``'s
recording: ``ideal`` for the default preset, ``paper`` for the paper preset), what the closed loop runs;
``random`` times freshly initialised models on uniformly random frames. It matters since PLM-Net's one-frame
form reads only the image-branch weight rows of nonzero image features (see
:class:`~plm_highway.models.plm_net.FusedPLMNet`), and how many are zero depends on the weights and the
frames (about 90% with the shipped checkpoints on rendered frames, 40-55% with random weights on noise):
the report gives the fraction of nonzero image features over the timed frames.

1. **Overhead at batch size 1**, what the closed loop runs: the BM policy, the PLM-Net policy in
   its exact inference form (:class:`FusedPLMNet`, fp32), on the CPU the same with the TAPM's large layers
   in int8 (``tapm_int8=True``, an approximation; PyTorch's quantised kernels are CPU kernels) and the
   PLM-Net reference (:meth:`PLMNet.forward`, every head) are timed frame by frame, the sides taking
   turns on every frame (:data:`BLOCK_FRAMES` = 1; the one going first rotates), so that a slow spell of a
   shared machine hits all sides alike and every call finds the caches as the other sides left them, as a
   closed loop's env step between two calls leaves them. (Blocks of 50 frames per side let a spell of
   other jobs, seconds long, fall on one side's blocks: ratios of one run spread from 1.5 to 5.3.) A call takes numpy frames and returns the steering to the host, so on a GPU every
   timed call includes the copies and waits for the GPU to finish. The ratio of median times is taken per
   repeat; the report gives the median over ``--repeats`` (3) and each repeat's, for wall time and for the
   calling thread's CPU time (which other processes disturb less), and a table of both presets' ratios
   side by side at the end, beside the paper's own figures (:data:`plm_highway.evaluation.paper_results.INFERENCE`:
   BM 2.352 ms and PLM-Net 5.909 ms on an RTX 2080 Ti, its Section 4.8). Both fused forms are compared
   with the reference on every timed input (max |difference|). On the CPU a BM whose first layer skips zero
   features as PLM-Net's image branch does (:func:`sparse_first_layer_bm`) is timed too, and PLM-Net's ratio
   over it reported: PLM-Net's one-frame form gains from the sparsity of z_o, which a BM could use as well.
2. **Batched throughput**: ``steer_batch`` of both policies at batch sizes :data:`BATCH_SIZES` (1, 32 and
   256), samples/s from the median call time, interleaved the same way.
3. **Training samples/s** of the BM and of the TAPM (on a frozen BM) over a short synthetic run on the
   device: the training loop itself (batches of 32, augmentation, Adam, deterministic algorithms), epochs
   alternating between the two, the median over ``--repeats``.

``--closed-loop`` also drives each timed preset's shipped checkpoints on the test track (on the CPU), under
the conditions they are for (default: ``ideal``; paper: ``paper``, as ``reproduce`` drives them;
``--closed-loop-steps`` shortens the runs): per seed the reference run (BM, no latency) and, for 5
seeds of the paper's time-variant profile (``steps:0.0-0.35:1.0``),
PLM-Net with the reference forward, the exact fused form and the int8 form, reporting each form's
steering MAE against the reference (mean and 95% CI over the seeds), the paired differences
(exact fused - reference forward: float rounding; int8 - exact fused: the approximation, before
and after), whether the int8 mean lies within the exact form's CI, and the largest step-wise
difference from the reference forward. The exact form equals the reference up to float rounding
(~1e-7), but a closed loop amplifies that: a difference that moves the car by a nanometre changes
a rendered uint8 pixel sooner or later, so the runs part slightly; the MAE shows whether it matters.

The 1-minute load average before the run is recorded: on a shared machine the absolute times
mean little, the ratios measured side by side in one run are what to compare.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np
import torch
from tqdm.auto import tqdm

from plm_highway.data.collect import collect
from plm_highway.evaluation.paper_results import INFERENCE
from plm_highway.evaluation.reproduce import conditions_named
from plm_highway.metrics.intervals import interval_text, mean_ci
from plm_highway.metrics.steering import common_span, steering_mae
from plm_highway.models.base_model import BaseModel, count_parameters, preset_config
from plm_highway.models.device import describe_device, resolve_device
from plm_highway.models.inference import BaseModelPolicy, PLMNetPolicy
from plm_highway.models.plm_net import PLMNet, SparseInputLinear
from plm_highway.models.shipped import load_shipped_plm_net
from plm_highway.models.tapm import TAPM, TAPMConfig
from plm_highway.road.track import load_track
from plm_highway.rollout.cells import Cell, drive_options
from plm_highway.rollout.closed_loop import drive
from plm_highway.rollout.conditions import scored_steps
from plm_highway.rollout.policies import VisionPolicy, single_threaded_inference
from plm_highway.training.samples import LabelledRows
from plm_highway.training.synthetic import render_lane_frames
from plm_highway.training.train import TrainConfig, bm_loss, deterministic, freeze, tapm_loss, train_epoch

THROUGHPUT_BLOCK_SAMPLES = 50
BLOCK_FRAMES = 1  # frames per side and turn (batch size 1); the throughput's turns take 50 samples
TARGET_OVERHEAD_RATIO = 1.25
LATENCY_RANGE_S = (0.0, 0.35)
SPEED_MPS = 16.7
BATCH_SIZES = (1, 32, 256)
PRESETS = ("default", "paper")
WEIGHTS = ("shipped", "random")
TRAIN_BATCH_SIZE = 32
CLOSED_LOOP_LATENCY = "steps:0.0-0.35:1.0"  # the paper's time-variant profile
CLOSED_LOOP_SEEDS = 5
MAX_FRAMES = 100_000
MAX_REPEATS = 100
RENDERED_EPISODE_S = 8.0  # collect's default episode; at least 160 frames each (20 Hz)

# The conditions each preset's shipped checkpoints are driven under.
PRESET_CONDITIONS = {"default": "ideal", "paper": "paper"}


def benchmark_models(presets=PRESETS, n_frames: int = 500, n_warmup: int = 50, repeats: int = 3,
                     train_batches: int = 10, seed: int = 0, closed_loop: bool = False,
                     closed_loop_steps: int | None = None, device="cpu", weights: str = "shipped") -> dict:
    device = resolve_device(device)
    if weights not in WEIGHTS:
        raise ValueError(f"weights: {weights!r} is not one of {list(WEIGHTS)}")
    result = {
        "conditions": {
            "device": describe_device(device),
            "threads": torch.get_num_threads(),
            "load_average_1min": os.getloadavg()[0],
            "cpus": os.cpu_count(),
            "torch_version": torch.__version__,
            "weights": weights,
            "frames": n_frames,
            "warmup_frames": n_warmup,
            "repeats": repeats,
            "seed": seed,
        },
        "target_overhead_ratio": TARGET_OVERHEAD_RATIO,
        "paper": dict(INFERENCE),
        "presets": {
            preset: benchmark_preset(preset, n_frames, n_warmup, repeats, train_batches, seed, device, weights)
            for preset in presets
        },
    }
    if closed_loop:
        result["closed_loop"] = {preset: closed_loop_check(PRESET_CONDITIONS[preset], max_steps=closed_loop_steps)
                                 for preset in presets}
    return result


def benchmark_preset(preset: str, n_frames: int, n_warmup: int, repeats: int, train_batches: int, seed: int,
                     device="cpu", weights: str = "shipped") -> dict:
    torch.manual_seed(seed)
    n_inputs = max(n_warmup + n_frames, max(BATCH_SIZES))
    if weights == "shipped":
        plm_net = load_shipped_plm_net(preset, device).eval()
        frames = rendered_frames(PRESET_CONDITIONS[preset], n_inputs, seed)
        latencies_s = np.random.default_rng(seed).uniform(*LATENCY_RANGE_S, size=n_inputs)
    else:
        bm = BaseModel(preset_config(preset)).eval()
        plm_net = PLMNet(bm, TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim))).to(device).eval()
        frames, latencies_s = _inputs(bm.config.image_size_px, n_inputs, seed)
    bm = plm_net.bm
    policies = {"bm": BaseModelPolicy(bm), "plm": PLMNetPolicy(plm_net)}
    if torch.device(device).type == "cpu":  # PyTorch's quantised kernels and the sparse product: CPU only
        policies["plm_int8"] = PLMNetPolicy(plm_net, tapm_int8=True)
        policies["bm_sparse"] = sparse_first_layer_bm(bm)
    policies["plm_reference"] = PLMNetPolicy(plm_net, fused=False)
    overhead = _overhead(policies, frames, latencies_s, n_warmup, n_frames, repeats)
    return {
        "image_size_px": list(bm.config.image_size_px),
        "bm_params": count_parameters(bm),
        "tapm_trainable_params": count_parameters(plm_net.tapm, trainable=True),
        # The one frozen BM the TAPM reads from (the paper's Table 2 counts it twice, see notes).
        "tapm_frozen_params": count_parameters(plm_net, trainable=False),
        "plm_net_params": count_parameters(plm_net),
        "image_features_nonzero_fraction": _nonzero_fraction(bm, frames[n_warmup : n_warmup + n_frames], device),
        **overhead,
        "max_abs_difference_fused_vs_reference": _max_difference(
            policies["plm"], policies["plm_reference"], frames, latencies_s
        ),
        **({"max_abs_difference_int8_vs_reference": _max_difference(
            policies["plm_int8"], policies["plm_reference"], frames, latencies_s)} if "plm_int8" in policies else {}),
        "throughput_samples_per_s": _throughput(policies, frames, latencies_s, n_frames, repeats),
        "training_samples_per_s": _training_speed(bm.config, train_batches, repeats, seed, device),
    }


def sparse_first_layer_bm(bm):
    """A batch-size-1 BM policy whose first FC layer skips zero features as PLM-Net's image branch does
    (:class:`~plm_highway.models.plm_net.SparseInputLinear`; equal to the BM up to float rounding): timed
    beside the BM to show how much of PLM-Net's low overhead a BM could have too."""
    first_layer = SparseInputLinear.of(bm.mlp[0].weight, bm.mlp[0].bias)

    class SparseFirstLayerBM(BaseModelPolicy):
        name = "BM (sparse first layer)"

        def _forward(self, frames, speeds_mps, latencies_s):
            z_o, z_v = self.model.encode(frames, speeds_mps)
            return self.model.steering_from_first_layer(first_layer(self.model.mlp_input(z_o, z_v)))

    return SparseFirstLayerBM(bm)


def rendered_frames(conditions: str, n: int, seed: int) -> np.ndarray:
    """``n`` frames the simulator renders under ``conditions`` (its camera), the expert driving the test track
    (``collect``'s recording, displaced starts included, seeded): what a lane keeper sees."""
    episodes = math.ceil(n / (RENDERED_EPISODE_S * 20))  # at least 20 frames per second under any conditions
    frames, _, _ = collect(track="test", progress=False, conditions=conditions, episodes=episodes,
                           episode_seconds=RENDERED_EPISODE_S, seed=seed)
    return np.ascontiguousarray(frames[:n])


def _nonzero_fraction(bm, frames: np.ndarray, device) -> float:
    """The mean fraction of nonzero image features z_o (what PLM-Net's one-frame form reads weights for)."""
    nonzero, total = 0, 0
    with torch.inference_mode():
        for start in range(0, len(frames), 64):
            chunk = torch.from_numpy(frames[start : start + 64]).to(device)
            z_o, _ = bm.encode(chunk, torch.full((len(chunk),), SPEED_MPS, device=device))
            nonzero, total = nonzero + int((z_o != 0).sum()), total + z_o.numel()
    return nonzero / max(total, 1)


def _inputs(image_size_px: tuple[int, int], n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, size=(n, *image_size_px), dtype=np.uint8)
    return frames, rng.uniform(*LATENCY_RANGE_S, size=n)


def _overhead(policies: dict, frames: np.ndarray, latencies_s: np.ndarray, n_warmup: int, n_frames: int,
              repeats: int) -> dict:
    def call(name):
        policy = policies[name]
        return lambda i: policy(frames[i], SPEED_MPS, float(latencies_s[i]))

    calls = {name: call(name) for name in policies}
    with torch.inference_mode():
        for fn in calls.values():
            for i in range(n_warmup):
                fn(i)
        per_repeat = [
            _time_interleaved(calls, range(n_warmup, n_warmup + n_frames), block=BLOCK_FRAMES, shift=repeat)
            for repeat in range(repeats)
        ]
    forms = {"overhead_ratio": "plm", "int8_overhead_ratio": "plm_int8", "reference_overhead_ratio": "plm_reference"}
    repeats_summary = []
    for times in per_repeat:
        wall = {name: float(np.median(t[0])) for name, t in times.items()}
        cpu = {name: float(np.median(t[1])) for name, t in times.items()}
        repeats_summary.append({
            **{f"{name}_ms_median": wall[name] for name in wall},
            **{f"{name}_cpu_ms_median": cpu[name] for name in cpu},
            **{key: wall[side] / wall["bm"] for key, side in forms.items() if side in wall},
            **{f"{key}_cpu": cpu[side] / cpu["bm"] for key, side in forms.items() if side in cpu},
            # PLM-Net over a BM that skips zero features as PLM-Net's image branch does.
            **({"overhead_ratio_vs_sparse_bm": wall["plm"] / wall["bm_sparse"],
                "overhead_ratio_vs_sparse_bm_cpu": cpu["plm"] / cpu["bm_sparse"]} if "bm_sparse" in wall else {}),
        })
    summary = {key: float(np.median([r[key] for r in repeats_summary])) for key in repeats_summary[0]}
    return {**summary, "repeats": repeats_summary}


def _time_interleaved(calls: dict, indices, block: int, shift: int = 0) -> dict[str, tuple[list, list]]:
    """(wall ms, thread CPU ms) per call, the sides alternating in blocks; the first side rotates."""
    names = list(calls)
    times: dict[str, tuple[list, list]] = {name: ([], []) for name in names}
    indices = list(indices)
    for block_index, start in enumerate(range(0, len(indices), block)):
        offset = (block_index + shift) % len(names)
        for name in names[offset:] + names[:offset]:
            fn, (wall, cpu) = calls[name], times[name]
            for i in indices[start : start + block]:
                wall0_ns, cpu0_ns = time.perf_counter_ns(), time.thread_time_ns()
                fn(i)
                wall.append((time.perf_counter_ns() - wall0_ns) / 1e6)
                cpu.append((time.thread_time_ns() - cpu0_ns) / 1e6)
    return times


def _max_difference(fused, reference, frames: np.ndarray, latencies_s: np.ndarray) -> float:
    speeds = np.full(len(frames), SPEED_MPS)
    worst = 0.0
    for start in range(0, len(frames), 64):
        chunk = slice(start, start + 64)
        difference = fused.steer_batch(frames[chunk], speeds[chunk], latencies_s[chunk]) - reference.steer_batch(
            frames[chunk], speeds[chunk], latencies_s[chunk]
        )
        worst = max(worst, float(np.max(np.abs(difference))))
    return worst


def _throughput(policies: dict, frames: np.ndarray, latencies_s: np.ndarray, n_frames: int, repeats: int) -> dict:
    result: dict[str, dict[str, float]] = {"bm": {}, "plm": {}}
    speeds = np.full(max(BATCH_SIZES), SPEED_MPS)
    for batch_size in BATCH_SIZES:
        n_calls = max(3, n_frames // batch_size // 2)
        starts = np.arange(n_calls) * batch_size % (len(frames) - batch_size + 1)

        def batched(name, batch_size=batch_size, starts=starts):
            policy = policies[name]
            return lambda k: policy.steer_batch(
                frames[starts[k] : starts[k] + batch_size], speeds[:batch_size],
                latencies_s[starts[k] : starts[k] + batch_size],
            )

        calls = {name: batched(name) for name in result}
        for fn in calls.values():
            fn(0)
        medians = {name: [] for name in calls}
        for repeat in range(repeats):
            times = _time_interleaved(calls, range(n_calls), block=max(1, THROUGHPUT_BLOCK_SAMPLES // batch_size), shift=repeat)
            for name, (wall, _) in times.items():
                medians[name].append(float(np.median(wall)))
        for name in calls:
            result[name][str(batch_size)] = batch_size / (float(np.median(medians[name])) / 1e3)
    return result


def _training_speed(config, train_batches: int, repeats: int, seed: int, device="cpu") -> dict:
    """Samples/s of the training loop on synthetic frames on ``device``, BM and TAPM epochs alternating."""
    device = torch.device(device)
    rng = np.random.default_rng(seed)
    n_rows = TRAIN_BATCH_SIZE * train_batches
    steering = rng.uniform(-0.8, 0.8, n_rows).astype(np.float32)
    frames = render_lane_frames(steering, config.image_size_px, rng)
    train_config = TrainConfig(batch_size=TRAIN_BATCH_SIZE, seed=seed, show_progress=False)

    def rows(n_targets: int) -> LabelledRows:
        return LabelledRows(
            frame_index=np.arange(n_rows), episode_id=np.zeros(n_rows, np.int32), t_s=np.arange(n_rows) * 0.05,
            speed_mps=np.full(n_rows, SPEED_MPS, np.float32), steering=steering,
            targets=np.repeat(steering[:, None], n_targets, axis=1),
        )

    with deterministic(seed, device):
        bm = BaseModel(config).to(device)
        tapm = TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim)).to(device)
        frozen_bm = freeze(BaseModel(config).to(device))
        runs = {
            "bm": (bm, bm_loss(bm), rows(1)),
            "tapm": (tapm, tapm_loss(tapm, frozen_bm), rows(tapm.config.n_heads)),
        }
        optimizers = {
            name: torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=train_config.learning_rate)
            for name, (model, _, _) in runs.items()
        }
        generator = torch.Generator().manual_seed(seed)
        seconds: dict[str, list[float]] = {name: [] for name in runs}
        for repeat in range(repeats + 1):  # the first epoch of each warms up and is not counted
            for name, (model, loss_fn, labelled) in runs.items():
                start = time.perf_counter()
                # train_epoch reads the loss back to the host every batch, so the GPU's work is done when it returns.
                train_epoch(model, loss_fn, optimizers[name], frames, labelled, train_config, generator, device=device)
                if repeat > 0:
                    seconds[name].append(time.perf_counter() - start)
    return {name: n_rows / float(np.median(values)) for name, values in seconds.items()}


def closed_loop_check(conditions: str = "ideal", latency: str = CLOSED_LOOP_LATENCY, seeds: int = CLOSED_LOOP_SEEDS,
                      track: str = "test", max_steps: int | None = None) -> dict:
    """Steering MAE of PLM-Net, reference forward vs exact fused vs int8, against the reference run.

    The shipped checkpoints of ``conditions`` (``ideal``: the default preset; ``paper``: the paper
    preset, its camera, loop rate, latency injection and image noise), driven as ``reproduce`` drives
    them. Per seed, the reference run (the BM without latency) and PLM-Net in each form at
    ``latency`` (a random profile: the seed draws its realisation); ``max_steps`` shortens every run.
    Reports each form's mean MAE with its 95% confidence interval over the seeds, the paired
    differences with their intervals, whether the int8 mean lies within the exact form's interval,
    and the largest step-wise steering difference of each fused form from the reference forward.
    """
    run_conditions = conditions_named(conditions)
    track_spec = load_track(track)
    steps = scored_steps(track_spec, run_conditions, max_steps)
    plm_net = load_shipped_plm_net(run_conditions.checkpoint_preset)
    forms = {
        "reference_forward": {"fused": False},
        "fused": {"fused": True},
        "fused_int8": {"fused": True, "tapm_int8": True},
    }
    mae: dict[str, list[float]] = {name: [] for name in forms}
    largest_difference = {name: 0.0 for name in forms if name != "reference_forward"}

    def run(name: str, model_policy, spec: str, seed: int):
        options = drive_options(Cell("", "", spec, seed), run_conditions, steps)
        policy = VisionPolicy(model_policy, latency_source=run_conditions.latency_source)
        return drive(name, policy, track_spec, spec, seed, **options).columns["steering"]

    with single_threaded_inference():
        for seed in tqdm(range(seeds), desc=f"closed loop ({conditions})", leave=False):
            reference = run("reference", BaseModelPolicy(plm_net.bm), "const:0", seed)
            steering = {name: run(name, PLMNetPolicy(plm_net, **options), latency, seed)
                        for name, options in forms.items()}
            for name in forms:
                mae[name].append(steering_mae(*common_span(reference, steering[name])))
            for name in largest_difference:
                n = min(len(steering[name]), len(steering["reference_forward"]))
                largest_difference[name] = max(largest_difference[name], float(np.max(np.abs(
                    steering[name][:n] - steering["reference_forward"][:n]))))
    return {
        "conditions": run_conditions.name,
        "track": track,
        "latency": latency,
        "seeds": list(range(seeds)),
        "max_steps": steps,
        "checkpoints": f"shipped {run_conditions.checkpoint_preset}",
        **{f"{name}_mae": _mean_ci(values, "positive") for name, values in mae.items()},
        "fused_minus_reference_mae": _mean_ci(np.subtract(mae["fused"], mae["reference_forward"]), "linear"),
        "int8_minus_fused_mae": _mean_ci(np.subtract(mae["fused_int8"], mae["fused"]), "linear"),
        "int8_mean_within_fused_ci": mean_within_ci(mae["fused_int8"], mae["fused"]),
        "max_abs_steering_difference": largest_difference["fused"],
        "max_abs_steering_difference_int8": largest_difference["fused_int8"],
    }


def mean_within_ci(values, reference_values) -> bool:
    """Whether the mean of ``values`` (steering MAEs, never negative) lies within the 95% CI of
    ``reference_values``' mean, an interval on the log scale (False where that interval is undefined: fewer than 3
    reference values)."""
    reference = mean_ci(reference_values, scale="positive")
    return reference.low is not None and bool(reference.low <= float(np.mean(values)) <= reference.high)


# The scale of each closed-loop figure's interval: the MAEs are errors (log scale), the paired differences signed.
def _scale(key: str) -> str:
    return "linear" if "_minus_" in key else "positive"


def _mean_ci(values, scale: str) -> dict:
    """Mean, 95% Student-t interval on ``scale`` (:func:`~plm_highway.metrics.intervals.mean_ci`; ``low``/``high``
    None with fewer than 3 values: no interval) and the values, for the JSON."""
    estimate = mean_ci(values, scale=scale)
    return {**estimate.as_dict(), "values": list(estimate.values)}


def _ci_text(check: dict, key: str) -> str:
    """A closed-loop figure as ``mean [low, high]``, its interval computed from its values on its scale (so a
    result file written before the intervals respected their quantity renders the same way), or ``mean (n=2, no
    interval)``."""
    estimate = mean_ci(check[key]["values"], scale=_scale(key))
    return interval_text(estimate.mean, estimate.low, estimate.high, estimate.n, lambda value: f"{value:.5f}",
                         short=True)


def _within(check: dict) -> bool:
    """Whether the int8 form's mean MAE lies within the exact fused form's CI (from the values, as :func:`_ci_text`)."""
    return mean_within_ci(check["fused_int8_mae"]["values"], check["fused_mae"]["values"])


def format_report(result: dict) -> str:
    conditions = result["conditions"]
    lines = [
        f"{conditions['device']}, {conditions['threads']} torch thread(s), load average "
        f"{conditions['load_average_1min']:.2f} on {conditions['cpus']} CPUs; {conditions['weights']} weights; "
        f"{conditions['frames']} timed frames per side and repeat after {conditions['warmup_frames']} warm-up, "
        f"{conditions['repeats']} repeats (medians)",
    ]
    target = result["target_overhead_ratio"]

    def verdict(ratio: float) -> str:
        return "meets" if ratio <= target else "MISSES"

    for preset, figures in result["presets"].items():
        height, width = figures["image_size_px"]
        has_int8 = "int8_overhead_ratio" in figures

        def per_repeat(key: str, figures=figures) -> str:
            return ", ".join(f"{r[key]:.3f}" for r in figures["repeats"])

        int8_ms = f"| PLM-Net int8 TAPM {figures['plm_int8_ms_median']:.3f} " if has_int8 else ""
        lines += [
            "",
            f"preset {preset} ({height}x{width} px): BM {figures['bm_params']:,} parameters, TAPM "
            f"{figures['tapm_trainable_params']:,} trainable + the frozen BM; nonzero image features "
            f"{figures['image_features_nonzero_fraction']:.1%}",
            f"  batch 1, median ms:  BM {figures['bm_ms_median']:.3f} | PLM-Net {figures['plm_ms_median']:.3f} "
            f"{int8_ms}| PLM-Net reference forward {figures['plm_reference_ms_median']:.3f}",
            f"  overhead PLM-Net (exact, fp32) / BM: {figures['overhead_ratio']:.3f} (repeats "
            f"{per_repeat('overhead_ratio')}; CPU time {figures['overhead_ratio_cpu']:.3f}); "
            f"{verdict(figures['overhead_ratio'])} the target <= {target}",
        ]
        if has_int8:
            lines.append(
                f"  overhead PLM-Net (int8 TAPM) / BM: {figures['int8_overhead_ratio']:.3f} (repeats "
                f"{per_repeat('int8_overhead_ratio')}; CPU time {figures['int8_overhead_ratio_cpu']:.3f}); "
                f"{verdict(figures['int8_overhead_ratio'])} the target <= {target}"
            )
        if "overhead_ratio_vs_sparse_bm" in figures:
            lines.append(
                f"  a BM with a sparse first layer (zero features skipped, as PLM-Net's image branch): "
                f"{figures['bm_sparse_ms_median']:.3f} ms; PLM-Net over it {figures['overhead_ratio_vs_sparse_bm']:.3f} "
                f"(CPU time {figures['overhead_ratio_vs_sparse_bm_cpu']:.3f})"
            )
        int8_difference = (f", int8 {figures['max_abs_difference_int8_vs_reference']:.2e}" if has_int8 else "")
        lines += [
            f"  before (reference forward) / BM: {figures['reference_overhead_ratio']:.3f} (CPU time "
            f"{figures['reference_overhead_ratio_cpu']:.3f}); steering max |difference| from the reference: "
            f"exact {figures['max_abs_difference_fused_vs_reference']:.2e}{int8_difference}",
        ]
        throughput = figures["throughput_samples_per_s"]
        lines.append("  batched throughput, samples/s: " + "; ".join(
            f"batch {b}: BM {throughput['bm'][b]:,.0f}, PLM-Net {throughput['plm'][b]:,.0f}" for b in throughput["bm"]
        ))
        training = figures["training_samples_per_s"]
        lines.append(f"  training, samples/s: BM {training['bm']:,.0f}, TAPM (frozen BM) {training['tapm']:,.0f}")
    lines += ["", *format_summary(result)]
    for check in result.get("closed_loop", {}).values():

        def ci(key: str, check=check) -> str:
            return _ci_text(check, key)

        within = "within" if _within(check) else "OUTSIDE"
        lines += [
            "",
            f"closed loop ({check['checkpoints']} checkpoints, {check['conditions']} conditions, track "
            f"{check['track']}, {check['latency']}, seeds {check['seeds'][0]}-{check['seeds'][-1]}, "
            f"{check['max_steps'] or 'all'} steps), PLM-Net steering MAE vs the reference run "
            f"(mean [95% CI] over the seeds; MAEs on the log scale, paired differences symmetric):",
            f"  reference forward {ci('reference_forward_mae')} | exact fused (before) "
            f"{ci('fused_mae')} | int8 TAPM (after) {ci('fused_int8_mae')}",
            f"  paired: exact fused - reference forward {ci('fused_minus_reference_mae')}; int8 - exact "
            f"{ci('int8_minus_fused_mae')}; the int8 mean is {within} the exact form's CI",
            f"  largest step difference from the reference forward: exact "
            f"{check['max_abs_steering_difference']:.2e}, int8 {check['max_abs_steering_difference_int8']:.2e}",
        ]
    return "\n".join(lines)


def format_summary(result: dict) -> list[str]:
    """The ratio table of both presets beside the paper's figures (what the README shows of a result)."""
    conditions, paper, target = result["conditions"], result["paper"], result["target_overhead_ratio"]

    def verdict(ratio: float) -> str:
        return "meets" if ratio <= target else "MISSES"

    lines = [
        f"PLM-Net / BM at batch size 1 on {conditions['device']}, {conditions['weights']} weights, median over "
        f"{conditions['repeats']} repeats (wall time; CPU time in brackets), target <= {target}:",
        f"  {'preset':8s} {'BM ms':>8s} {'PLM-Net ms':>10s}  {'exact (fp32)':>22s}  {'int8 TAPM':>22s}  "
        f"{'reference forward':>17s}",
    ]
    for preset, figures in result["presets"].items():
        exact = figures["overhead_ratio"]
        exact_cell = f"{exact:.3f} ({figures['overhead_ratio_cpu']:.3f}) {verdict(exact)}"
        int8_cell = "n/a"
        if "int8_overhead_ratio" in figures:
            int8 = figures["int8_overhead_ratio"]
            int8_cell = f"{int8:.3f} ({figures['int8_overhead_ratio_cpu']:.3f}) {verdict(int8)}"
        lines.append(
            f"  {preset:8s} {figures['bm_ms_median']:8.3f} {figures['plm_ms_median']:10.3f}  {exact_cell:>22s}  "
            f"{int8_cell:>22s}  {figures['reference_overhead_ratio']:17.3f}"
        )
    lines.append(
        f"  the paper's, 160x160 px: BM {paper['bm_ms']:.3f} ms, PLM-Net {paper['plm_net_ms']:.3f} ms, ratio "
        f"{paper['plm_net_ms'] / paper['bm_ms']:.3f} (means over ~680 frames at batch size 1 on "
        f"{paper['device']}; its {paper['source']})"
    )
    for preset, figures in result["presets"].items():
        throughput, training = figures["throughput_samples_per_s"], figures["training_samples_per_s"]
        repeats = ", ".join(f"{r['overhead_ratio']:.3f}" for r in figures["repeats"])
        lines.append(
            f"  {preset}: repeats {repeats}; samples/s at batch " + ", ".join(throughput["bm"]) + ": BM "
            + " / ".join(f"{v:,.0f}" for v in throughput["bm"].values()) + ", PLM-Net "
            + " / ".join(f"{v:,.0f}" for v in throughput["plm"].values())
            + f"; training BM {training['bm']:,.0f}, TAPM {training['tapm']:,.0f}"
        )
    return lines



def format_runs(results: list[dict]) -> list[str]:
    """Several ``bench models`` runs side by side and the median of their ratios (the target is judged on the
    median of runs; each run's ratio is itself the median of its repeats). What the README shows, rendered
    from the committed result files."""
    target = results[0]["target_overhead_ratio"]
    presets = list(results[0]["presets"])
    lines = []
    for index, result in enumerate(results, start=1):
        conditions = result["conditions"]
        lines.append(f"measurement {index}: $ {result.get('command', 'plm-highway bench models')}")
        lines.append(f"  {conditions['device']}, {conditions['threads']} torch thread(s), {conditions['weights']} "
                     f"weights, load average {conditions['load_average_1min']:.1f} on {conditions['cpus']} CPUs, "
                     f"{conditions['repeats']} repeats of {conditions['frames']} frames per side")
        for preset in presets:
            figures = result["presets"][preset]
            repeats = ", ".join(f"{r['overhead_ratio']:.3f}" for r in figures["repeats"])
            throughput, training = figures["throughput_samples_per_s"], figures["training_samples_per_s"]
            lines.append(
                f"  {preset:8s} BM {figures['bm_ms_median']:6.3f} ms, PLM-Net {figures['plm_ms_median']:6.3f} ms: "
                f"{figures['overhead_ratio']:.3f} (repeats {repeats}; CPU time {figures['overhead_ratio_cpu']:.3f}); "
                f"reference forward {figures['reference_overhead_ratio']:.3f}; nonzero image features "
                f"{figures['image_features_nonzero_fraction']:.1%}"
            )
            if "overhead_ratio_vs_sparse_bm" in figures:
                lines.append(
                    f"  {'':8s} a BM with a sparse first layer: {figures['bm_sparse_ms_median']:6.3f} ms; PLM-Net "
                    f"over it {figures['overhead_ratio_vs_sparse_bm']:.3f} (CPU time "
                    f"{figures['overhead_ratio_vs_sparse_bm_cpu']:.3f})"
                )
            lines.append(
                f"  {'':8s} samples/s at batch " + ", ".join(throughput["bm"]) + ": BM "
                + " / ".join(f"{v:,.0f}" for v in throughput["bm"].values()) + ", PLM-Net "
                + " / ".join(f"{v:,.0f}" for v in throughput["plm"].values())
                + f"; training BM {training['bm']:,.0f}, TAPM {training['tapm']:,.0f}"
            )
    def median(preset: str, key: str) -> float:
        return float(np.median([r["presets"][preset][key] for r in results]))

    lines.append(f"PLM-Net / BM at batch size 1, median of {len(results)} runs (target <= {target}): " + ", ".join(
        f"{preset} {median(preset, 'overhead_ratio'):.3f} "
        f"{'meets' if median(preset, 'overhead_ratio') <= target else 'MISSES'} "
        f"(CPU time {median(preset, 'overhead_ratio_cpu'):.3f})" for preset in presets))
    paper = results[0]["paper"]
    lines.append(f"the paper's, 160x160 px: BM {paper['bm_ms']:.3f} ms, PLM-Net {paper['plm_net_ms']:.3f} ms, ratio "
                 f"{paper['plm_net_ms'] / paper['bm_ms']:.3f} ({paper['device']}; its {paper['source']})")
    return lines


def format_closed_loop_table(result: dict) -> list[str]:
    """The ``--closed-loop`` check of a result as a markdown table (what the README shows of it)."""

    lines = ["| preset | reference forward | exact fused | int8 TAPM | int8 - exact, paired | within the CI? |",
             "|---|---|---|---|---|---|"]
    for preset, check in result["closed_loop"].items():
        lines.append(
            f"| {preset} ({check['conditions']}) | {_ci_text(check, 'reference_forward_mae')} | "
            f"{_ci_text(check, 'fused_mae')} | {_ci_text(check, 'fused_int8_mae')} | "
            f"{_ci_text(check, 'int8_minus_fused_mae')} | {'yes' if _within(check) else 'no'} |"
        )
    return lines
