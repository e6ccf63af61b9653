"""Graded checks for Lesson 1, "Latency makes a lane keeper zig-zag".

Each check takes an optional ``seed``: without it, the cases worked out by hand below; with it
(nbgrader's hidden tests), further cases drawn from that seed and compared with a brute-force
reference, so that hard-coding the visible answers does not pass.
"""

from __future__ import annotations

import numpy as np

from plm_highway.expert import ExpertPolicy
from plm_highway.grading.checks import CheckFailed, call_student, expect_close, expect_equal, expect_true, graded
from plm_highway.rollout.closed_loop import drive

DT_S = 0.05
TIME_TOLERANCE_S = 1e-9
BUFFER = "lesson1.DelayBuffer"


def _new_buffer(buffer_class, max_latency_s: float):
    return call_student(buffer_class, max_latency_s, what=f"DelayBuffer(max_latency_s={max_latency_s})",
                        exercise=BUFFER)


def _push(buffer, time_s: float, item) -> None:
    call_student(buffer.push, time_s, item, what=f"push({time_s!r}, {item!r})", exercise=BUFFER)


def _get(buffer, now_s: float, latency_s: float):
    what = f"get(now_s={now_s!r}, latency_s={latency_s!r})"
    result = call_student(buffer.get, now_s, latency_s, what=what, exercise=BUFFER)
    expect_true(isinstance(result, tuple) and len(result) == 2, what, "return a tuple (item, age_s)",
                expected="(item, age_s)", received=repr(result)[:80])
    return result


def _filled_buffer(buffer_class, max_latency_s: float, until_s: float):
    buffer = _new_buffer(buffer_class, max_latency_s)
    for step in range(int(round(until_s / DT_S)) + 1):
        _push(buffer, step / 20, f"item@{step}")
    return buffer


def reference_get(times_s: list[float], items: list, now_s: float, latency_s: float):
    """The newest item taken at or before ``now_s - latency_s`` (else the oldest), and its age: brute force."""
    eligible = [i for i, t in enumerate(times_s) if t <= now_s - latency_s + TIME_TOLERANCE_S]
    index = eligible[-1] if eligible else 0
    return items[index], now_s - times_s[index]


@graded(points=3)
def check_delay_buffer(buffer_class, seed: int | None = None) -> None:
    """Ages lie in [latency, latency + one step]; the oldest item before history exists; memory stays bounded."""
    if seed is not None:
        _random_buffer_cases(buffer_class, np.random.default_rng(seed))
        return
    buffer = _filled_buffer(buffer_class, max_latency_s=1.0, until_s=1.0)
    cases = [  # (now, latency, expected item, expected age): worked out by hand on a 0.05 s grid
        (1.0, 0.0, "item@20", 0.0),
        (1.0, 0.2, "item@16", 0.2),
        (1.0, 0.22, "item@15", 0.25),
        (1.0, 0.35, "item@13", 0.35),
    ]
    for now_s, latency_s, expected_item, expected_age_s in cases:
        item, age_s = _get(buffer, now_s, latency_s)
        expect_equal(f"item from get(now_s={now_s}, latency_s={latency_s}), items pushed every 0.05 s",
                     expected_item, item, hint="return the NEWEST item taken at or before now_s - latency_s "
                     "(compare times with a 1e-9 s tolerance)")
        expect_close(f"age from get(now_s={now_s}, latency_s={latency_s})", expected_age_s, age_s, atol=1e-9,
                     hint="age = now_s - the time the returned item was pushed")
    young = _filled_buffer(buffer_class, max_latency_s=1.0, until_s=0.1)
    item, age_s = _get(young, 0.1, 0.3)
    expect_equal("item from get(now_s=0.1, latency_s=0.3) with only 0.1 s of history", "item@0", item,
                 hint="before enough history exists, deliver the oldest item")
    expect_close("age of the oldest item", 0.1, age_s, atol=1e-9)
    long = _filled_buffer(buffer_class, max_latency_s=0.5, until_s=50.0)
    expect_true(len(long) <= 0.5 / DT_S + 3, "len(buffer) after 50 s of pushes with max_latency_s=0.5",
                "forget items older than now - max_latency_s (keep one at or before that time)",
                expected=f"at most {int(0.5 / DT_S + 3)} items", received=len(long))
    item, age_s = _get(long, 50.0, 0.5)
    expect_close("age from get(now_s=50.0, latency_s=0.5) with max_latency_s=0.5", 0.5, age_s, atol=1e-9,
                 hint="keep the newest item at or before now - max_latency_s: do not forget too much")


