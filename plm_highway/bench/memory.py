"""``plm-highway bench memory``: the resident memory of a long run of the env with the latency wrapper.

The expert drives the test track through :class:`~plm_highway.latency.LatencyWrapper` for a given
number of policy steps (200,000 by default, about three hours of driving at 20 Hz), resetting when
an episode ends. The resident set size (RSS, from ``/proc/self/status``) is read after a warm-up
(first episodes: imports, caches and the road drawing settle) and then every ``sample_every`` steps.

A run is **flat** when the RSS at the end exceeds the RSS after warm-up by at most
:data:`FLAT_MARGIN_MIB`: a leak of one small observation (200x66 bytes, 13 kB) per step would add
2.5 GiB over 200,000 steps, one float per step 1.5 MiB; the margin leaves room for the allocator's
arenas and Python's free lists, which grow in steps, not per step.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium
import numpy as np

from plm_highway.errors import BadInput
from plm_highway.latency import LatencyWrapper
from plm_highway.latency.profiles import check_specs

DEFAULT_STEPS = 200_000
DEFAULT_WARMUP_STEPS = 2_000
MIN_STEPS = 1_000
MAX_STEPS = 10_000_000
FLAT_MARGIN_MIB = 16.0


def rss_mib() -> float:
    """This process's resident set size [MiB] (Linux ``VmRSS``; the peak elsewhere)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


@dataclass(frozen=True)
class MemoryRun:
    steps: int
    warmup_steps: int
    latency: str
    track: str
    episodes: int
    wall_s: float
    rss_start_mib: float  # before the env exists
    rss_after_warmup_mib: float
    rss_end_mib: float
    rss_peak_mib: float
    samples: list[tuple[int, float]] = field(default_factory=list)  # (step, RSS MiB) after warm-up

    @property
    def growth_mib(self) -> float:
        return self.rss_end_mib - self.rss_after_warmup_mib

    @property
    def slope_mib_per_100k_steps(self) -> float:
        """Least-squares slope of RSS over the samples, per 100,000 steps (0 with fewer than 2 samples)."""
        if len(self.samples) < 2:
            return 0.0
        steps, rss = np.array(self.samples, dtype=float).T
        return float(np.polyfit(steps, rss, 1)[0] * 100_000)

    @property
    def flat(self) -> bool:
        return self.growth_mib <= FLAT_MARGIN_MIB

    def as_dict(self) -> dict:
        return {"steps": self.steps, "warmup_steps": self.warmup_steps, "latency": self.latency,
                "track": self.track, "episodes": self.episodes, "wall_s": self.wall_s,
                "rss_start_mib": self.rss_start_mib, "rss_after_warmup_mib": self.rss_after_warmup_mib,
                "rss_end_mib": self.rss_end_mib, "rss_peak_mib": self.rss_peak_mib,
                "growth_mib": self.growth_mib, "slope_mib_per_100k_steps": self.slope_mib_per_100k_steps,
                "flat_margin_mib": FLAT_MARGIN_MIB, "flat": self.flat,
                "samples": [list(sample) for sample in self.samples]}


def memory_run(steps: int = DEFAULT_STEPS, latency: str = "steps:0.0-0.35:1.0", track: str = "test",
               warmup_steps: int = DEFAULT_WARMUP_STEPS, sample_every: int = 10_000, seed: int = 0,
               progress: Callable[[int], None] | None = None) -> MemoryRun:
    """Drive ``steps`` policy steps after ``warmup_steps``, recording RSS; see the module docstring."""
    if not MIN_STEPS <= steps <= MAX_STEPS:
        raise BadInput(f"--steps {steps}: outside the accepted range [{MIN_STEPS:,}, {MAX_STEPS:,}]")
    if not 0 <= warmup_steps <= MAX_STEPS or not 1 <= sample_every <= steps:
        raise BadInput(f"--warmup-steps {warmup_steps} / --sample-every {sample_every}: warm-up in [0, "
                       f"{MAX_STEPS:,}], sampling interval in [1, --steps]")
    check_specs([latency])  # refused before the env is built
    rss_start = rss_mib()
    env, policy = _expert_on_wrapped_env(track, latency)
    try:
        state = {"obs_info": env.reset(seed=seed), "episodes": 1}

        def drive(count: int) -> None:
            obs, info = state["obs_info"]
            for _ in range(count):
                obs, _, terminated, truncated, info = env.step(policy(obs, info))
                if terminated or truncated:
                    obs, info = env.reset()
                    state["episodes"] += 1
            state["obs_info"] = (obs, info)

        drive(warmup_steps)
        rss_warm = rss_mib()
        samples, peak, done = [(0, rss_warm)], rss_warm, 0
        started = time.perf_counter()
        while done < steps:
            chunk = min(sample_every, steps - done)
            drive(chunk)
            done += chunk
            samples.append((done, rss_mib()))
            peak = max(peak, samples[-1][1])
            if progress is not None:
                progress(chunk)
        wall_s = time.perf_counter() - started
    finally:
        env.close()
    return MemoryRun(steps, warmup_steps, env.profile.spec or str(latency), track, state["episodes"], wall_s,
                     rss_start, rss_warm, samples[-1][1], peak, samples)


def _expert_on_wrapped_env(track: str, latency: str):
    from plm_highway.expert import ExpertPolicy  # lazy: highway_env, and `bench memory --help` imports this module

    env = LatencyWrapper(gymnasium.make("plm_highway/LaneKeeping-v0", config={"track": track}), latency)
    expert = ExpertPolicy()
    return env, lambda obs, info: np.array([expert(obs, info)], dtype=np.float32)


def memory_lines(run: MemoryRun) -> list[str]:
    verdict = "flat" if run.flat else "GROWING"
    return [
        f"env + camera + LatencyWrapper({run.latency}) on track {run.track}, expert policy: {run.steps:,} policy "
        f"steps after {run.warmup_steps:,} warm-up steps, {run.episodes} episodes, {run.wall_s:.0f} s "
        f"({run.steps / max(run.wall_s, 1e-9):.0f} steps/s)",
        f"RSS before the env          : {run.rss_start_mib:8.1f} MiB",
        f"RSS after warm-up (start)   : {run.rss_after_warmup_mib:8.1f} MiB",
        f"RSS at the end              : {run.rss_end_mib:8.1f} MiB",
        f"RSS peak                    : {run.rss_peak_mib:8.1f} MiB",
        f"growth start -> end         : {run.growth_mib:+8.1f} MiB (margin {FLAT_MARGIN_MIB:g} MiB: {verdict})",
        f"slope                       : {run.slope_mib_per_100k_steps:+8.2f} MiB per 100k steps",
        f"ratio end / start           : {run.rss_end_mib / run.rss_after_warmup_mib:8.3f}",
    ]
