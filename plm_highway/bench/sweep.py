"""``plm-highway bench sweep``: N closed-loop runs one env at a time vs batched vs a process pool;
``plm-highway bench reproduce``: the reproduction's runs serial vs batched vs on a process pool.

``bench sweep`` drives the same N runs (seeds 0..N-1 of one latency profile on one track,
``--steps`` policy steps each, one model policy) several ways in one invocation and prints the
wall times side by side with their ratio to the *fastest* one-env side:

1. **one env at a time, default kernels, 1 thread**: :func:`~plm_highway.rollout.cells.run_cells` ``serial``
   (one :func:`~plm_highway.rollout.closed_loop.drive` per seed), the model with PyTorch's own kernel choice
   (batch 1), one torch thread;
2. the same on **2 torch threads** (the serial side's other configuration on 2 cores);
3. **one env at a time, batch-invariant kernels**: ``drive`` with the policy as the closed loop runs
   it (:mod:`plm_highway.models.batch_invariant`), the reference every other side is compared with;
4. **batched, own envs**: :func:`~plm_highway.rollout.cells.run_cells`, all N envs in one
   batch, one forward pass per step (PLM-Net: per latency segment), one thread;
5. **batched, 2 threads**: the same split over two Python threads, one batch each (one torch
   thread each; a forward pass releases the GIL, so one batch's envs step meanwhile);
6. **batched, gymnasium SyncVectorEnv** (``autoreset_mode=DISABLED``): the envs in gymnasium's
   vector API, one ``steer_batch`` per step;
7. **process pool, cold**: the N runs over ``--workers`` spawned processes, each batched; the time
   includes starting the processes and loading the model in each;
8. **process pool, warm**: the same on workers started and loaded before the clock, as the one-env
   sides load their model before it (a sweep or ``reproduce`` starts its pool once).

Every side is timed ``--repeats`` times, the sides interleaved; the medians are printed and the
speed-ups are ratios of medians (the one-env sides' times spread by up to 2x between runs on this
shared machine). Each side's largest |steering difference| against side 3 is printed (0: identical). The 1-minute
load average is printed: on a shared machine the absolute times mean little, compare the ratios.
"""

from __future__ import annotations

import contextlib
import os
import time
from functools import partial

import numpy as np
import torch
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from tqdm.auto import tqdm

from plm_highway.evaluation.reproduce import conditions_named, default_settings, plan_cells
from plm_highway.latency.profiles import check_specs
from plm_highway.road.track import load_track, resolve_track
from plm_highway.rollout.backends import LocalPool, worker_pool
from plm_highway.rollout.cells import RunCell, run_cells, runs_under, worker_policy
from plm_highway.rollout.closed_loop import LOG_COLUMNS, make_env
from plm_highway.rollout.policies import (
    SHIPPED_PRESET,
    VisionPolicy,
    make_policies,
    make_policy,
    single_threaded_inference,
)

SERIAL_SIDES = ("one env at a time, default kernels, 1 thread", "one env at a time, default kernels, 2 threads",
                "one env at a time, batch-invariant kernels")
REFERENCE_SIDE = SERIAL_SIDES[2]