def _random_buffer_cases(buffer_class, rng: np.random.Generator) -> None:
    """Irregular push times, random latencies: the buffer against a brute-force lookup."""
    max_latency_s = float(rng.uniform(0.3, 1.0))
    buffer = _new_buffer(buffer_class, max_latency_s)
    times_s: list[float] = []
    items: list[str] = []
    now_s = float(rng.uniform(0, 3))
    for step in range(300):
        now_s = round(now_s + float(rng.choice([0.01, 0.02, 0.05, 0.1, 0.15])), 2)
        times_s.append(now_s)
        items.append(f"frame{step}")
        _push(buffer, now_s, items[-1])
        latency_s = float(rng.choice([0.0, max_latency_s, round(float(rng.uniform(0, max_latency_s)), 2),
                                      float(rng.uniform(0, max_latency_s))]))
        item, age_s = _get(buffer, now_s, latency_s)
        expected_item, expected_age_s = reference_get(times_s, items, now_s, latency_s)
        where = f"get(now_s={now_s:g}, latency_s={latency_s:g}) after irregular pushes"
        expect_equal(f"item from {where}", expected_item, item,
                     hint="look the item up by time (the newest at or before now_s - latency_s), not by counting")
        expect_close(f"age from {where}", expected_age_s, age_s, atol=1e-9)
        window = sum(t > now_s - max_latency_s for t in times_s)
        expect_true(len(buffer) <= window + 2, f"len(buffer) after {step + 1} irregular pushes",
                    "forget what is older than now - max_latency_s", expected=f"at most {window + 2}",
                    received=len(buffer))


@graded(points=2)
def check_growing_latency(buffer_class, seed: int | None = None) -> None:
    """When the latency jumps up, the age must jump with it (the original ROS FIFO did not)."""
    rng = np.random.default_rng(seed) if seed is not None else None
    buffer = _new_buffer(buffer_class, 1.0)
    latency_s = 0.0
    for step in range(60 if rng is None else 200):
        now_s = step / 20
        _push(buffer, now_s, step)
        if rng is None:
            latency_s = 0.0 if now_s < 2.0 else 0.3
        elif step % 20 == 0:
            latency_s = float(rng.choice([0.0, 0.1, 0.25, 0.3, 0.45, 0.6, 0.95]))
        item, age_s = _get(buffer, now_s, latency_s)
        if now_s >= latency_s:
            expect_true(latency_s - 1e-9 <= age_s <= latency_s + DT_S + 1e-9,
                        f"age at t = {now_s:.2f} s with latency {latency_s:g} s (it was {'raised' if step else 'set'} "
                        "a moment ago)", "look the item up by time, not by counting frames",
                        expected=f"between {latency_s:g} and {latency_s + DT_S:g} s", received=age_s)
            expect_close(f"item at t = {now_s:.2f} s", step - round(age_s * 20), item, atol=0)


@graded(points=3)
def check_zigzag(drive_with_latency) -> None:
    """The car's true offsets equal those of the kit's closed loop with the same latency, and 0.25 s old
    snapshots make the lane keeper weave at least twice as much as fresh ones."""
    offsets = {}
    for latency_s in (0.0, 0.25):
        received = call_student(drive_with_latency, latency_s, seed=0, duration_s=25.0,
                                what=f"drive_with_latency({latency_s}, seed=0, duration_s=25.0)",
                                exercise="lesson1.drive_with_latency")
        received = np.asarray(received, dtype=float)
        expected = drive("reference", ExpertPolicy(), "test", f"const:{latency_s}", 0, max_steps=501).columns[
            "lateral_offset_m"]
        expect_true(received.ndim == 1 and 495 <= len(received) <= 501, f"drive_with_latency({latency_s}) result",
                    "one true lateral offset per policy step (20 per second) until duration_s",
                    expected="500 offsets for 25 s", received=f"shape {received.shape}")
        n = len(received)
        # Recording before or after each step are both fine: accept the series shifted by one step.
        shifted = np.abs(received[: n - 1] - expected[1:n]).max(initial=0.0)
        if np.abs(received - expected[:n]).max(initial=0.0) > 1e-3 and shifted > 1e-3:
            expect_close(f"the car's true lateral offsets [m] with latency {latency_s} s, step by step",
                         expected[:n], received, atol=1e-3,
                         hint="push every new snapshot, steer with expert_steering(state of the snapshot your "
                              "buffer returns), record info['lateral_offset_m'] (the true offset)")
        offsets[latency_s] = float(np.sqrt(np.mean(received ** 2)))
    if offsets[0.25] < 2 * offsets[0.0]:
        raise CheckFailed("lateral offset RMS with 0.25 s latency against none", f"at least {2 * offsets[0.0]:.3f} m",
                          f"{offsets[0.25]:.3f} m", "with late snapshots the expert should weave")
