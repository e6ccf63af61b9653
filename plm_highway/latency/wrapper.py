"""Make a lane-keeping env's observations late.

The env records a snapshot (camera frame + privileged state) after every simulation step.
This wrapper keeps them for ``max_latency_s`` and, at each policy step at time ``t``, delivers
the newest snapshot taken at or before ``t - latency(t)``. Its true age therefore lies in
``[latency, latency + one simulation step)`` at every step, also when the latency grows:
unlike a FIFO counted in frames (the original ROS implementation, which served fresher, even
zero-latency, frames while it refilled), history is looked up by time.

Right after reset there is no history older than the reset itself: until ``t >= latency``
the wrapper delivers the oldest snapshot (taken at reset) and reports its true, smaller age.
"""

from __future__ import annotations

import bisect
import copy
import math
from collections import deque

import gymnasium
import numpy as np

from plm_highway.latency.profiles import LatencyProfile, parse_profile

TIME_EPS_S = 1e-9  # snapshot times are multiples of the simulation step; absorb float error


class LatencyWrapper(gymnasium.Wrapper):
    """Deliver observations ``profile.latency_s(t)`` seconds old.

    ``info["latency_s"]`` is the requested latency, ``info["observation_age_s"]`` the true age of
    what was delivered and ``info["observed_state"]`` the privileged state of that same instant.
    Everything else in ``info`` describes the car now.
    """

    def __init__(self, env: gymnasium.Env, profile: LatencyProfile | str | float, max_latency_s: float = 1.0):
        super().__init__(env)
        # A private copy: two wrappers given one profile object must not share its random state.
        self.profile = copy.deepcopy(parse_profile(profile))
        self.max_latency_s = float(max_latency_s)
        if self.profile.max_latency_s > self.max_latency_s + TIME_EPS_S:
            raise ValueError(
                f"latency spec {self.profile.spec!r}: reaches {self.profile.max_latency_s} s, beyond the "
                f"buffer's maximum of {self.max_latency_s} s (raise max_latency_s)"
            )
        self._times_s: deque[float] = deque()
        self._snapshots: deque = deque()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        _, info = self.env.reset(seed=seed, options=options)
        # A child of the env's seed sequence: a given reset seed gives the same latency realisation
        # in every run, without drawing from (and so changing) the env's own random stream.
        seed_sequence = self.env.unwrapped.np_random.bit_generator.seed_seq.spawn(1)[0]
        self.profile.reset(np.random.default_rng(seed_sequence))
        self._times_s.clear()
        self._snapshots.clear()
        return self._delayed(info)

    def step(self, action):
        _, reward, terminated, truncated, info = self.env.step(action)
        obs, info = self._delayed(info)
        return obs, reward, terminated, truncated, info

    def _delayed(self, info: dict):
        for snapshot in self.env.unwrapped.new_snapshots:
            self._times_s.append(snapshot.time_s)
            self._snapshots.append(snapshot)
        now_s = self._times_s[-1]
        latency_s = float(self.profile.latency_s(now_s))
        if not (math.isfinite(latency_s) and 0.0 <= latency_s <= self.max_latency_s + TIME_EPS_S):
            raise ValueError(f"latency spec {self.profile.spec!r}: latency {latency_s!r} s at t={now_s} s is out of range")
        self._forget_before(now_s - self.max_latency_s - 2 * self.env.unwrapped.simulation_dt_s)
        index = bisect.bisect_right(self._times_s, now_s - latency_s + TIME_EPS_S) - 1
        snapshot = self._snapshots[max(index, 0)]
        info = dict(info)
        info["latency_s"] = latency_s
        info["observation_age_s"] = now_s - snapshot.time_s
        info["observed_state"] = snapshot.state
        return snapshot.frame, info

    def _forget_before(self, oldest_needed_s: float) -> None:
        # Keep one snapshot at or before the oldest time any allowed latency can ask for.
        while len(self._times_s) > 1 and self._times_s[1] <= oldest_needed_s:
            self._times_s.popleft()
            self._snapshots.popleft()
