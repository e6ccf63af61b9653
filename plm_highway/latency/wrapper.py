"""Make a lane-keeping env's observations late.

The env records a snapshot (camera frame + privileged state) after every simulation step. At each
policy step at time ``t`` the wrapper asks its profile for the latency and delivers an old
snapshot, chosen by one of two injections:

- ``"time"`` (default): the newest snapshot taken at or before ``t - latency(t)``. Its true age lies
  in ``[latency, latency + one simulation step)`` at every step, also when the latency grows.
  Right after reset there is no history older than the reset itself: until ``t >= latency`` the
  wrapper delivers the reset snapshot and reports its true, smaller age.
- ``"legacy-fifo"``: the original PLM-Net code's FIFO, counted in frames of the policy loop, kept
  to reproduce its experiments (see :class:`LegacyFifo`). Its age differs from the requested
  latency whenever the latency changes.

Every delivered frame is a fresh copy: the caller may keep or modify it without touching the
wrapper's history, and no array is delivered twice (gymnasium's ``check_env`` rule).
"""

from __future__ import annotations

import bisect
import copy
import math
from collections import deque

import gymnasium
import numpy as np

from plm_highway.errors import BadInput
from plm_highway.latency.profiles import MAX_LATENCY_S, LatencyProfile, parse_profile

TIME_EPS_S = 1e-9  # snapshot times are multiples of the simulation step; absorb float error
INJECTIONS = ("time", "legacy-fifo")


class TimeLookup:
    """History looked up by time: the newest snapshot at or before ``now - latency``."""

    def __init__(self, max_latency_s: float) -> None:
        self.max_latency_s = max_latency_s
        self.simulation_dt_s = 0.0
        self._times_s: deque[float] = deque()
        self._snapshots: deque = deque()

    def __len__(self) -> int:
        return len(self._snapshots)

    def reset(self, simulation_dt_s: float, policy_dt_s: float) -> None:
        self.simulation_dt_s = simulation_dt_s
        self._times_s.clear()
        self._snapshots.clear()

    def serve(self, new_snapshots, now_s: float, latency_s: float):
        for snapshot in new_snapshots:
            self._times_s.append(snapshot.time_s)
            self._snapshots.append(snapshot)
        self._forget_before(now_s - self.max_latency_s - 2 * self.simulation_dt_s)
        index = bisect.bisect_right(self._times_s, now_s - latency_s + TIME_EPS_S) - 1
        return self._snapshots[max(index, 0)]

    def _forget_before(self, oldest_needed_s: float) -> None:
        # Keep one snapshot at or before the oldest time any allowed latency can ask for.
        while len(self._times_s) > 1 and self._times_s[1] <= oldest_needed_s:
            self._times_s.popleft()
            self._snapshots.popleft()


def served_steps(latency_s: float, policy_dt_s: float) -> int:
    """How many policy steps old the frame served for ``latency_s`` is (both injections).

    The time look-up serves the newest frame at least ``latency_s`` old, ceil(latency / step) steps; the legacy FIFO
    counts its frames the same way.
    """
    return max(0, math.ceil(latency_s / policy_dt_s - 1e-6))


class LegacyFifo:
    """The original PLM-Net FIFO (ROS loop of ``run_neural..._delay_mitig_rand``), frame for frame.

    Once per loop iteration (here: per policy step) with requested delay ``delta`` frames:
    if ``delta > 0``, push the current frame; if the FIFO then holds more than ``delta + 1``, drop
    the oldest; if it holds more than ``delta``, serve (and remove) the oldest, otherwise serve the
    current frame. With ``delta == 0`` the FIFO is bypassed and left as it is.

    Consequences (what :mod:`tests.test_latency` checks): at a constant delta the age is ``delta``
    frames after a start-up of ``delta`` fresh frames; when delta grows from d1 to d2 the FIFO
    serves the *current* frame (age 0) for d2 - d1 iterations while it refills; when it shrinks,
    the age ramps down one frame per iteration (d1 - 1, d1 - 2, ..., d2). The FIFO never holds
    more than ``max delta`` frames.
    """

    def __init__(self) -> None:
        self.policy_dt_s = 0.0
        self._fifo: deque = deque()

    def __len__(self) -> int:
        return len(self._fifo)

    def reset(self, simulation_dt_s: float, policy_dt_s: float) -> None:
        self.policy_dt_s = policy_dt_s
        self._fifo.clear()

    def delta_frames(self, latency_s: float) -> int:
        return served_steps(latency_s, self.policy_dt_s)

    def serve(self, new_snapshots, now_s: float, latency_s: float):
        current = new_snapshots[-1]  # the loop saw one (the newest) frame per iteration
        delta = self.delta_frames(latency_s)
        if delta == 0:
            return current
        self._fifo.append(current)
        if len(self._fifo) > delta + 1:
            self._fifo.popleft()
        if len(self._fifo) > delta:
            return self._fifo.popleft()
        return current


