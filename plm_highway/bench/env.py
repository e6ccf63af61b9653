"""``plm-highway bench env``: our env's speed beside highway-env's own camera envs and beside its limit.

Sides, stepped in turn within each repeat (so a loaded machine slows them alike), each with the
same policy and rates: one simulation step per policy step at 20 Hz, a 200x66 grayscale image, and
the same fixed steering sequence (the expert's actions of one episode on our test track, replayed by
step index: the policy costs nothing and is identical everywhere).

- ``lane-keeping-v0`` + ``GrayscaleObservation`` 200x66: highway-env's own lane-keeping task,
  its fastest comparable camera configuration (the headline ratio). Its 200-step time limit is
  lifted, so like ours it runs long episodes.
- ``racetrack-large-v0`` + ``GrayscaleObservation`` 200x66, no other vehicles (kept for
  continuity with earlier figures; its large map is redrawn by pygame every frame).
- ours: ``plm_highway/LaneKeeping-v0`` on the test track, without and with the latency wrapper.
- the limit: ``cv2.warpPerspective`` alone over the same poses at the configured map resolution,
  with the homographies precomputed; once for the rows the camera warps (ground rows) and once for
  the whole frame (the earlier definition of the limit).

Times are CPU seconds of this process (``time.process_time``, all threads), so other work on a
shared machine slows the figures less than wall time would; caches are still shared, so report
the machine's load with them. Resets count in the time (ours: one per 1,371 steps at the end of
the test track). The median of the repeats is reported, with min and max. Memory over a long run is
``plm-highway bench memory`` (:mod:`plm_highway.bench.memory`).
"""

from __future__ import annotations

import os
import statistics
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass

import gymnasium
import numpy as np

from plm_highway.errors import BadInput
from plm_highway.latency import LatencyWrapper

GRAYSCALE_200X66 = {"type": "GrayscaleObservation", "observation_shape": (200, 66), "stack_size": 1,
                    "weights": [0.2989, 0.5870, 0.1140]}
RATES_20HZ = {"simulation_frequency": 20, "policy_frequency": 20}
# CPU time of this process (all its threads): on a machine shared with other work, wall time mostly
# measures the wait for a core.
CLOCK = time.process_time


@dataclass(frozen=True)
class EnvBenchConfig:
    steps: int = 2000  # policy steps per repeat and side
    repeats: int = 3
    latency: str = "const:0.2"  # the wrapper's profile on the "with latency" side
    track: str = "test"

    def __post_init__(self):
        if not 10 <= self.steps <= 10_000_000:
            raise BadInput(f"--steps {self.steps}: must be from 10 to 10,000,000")
        if not 1 <= self.repeats <= 100:
            raise BadInput(f"--repeats {self.repeats}: must be from 1 to 100")






# -- the sides ----------------------------------------------------------------------------------------


def replay_actions(track: str = "test") -> np.ndarray:
    """The expert's actions over one episode of our env: the policy every side replays."""
    from plm_highway.expert import ExpertPolicy  # lazy: highway_env, and `bench env --help` imports this module

    env = gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": track})
    expert = ExpertPolicy()
    obs, info = env.reset(seed=0)
    actions = []
    while True:
        actions.append(expert(obs, info))
        obs, _, terminated, truncated, info = env.step(np.array([actions[-1]], dtype=np.float32))
        if terminated or truncated:
            env.close()
            return np.array(actions, dtype=np.float32).reshape(-1, 1)


def highway_env_side(env_id: str, config: dict, max_episode_steps: int | None = None):
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")  # 'dummy' renders blank frames
    import highway_env  # noqa: F401  (registers its envs; lazy: `bench env --help` imports this module)

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*out of date.*")  # racetrack-large-v0 is kept on purpose
        return gymnasium.make(env_id, config={"observation": GRAYSCALE_200X66, **RATES_20HZ, **config},
                              max_episode_steps=max_episode_steps)


def ours_side(track: str, latency: str | None):
    env = gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": track, **RATES_20HZ})
    return env if latency is None else LatencyWrapper(env, latency)


def time_env_steps(env, actions: np.ndarray, steps: int) -> float:
    """Steps per CPU second of ``env.step`` replaying ``actions`` by step index within each episode."""
    env.reset(seed=0)
    step_in_episode = 0
    n_actions = len(actions)
    start = CLOCK()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(actions[step_in_episode % n_actions])
        step_in_episode += 1
        if terminated or truncated:
            env.reset()
            step_in_episode = 0
    return steps / (CLOCK() - start)


def warp_limit_sides(track: str, actions: np.ndarray) -> dict[str, Callable[[int], float]]:
    """Timers of the warp alone over the poses of the replayed episode (homographies precomputed)."""
    import cv2  # lazy, as highway_env above: `bench env --help` imports this module

    from plm_highway.camera.pinhole import pose_matrix

    env = gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": track, **RATES_20HZ})
    env.reset(seed=0)
    camera = env.unwrapped.camera
    poses = []
    for action in actions:
        _, _, terminated, truncated, info = env.step(action)
        poses.append((info["x_m"], info["y_m"], info["heading_rad"]))
        if terminated or truncated:
            break
    env.close()
    image = camera.ground.image
    config = camera.config
    first = camera._first_ground_row
    ground_rows = [camera.homography(*pose) for pose in poses]
    whole = [camera.ground.world_to_pixel @ pose_matrix(*pose) @ camera._image_to_ground for pose in poses]
    flags, border = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, cv2.BORDER_REPLICATE
    frame = np.empty((config.height_px, config.width_px), np.uint8)

    def timer(homographies, size, dst) -> Callable[[int], float]:
        def steps_per_s(steps: int) -> float:
            start = CLOCK()
            for i in range(steps):
                cv2.warpPerspective(image, homographies[i % len(homographies)], size, dst=dst, flags=flags,
                                    borderMode=border)
            return steps / (CLOCK() - start)
        return steps_per_s

    return {
        "limit_warp_ground_rows": timer(ground_rows, camera._ground_size, frame[first:]),
        "limit_warp_whole_frame": timer(whole, camera._size, frame),
    }


