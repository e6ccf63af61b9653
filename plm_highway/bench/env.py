"""``plm-highway bench env``: our env + camera + latency wrapper against highway-env's own camera.

Both sides step at one simulation step per policy step (20 Hz), observe a 200x66 grayscale image
and reset when an episode ends; resets count in the time. Our side also pays for its expert
policy; the reference side steers straight. The median of several repeats is reported.
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from plm_highway.bench import BENCH_RESULT
from plm_highway.io import write_json


def configure(parser) -> None:
    parser.add_argument("--steps", type=int, default=2000, help="policy steps per repeat and side")
    parser.add_argument("--repeats", type=int, default=3, help="repeats per side; the median is reported")
    parser.add_argument("--latency", default="const:0.2", help="latency profile of our side")
    parser.add_argument("--json", help="also write the figures to this JSON file")


def racetrack_steps_per_s(steps: int) -> float:
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")  # 'dummy' renders blank frames
    import gymnasium
    import highway_env  # noqa: F401  (registers racetrack-large-v0)

    config = {
        "observation": {"type": "GrayscaleObservation", "observation_shape": (200, 66), "stack_size": 1,
                        "weights": [0.2989, 0.5870, 0.1140]},
        "simulation_frequency": 20, "policy_frequency": 20, "other_vehicles": 0,
    }
    env = gymnasium.make("racetrack-large-v0", config=config)
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    return _time_steps(env, lambda obs, info: action, steps)


def ours_steps_per_s(steps: int, latency: str) -> float:
    import gymnasium

    import plm_highway  # noqa: F401
    from plm_highway.expert import ExpertPolicy
    from plm_highway.latency import LatencyWrapper

    env = LatencyWrapper(gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": "test"}), latency)
    env.reset(seed=0)
    expert = ExpertPolicy()
    return _time_steps(env, lambda obs, info: np.array([expert(obs, info)], dtype=np.float32), steps)


def _time_steps(env, policy, steps: int) -> float:
    obs, info = env.reset(seed=0)
    start = time.perf_counter()
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(policy(obs, info))
        if terminated or truncated:
            obs, info = env.reset()
    return steps / (time.perf_counter() - start)


def run(args) -> int:
    if args.steps < 10 or args.repeats < 1:
        raise ValueError("--steps must be >= 10 and --repeats >= 1")
    reference, ours = [], []
    for repeat in range(args.repeats):
        reference.append(racetrack_steps_per_s(args.steps))
        ours.append(ours_steps_per_s(args.steps, args.latency))
        print(f"repeat {repeat + 1}/{args.repeats}: racetrack-large-v0 {reference[-1]:.0f} steps/s, "
              f"plm_highway {ours[-1]:.0f} steps/s", flush=True)
    result = {
        "racetrack_large_grayscale_steps_per_s": statistics.median(reference),
        "plm_highway_camera_latency_steps_per_s": statistics.median(ours),
        "steps": args.steps, "repeats": args.repeats, "latency": args.latency,
    }
    result["ratio"] = result["plm_highway_camera_latency_steps_per_s"] / result["racetrack_large_grayscale_steps_per_s"]
    print(f"racetrack-large-v0 + GrayscaleObservation 200x66 : {result['racetrack_large_grayscale_steps_per_s']:8.0f} steps/s")
    print(f"plm_highway LaneKeeping-v0 + camera + latency    : {result['plm_highway_camera_latency_steps_per_s']:8.0f} steps/s")
    print(f"ratio                                            : {result['ratio']:8.1f}x")
    if args.json:
        write_json(args.json, result, BENCH_RESULT, overwrite=args.overwrite)
    return 0