class LatencyWrapper(gymnasium.Wrapper, gymnasium.utils.RecordConstructorArgs):
    """Deliver observations ``profile.latency_s(t)`` seconds old.

    ``info["latency_s"]`` is the requested latency, ``info["observation_age_s"]`` the true age of
    what was delivered and ``info["observed_state"]`` the privileged state of that same instant (a
    copy). Everything else in ``info`` describes the car now.

    ``injection`` is ``"time"`` (default: exact ages) or ``"legacy-fifo"`` (the original code's
    FIFO, whose ages differ from the requested latency while it changes).

    Like gymnasium's own wrappers it records its arguments in ``env.spec``, so ``env.spec.make()``
    rebuilds the same stack (a trace is read again from its path).
    """

    def __init__(self, env: gymnasium.Env, profile: LatencyProfile | str | float, max_latency_s: float = 1.0,
                 injection: str = "time"):
        parsed = parse_profile(profile)
        gymnasium.utils.RecordConstructorArgs.__init__(
            self, profile=profile if isinstance(profile, LatencyProfile) else parsed.spec,
            max_latency_s=max_latency_s, injection=injection)
        gymnasium.Wrapper.__init__(self, env)
        # A private copy: two wrappers given one profile object must not share its random state.
        self.profile = copy.deepcopy(parsed)
        max_latency_s = float(max_latency_s)
        if not (math.isfinite(max_latency_s) and 0.0 <= max_latency_s <= MAX_LATENCY_S):
            raise BadInput(f"max_latency_s {max_latency_s!r} is outside [0, {MAX_LATENCY_S:g}] s")
        self.max_latency_s = max_latency_s
        if self.profile.max_latency_s > self.max_latency_s + TIME_EPS_S:
            raise BadInput(
                f"latency spec {self.profile.spec!r}: reaches {self.profile.max_latency_s} s, beyond the "
                f"buffer's maximum of {self.max_latency_s} s (raise max_latency_s)"
            )
        if injection not in INJECTIONS:
            raise BadInput(f"injection {injection!r}: expected one of {', '.join(INJECTIONS)}")
        self.injection = injection
        self._history = TimeLookup(self.max_latency_s) if injection == "time" else LegacyFifo()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        _, info = self.env.reset(seed=seed, options=options)
        # A child of the env's seed sequence: a given reset seed gives the same latency realisation
        # in every run, without drawing from (and so changing) the env's own random stream.
        seed_sequence = self.env.unwrapped.np_random.bit_generator.seed_seq.spawn(1)[0]
        self.profile.reset(np.random.default_rng(seed_sequence))
        # Rates are read at every reset: reset(options={"config": ...}) may change them.
        base = self.env.unwrapped
        self._history.reset(base.simulation_dt_s, 1.0 / base.config["policy_frequency"])
        return self._delayed(info)

    def step(self, action):
        _, reward, terminated, truncated, info = self.env.step(action)
        obs, info = self._delayed(info)
        return obs, reward, terminated, truncated, info

    def _delayed(self, info: dict):
        new_snapshots = self.env.unwrapped.new_snapshots
        now_s = new_snapshots[-1].time_s
        latency_s = float(self.profile.latency_s(now_s))
        if not (math.isfinite(latency_s) and 0.0 <= latency_s <= self.max_latency_s + TIME_EPS_S):
            raise BadInput(f"latency spec {self.profile.spec!r}: latency {latency_s!r} s at t={now_s} s is out of range")
        snapshot = self._history.serve(new_snapshots, now_s, latency_s)
        info = dict(info)
        info["latency_s"] = latency_s
        info["observation_age_s"] = now_s - snapshot.time_s
        info["observed_state"] = dict(snapshot.state)
        # A copy, never the buffered frame: a caller writing into it must not change later steps.
        return snapshot.frame.copy(), info