SIDE_LABELS = {
    "lane_keeping_v0": "highway-env lane-keeping-v0 + Grayscale 200x66",
    "racetrack_large_v0": "highway-env racetrack-large-v0 + Grayscale 200x66",
    "ours": "plm_highway LaneKeeping-v0 (camera 200x66)",
    "ours_latency": "plm_highway LaneKeeping-v0 + LatencyWrapper",
    "limit_warp_ground_rows": "limit: warpPerspective alone, ground rows",
    "limit_warp_whole_frame": "limit: warpPerspective alone, whole frame",
}


def bench_env(config: EnvBenchConfig, progress: bool = True) -> dict:
    """Steps per second of every side, ``config.repeats`` times in turn; medians, min, max, ratios."""
    actions = replay_actions(config.track)
    envs = {
        "lane_keeping_v0": highway_env_side("lane-keeping-v0", {}, max_episode_steps=10**9),
        "racetrack_large_v0": highway_env_side("racetrack-large-v0", {"other_vehicles": 0}),
        "ours": ours_side(config.track, None),
        "ours_latency": ours_side(config.track, config.latency),
    }
    timers: dict[str, Callable[[int], float]] = {
        name: (lambda steps, env=env: time_env_steps(env, actions, steps)) for name, env in envs.items()
    }
    timers.update(warp_limit_sides(config.track, actions))
    load_before = os.getloadavg()
    samples: dict[str, list[float]] = {name: [] for name in timers}
    for repeat in range(config.repeats):
        for name, timer in timers.items():
            samples[name].append(timer(config.steps))
        if progress:
            print(f"repeat {repeat + 1}/{config.repeats}: "
                  + ", ".join(f"{name} {values[-1]:.0f}" for name, values in samples.items()), file=sys.stderr)
    for env in envs.values():
        env.close()
    median = {name: statistics.median(values) for name, values in samples.items()}
    ratios = {
        "ours_over_lane_keeping_v0": median["ours"] / median["lane_keeping_v0"],
        "ours_latency_over_lane_keeping_v0": median["ours_latency"] / median["lane_keeping_v0"],
        "ours_over_racetrack_large_v0": median["ours"] / median["racetrack_large_v0"],
        "ours_latency_over_racetrack_large_v0": median["ours_latency"] / median["racetrack_large_v0"],
        "ours_over_limit_ground_rows": median["ours"] / median["limit_warp_ground_rows"],
        "ours_latency_over_limit_ground_rows": median["ours_latency"] / median["limit_warp_ground_rows"],
        "ours_over_limit_whole_frame": median["ours"] / median["limit_warp_whole_frame"],
    }
    return {
        "config": asdict(config), "steps_per_s_median": median, "steps_per_s_samples": samples,
        "ratios": ratios, "load_average_1min": [load_before[0], os.getloadavg()[0]], "cpu_count": os.cpu_count(),
    }


def format_bench(result: dict) -> str:
    config, median, samples, ratios = result["config"], result["steps_per_s_median"], \
        result["steps_per_s_samples"], result["ratios"]
    lines = [f"{config['steps']} policy steps x {config['repeats']} repeats per side, 20 Hz, same replayed "
             f"steering on every side, steps per CPU second; load average {result['load_average_1min'][0]:.1f} -> "
             f"{result['load_average_1min'][1]:.1f} on {result['cpu_count']} CPUs",
             f"{'side':52s} {'median':>9s} {'min':>9s} {'max':>9s}  steps/s"]
    for name, label in SIDE_LABELS.items():
        label = label + (f" ({config['latency']})" if name == "ours_latency" else "")
        lines.append(f"{label:52s} {median[name]:9.0f} {min(samples[name]):9.0f} {max(samples[name]):9.0f}")
    lines += [
        f"ours / lane-keeping-v0 (headline)       : {ratios['ours_over_lane_keeping_v0']:6.1f}x   "
        f"with latency wrapper {ratios['ours_latency_over_lane_keeping_v0']:6.1f}x",
        f"ours / racetrack-large-v0               : {ratios['ours_over_racetrack_large_v0']:6.1f}x   "
        f"with latency wrapper {ratios['ours_latency_over_racetrack_large_v0']:6.1f}x",
        f"ours / limit (ground-row warp)          : {100 * ratios['ours_over_limit_ground_rows']:5.0f}%    "
        f"with latency wrapper {100 * ratios['ours_latency_over_limit_ground_rows']:5.0f}%",
        f"ours / limit (whole-frame warp)         : {100 * ratios['ours_over_limit_whole_frame']:5.0f}%",
    ]
    return "\n".join(lines)