def bench_sweep(n_envs: int = 16, steps: int = 100, policy: str = "plm", latency: str = "steps:0.0-0.35:1.0",
                track: str = "test", workers: int = 2, two_thread_serial: bool = True, repeats: int = 3) -> dict:
    """The sides of the module docstring, each timed ``repeats`` times (the sides interleaved, so that a
    slow spell of a shared machine hits every side alike); each side's median wall time is reported and
    the speed-ups are ratios of medians. ``two_thread_serial=False`` leaves out side 2 (on a loaded
    machine two torch threads at batch size 1 can take 20x longer than one)."""
    if not 1 <= repeats <= 100:
        raise ValueError(f"repeats {repeats}: must lie in [1, 100]")
    # the track read once and shared by every side's cells; a bad latency or track is refused before any model loads
    # or the pool starts (the latency is parsed where each run is made of it)
    track_spec = resolve_track(track)
    check_specs((latency,))
    load = os.getloadavg()[0]
    vision = make_policy(policy)
    default_kernels = make_policy(policy)
    default_kernels.model_policy.batch_invariant = False
    cells = [RunCell(f"seed {seed}", vision, track_spec, latency, seed, max_steps=steps) for seed in range(n_envs)]

    def serial(policy_object: VisionPolicy) -> np.ndarray:
        return _steering(run_cells([RunCell(c.name, policy_object, track_spec, latency, c.seed, max_steps=steps)
                                    for c in cells], serial=True))

    pool_side = f"process pool ({workers} workers, batched), cold"
    warm_side = f"process pool ({workers} workers, batched), warm"
    # (name, function, torch threads, inside single_threaded_inference)
    plan = [(SERIAL_SIDES[0], partial(serial, default_kernels), 1, True)]
    if two_thread_serial:
        plan.append((SERIAL_SIDES[1], partial(serial, default_kernels), 2, True))
    plan += [
        (REFERENCE_SIDE, partial(serial, vision), 1, True),
        ("batched, own envs", lambda: _steering(run_cells(cells, batch_size=n_envs)), 1, True),
        ("batched, 2 threads", lambda: _steering(run_cells(cells, batch_size=n_envs, threads=2)), 1, True),
        ("batched, gymnasium SyncVectorEnv", lambda: _vector_env_steering(vision, cells, steps), 1, True),
        (pool_side, lambda: _pool_steering(policy, track, latency, n_envs, steps, workers), 1, False),
    ]
    walls: dict[str, list[float]] = {name: [] for name, *_ in plan}
    walls[warm_side] = []
    steering: dict[str, np.ndarray] = {}

    def timed(name: str, function, threads: int) -> None:
        previous = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            start = time.perf_counter()
            result = function()
            walls[name].append(time.perf_counter() - start)
        finally:
            torch.set_num_threads(previous)
        if name in steering and not np.array_equal(steering[name], result):
            raise RuntimeError(f"bench sweep: side {name!r} steered differently in a repeat")
        steering[name] = result

    with _warm_pool(policy, track, latency, workers) as pool:
        with single_threaded_inference():
            run_cells([RunCell("warm-up", p, track, latency, 0, max_steps=3) for p in (vision, default_kernels)],
                      serial=True)
        for _ in tqdm(range(repeats), desc="bench sweep repeats", leave=False):
            for name, function, threads, single in plan:
                with single_threaded_inference() if single else contextlib.nullcontext():
                    timed(name, function, threads)
            timed(warm_side, lambda: _pool_steering(policy, track, latency, n_envs, steps, workers, pool), 1)
    sides = {name: {"wall_s": float(np.median(times)), "wall_s_repeats": times,
                    "torch_threads": 2 if name == SERIAL_SIDES[1] else 1} for name, times in walls.items()}
    reference = steering[REFERENCE_SIDE]
    best_serial_s = min(sides[name]["wall_s"] for name in SERIAL_SIDES if name in sides)
    for name, figures in sides.items():
        figures["speed_up"] = best_serial_s / figures["wall_s"]
        figures["policy_steps_per_s"] = n_envs * steps / figures["wall_s"]
        figures["max_steering_difference"] = float(np.max(np.abs(steering[name] - reference)))
    return {"envs": n_envs, "steps": steps, "policy": policy, "latency": latency, "track": track,
            "repeats": repeats, "load_average_1min": load, "load_average_1min_after": os.getloadavg()[0],
            "cpus": os.cpu_count(), "reference_side": REFERENCE_SIDE,
            "speed_up_relative_to": "the fastest one-env side (median wall times)", "sides": sides}


def _steering(logs) -> np.ndarray:
    return np.stack([log.columns["steering"] for log in logs])


def _vector_env_steering(vision, cells, steps: int) -> np.ndarray:
    """The runs through gymnasium's SyncVectorEnv; (N, steps) steering. Assumes no run ends early."""
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


def _pool_steering(policy: str, track: str, latency: str, n_envs: int, steps: int, workers: int,
                   pool=None) -> np.ndarray:
    """The runs split over ``workers`` processes, each chunk batched, (N, steps) steering; ``pool``: a warm
    executor to map on, else a fresh pool is started (and its start-up timed with the runs)."""
    cells = [RunCell(f"seed {seed}", policy, track, latency, seed, max_steps=steps) for seed in range(n_envs)]
    with LocalPool(workers, executor=pool) as backend:
        return _steering(run_cells(cells, backend=backend))


@contextlib.contextmanager
def _warm_pool(policy: str, track: str, latency: str, workers: int):
    """A pool of ``workers`` processes that have imported everything and loaded the model before the clock
    starts, as the one-env sides have: the setup a sweep pays once, not per run."""
    with worker_pool(workers) as pool:
        pids: set[int] = set()
        for _ in range(10):  # a task per idle worker until every worker has warmed up
            pids |= {future.result() for future in
                     [pool.submit(_warm_up, policy, track, latency) for _ in range(workers)]}
            if len(pids) >= workers:
                break
        yield pool


