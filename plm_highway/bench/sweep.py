"""``plm-highway bench sweep``: N closed-loop runs one env at a time vs batched vs a process pool.

The same N runs (seeds 0..N-1 of one latency profile on one track, ``--steps`` policy steps each,
one model policy) are driven five ways in one invocation, and the wall times printed side by side
with their ratio to the first:

1. **one env at a time**: :func:`~plm_highway.evaluation.closed_loop.drive` per seed (batch-1 forward);
2. **batched, own envs**: :func:`~plm_highway.evaluation.batched.run_cells`, all N envs in one
   batch, one forward pass per step;
3. **batched, gymnasium SyncVectorEnv** (``autoreset_mode=DISABLED``): the same envs in gymnasium's
   vector API, the same batched forward pass; its infos come stacked into arrays;
4. **batched, batch-invariant**: run_cells with ``batch_invariant=True`` (bit-identical to 1.);
5. **process pool**: the N runs split over ``--workers`` spawned processes, each batched; the time
   includes starting the processes and loading the model in each, as a sweep pays it.

Sides 1-4 share one loaded model and run on one torch thread; the largest steering difference of
2., 3. and 5. against 1. is printed. The 1-minute load average is printed: on a shared machine the
absolute times mean little; compare the ratios measured side by side.
"""

from __future__ import annotations

import os
import time

import numpy as np


def bench_sweep(n_envs: int = 16, steps: int = 100, policy: str = "plm", latency: str = "steps:0.0-0.35:1.0",
                track: str = "test", workers: int = 2) -> dict:
    from plm_highway.evaluation.batched import RunCell, run_cells
    from plm_highway.evaluation.closed_loop import drive
    from plm_highway.evaluation.policies import make_policy, single_threaded_inference
    from plm_highway.sweep.backends import LocalPool

    load = os.getloadavg()[0]
    vision = make_policy(policy)
    cells = [RunCell(f"seed {seed}", vision, track, latency, seed, max_steps=steps) for seed in range(n_envs)]
    sides: dict[str, dict] = {}
    with single_threaded_inference():
        drive("warm-up", vision, track, latency, 0, max_steps=3)

        start = time.perf_counter()
        serial = [drive(c.name, vision, track, latency, c.seed, max_steps=steps) for c in cells]
        sides["one env at a time"] = {"wall_s": time.perf_counter() - start}
        steering = np.stack([log.columns["steering"] for log in serial])

        start = time.perf_counter()
        batched = run_cells(cells, batch_size=n_envs)
        sides["batched, own envs"] = {"wall_s": time.perf_counter() - start,
                                      "max_steering_difference": _max_difference(batched, steering)}

        start = time.perf_counter()
        vector_steering = _vector_env_steering(vision, cells, steps)
        sides["batched, gymnasium SyncVectorEnv"] = {
            "wall_s": time.perf_counter() - start,
            "max_steering_difference": float(np.max(np.abs(vector_steering - steering)))}

        start = time.perf_counter()
        invariant = run_cells(cells, batch_size=n_envs, batch_invariant=True)
        sides["batched, batch-invariant"] = {"wall_s": time.perf_counter() - start,
                                             "max_steering_difference": _max_difference(invariant, steering)}
    chunks = [(policy, track, latency, tuple(range(n_envs))[w::workers], steps) for w in range(workers)]
    chunks = [chunk for chunk in chunks if chunk[3]]
    start = time.perf_counter()
    pooled = dict(LocalPool(len(chunks)).map_unordered(_pool_chunk, chunks))
    pool_steering = np.zeros_like(steering)
    for index, chunk in enumerate(chunks):
        pool_steering[list(chunk[3])] = pooled[index]
    sides[f"process pool ({len(chunks)} workers, batched)"] = {
        "wall_s": time.perf_counter() - start,
        "max_steering_difference": float(np.max(np.abs(pool_steering - steering)))}
    baseline = sides["one env at a time"]["wall_s"]
    for figures in sides.values():
        figures["speed_up"] = baseline / figures["wall_s"]
        figures["policy_steps_per_s"] = n_envs * steps / figures["wall_s"]
    return {"envs": n_envs, "steps": steps, "policy": policy, "latency": latency, "track": track,
            "load_average_1min": load, "cpus": os.cpu_count(), "sides": sides}


def _max_difference(logs, steering: np.ndarray) -> float:
    return float(np.max(np.abs(np.stack([log.columns["steering"] for log in logs]) - steering)))


def _vector_env_steering(vision, cells, steps: int) -> np.ndarray:
    """The runs through gymnasium's SyncVectorEnv; (N, steps) steering. Assumes no run ends early."""
    from functools import partial

    from gymnasium.vector import AutoresetMode, SyncVectorEnv

    from plm_highway.evaluation.closed_loop import make_env

    envs = SyncVectorEnv([partial(make_env, c.track, c.latency) for c in cells], autoreset_mode=AutoresetMode.DISABLED)
    obs, infos = envs.reset(seed=[c.seed for c in cells])
    model = vision.model_policy
    out = np.zeros((len(cells), steps))
    for k in range(steps):
        latencies_s = np.maximum(0.0, infos["observation_age_s"] + vision.latency_bias_s).astype(np.float32)
        out[:, k] = model.steer_batch(obs, infos["speed_mps"], latencies_s)
        obs, _, terminated, truncated, infos = envs.step(out[:, k, None].astype(np.float32))
        if k < steps - 1 and np.any(terminated | truncated):
            raise RuntimeError("bench sweep: a run ended before --steps; choose fewer steps")
    envs.close()
    return out


def _pool_chunk(chunk) -> np.ndarray:
    """A pool worker: the chunk's runs batched; (runs, steps) steering."""
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    from plm_highway.evaluation.batched import RunCell, run_cells
    from plm_highway.evaluation.policies import single_threaded_inference

    policy, track, latency, seeds, steps = chunk
    with single_threaded_inference():
        logs = run_cells([RunCell(f"seed {s}", policy, track, latency, s, max_steps=steps) for s in seeds])
    return np.stack([log.columns["steering"] for log in logs])


def report_lines(result: dict) -> list[str]:
    lines = [f"{result['envs']} runs x {result['steps']} steps, {result['policy']} on {result['track']}, latency "
             f"{result['latency']}; load average {result['load_average_1min']:.2f} on {result['cpus']} CPUs "
             "(a shared, loaded machine: compare the ratios)",
             f"{'side':44s} {'wall s':>8s} {'steps/s':>8s} {'speed-up':>9s} {'max |dsteer| vs 1':>18s}"]
    for name, figures in result["sides"].items():
        difference = figures.get("max_steering_difference")
        lines.append(f"{name:44s} {figures['wall_s']:8.2f} {figures['policy_steps_per_s']:8.1f} "
                     f"{figures['speed_up']:8.2f}x {'' if difference is None else f'{difference:18.2e}'}")
    return lines