def _warm_up(policy: str, track: str, latency: str) -> int:
    """A worker: load the model the pooled runs use and drive a few steps (imports, caches); its pid."""
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

    vision = worker_policy(policy, None, SHIPPED_PRESET)
    with single_threaded_inference():
        run_cells([RunCell("warm-up", vision, track, latency, 0, max_steps=3)])
    time.sleep(0.5)  # hold this worker so that the other warm-up task goes to another
    return os.getpid()


def bench_reproduce(seeds: int = 5, max_steps: int | None = 100, workers: int = 2, track: str = "test",
                    conditions: str = "ideal", batch_size: int = 32) -> dict:
    """``reproduce``'s runs of one track (reference + BM and PLM-Net per default setting, per seed) three ways:
    serial (:func:`plm_highway.rollout.cells.run_cells` ``serial``, one env at a time), batched in this process
    (``--workers 0``), and batched on a pool of ``workers`` processes (started and loaded inside the
    time, as ``reproduce`` pays it). One torch thread per process. Identity: every logged column compared."""
    load = os.getloadavg()[0]
    run_conditions = conditions_named(conditions)
    track_spec = load_track(track)
    cells = plan_cells(list(default_settings(run_conditions)), list(range(seeds)), track_spec.name, run_conditions)
    policies = make_policies(None, run_conditions)
    preset = run_conditions.checkpoint_preset
    runs = runs_under(cells, track_spec, run_conditions, policies, max_steps)
    named_runs = runs_under(cells, track_spec, run_conditions, None, max_steps)  # what workers load themselves

    def parallel():
        with LocalPool(workers) as backend:
            return run_cells(named_runs, preset=preset, batch_size=batch_size, backend=backend)

    sides: dict[str, dict] = {}
    logs = {}
    with single_threaded_inference():
        for name, function in (
                ("serial (one env at a time)", lambda: run_cells(runs, serial=True)),
                ("batched (--workers 0)", lambda: run_cells(runs, preset=preset, batch_size=batch_size)),
                (f"parallel ({workers} workers, batched)", parallel)):
            start = time.perf_counter()
            logs[name] = function()
            sides[name] = {"wall_s": time.perf_counter() - start}
    serial_name = next(iter(sides))
    for name, figures in sides.items():
        figures["speed_up"] = sides[serial_name]["wall_s"] / figures["wall_s"]
        figures["identical_to_serial"] = all(
            np.array_equal(a.columns[c], b.columns[c]) for a, b in zip(logs[name], logs[serial_name])
            for c in LOG_COLUMNS)
    return {"runs": len(cells), "seeds": seeds, "max_steps": max_steps, "track": track, "conditions": conditions,
            "policy_steps": int(sum(log.steps for log in logs[serial_name])), "load_average_1min": load,
            "load_average_1min_after": os.getloadavg()[0], "cpus": os.cpu_count(), "sides": sides}


def report_lines(result: dict) -> list[str]:
    lines = [f"{result['envs']} runs x {result['steps']} steps, {result['policy']} on {result['track']}, latency "
             f"{result['latency']}; load average {result['load_average_1min']:.2f} "
             f"(after: {result.get('load_average_1min_after', float('nan')):.2f}) on {result['cpus']} CPUs "
             "(a shared, loaded machine: compare the ratios)",
             f"wall s: median of {result.get('repeats', 1)} timed repeats per side; speed-up: against the fastest "
             "one-env side; max |dsteer|: against "
             f"'{result.get('reference_side', 'one env at a time')}' (0 = identical)",
             f"{'side':48s} {'wall s':>8s} {'steps/s':>8s} {'speed-up':>9s} {'max |dsteer|':>13s}"]
    for name, figures in result["sides"].items():
        difference = figures.get("max_steering_difference")
        lines.append(f"{name:48s} {figures['wall_s']:8.2f} {figures['policy_steps_per_s']:8.1f} "
                     f"{figures['speed_up']:8.2f}x {'' if difference is None else f'{difference:13.2e}'}")
    return lines


def reproduce_report_lines(result: dict) -> list[str]:
    lines = [f"reproduce's runs on {result['track']} ({result['conditions']} conditions): {result['runs']} runs, "
             f"{result['seeds']} seeds, at most {result['max_steps']} steps each ({result['policy_steps']} policy "
             f"steps); load average {result['load_average_1min']:.2f} (after: {result['load_average_1min_after']:.2f})"
             f" on {result['cpus']} CPUs (a shared machine: compare the ratios)",
             f"{'side':36s} {'wall s':>8s} {'speed-up':>9s}  identical to serial"]
    for name, figures in result["sides"].items():
        lines.append(f"{name:36s} {figures['wall_s']:8.2f} {figures['speed_up']:8.2f}x  "
                     f"{'yes' if figures['identical_to_serial'] else 'NO'}")
    return lines
