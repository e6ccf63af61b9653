"""Graded checks for Lesson 1, "Latency makes a lane keeper zig-zag"."""

from __future__ import annotations

import numpy as np

from plm_highway.grading.checks import CheckFailed, call_student, expect_close, expect_true, graded

DT_S = 0.05


def _filled_buffer(buffer_class, max_latency_s: float, until_s: float):
    buffer = call_student(buffer_class, max_latency_s, what="DelayBuffer(max_latency_s)")
    for step in range(int(round(until_s / DT_S)) + 1):
        call_student(buffer.push, step / 20, f"item@{step}", what="DelayBuffer.push")
    return buffer


@graded(points=3)
def check_delay_buffer(buffer_class) -> None:
    """Ages must lie in [latency, latency + one step]; the oldest item before history exists."""
    buffer = _filled_buffer(buffer_class, max_latency_s=1.0, until_s=1.0)
    cases = [  # (now, latency, expected item, expected age): worked out by hand on a 0.05 s grid
        (1.0, 0.0, "item@20", 0.0),
        (1.0, 0.2, "item@16", 0.2),
        (1.0, 0.22, "item@15", 0.25),
        (1.0, 0.35, "item@13", 0.35),
    ]
    for now_s, latency_s, expected_item, expected_age_s in cases:
        result = call_student(buffer.get, now_s, latency_s, what="DelayBuffer.get")
        expect_true(isinstance(result, tuple) and len(result) == 2,
                    f"get({now_s}, {latency_s}) must return (item, age_s), received {result!r}")
        item, age_s = result
        expect_true(item == expected_item,
                    f"get(now_s={now_s}, latency_s={latency_s}): expected {expected_item!r}, received {item!r}",
                    hint="return the NEWEST item taken at or before now_s - latency_s (compare with a 1e-9 tolerance)")
        expect_close(f"age returned by get({now_s}, {latency_s})", expected_age_s, age_s, atol=1e-9,
                     hint="age = now_s - time the item was pushed")
    young = _filled_buffer(buffer_class, max_latency_s=1.0, until_s=0.1)
    item, age_s = call_student(young.get, 0.1, 0.3, what="DelayBuffer.get")
    expect_true(item == "item@0", f"with only 0.1 s of history and latency 0.3 s, expected the oldest item 'item@0', "
                f"received {item!r}", hint="before enough history exists, deliver the oldest item")
    expect_close("age of the oldest item", 0.1, age_s, atol=1e-9)
    long = _filled_buffer(buffer_class, max_latency_s=0.5, until_s=50.0)
    expect_true(len(long) <= 0.5 / DT_S + 3, f"after 50 s with max_latency_s=0.5 the buffer holds {len(long)} items",
                hint="forget items older than now - max_latency_s (keep one at or before that time)")
    item, age_s = call_student(long.get, 50.0, 0.5, what="DelayBuffer.get")
    expect_close("age at the maximum latency", 0.5, age_s, atol=1e-9, hint="do not forget too much")


@graded(points=2)
def check_growing_latency(buffer_class) -> None:
    """When the latency jumps up, the age must jump with it (the original ROS FIFO did not)."""
    buffer = call_student(buffer_class, 1.0, what="DelayBuffer(max_latency_s)")
    for step in range(60):
        now_s = step / 20
        call_student(buffer.push, now_s, step, what="DelayBuffer.push")
        latency_s = 0.0 if now_s < 2.0 else 0.3
        item, age_s = call_student(buffer.get, now_s, latency_s, what="DelayBuffer.get")
        if now_s >= latency_s:
            expect_true(latency_s - 1e-9 <= age_s <= latency_s + DT_S + 1e-9,
                        f"at t={now_s:.2f} s with latency {latency_s} s the age was {age_s:.3f} s",
                        hint="look the item up by time, not by counting frames")
            expect_close(f"item at t={now_s:.2f} s", step - round(age_s * 20), item, atol=0)


@graded(points=3)
def check_zigzag(drive_with_latency) -> None:
    """The lane keeper fed 0.25 s old snapshots must weave at least twice as much as without."""
    from plm_highway.evaluation.closed_loop import drive
    from plm_highway.expert import ExpertPolicy

    offsets = {}
    for latency_s in (0.0, 0.25):
        received = call_student(drive_with_latency, latency_s, seed=0, duration_s=25.0, what="drive_with_latency")
        received = np.asarray(received, dtype=float)
        reference = drive("reference", ExpertPolicy(), "test", f"const:{latency_s}", 0, max_steps=500)
        expected = reference.columns["lateral_offset_m"]
        expect_true(received.ndim == 1 and len(received) >= 400,
                    f"drive_with_latency({latency_s}) should return one lateral offset per policy step "
                    f"(~{len(expected)} for 25 s), received shape {received.shape}")
        n = min(len(received), len(expected))
        rms_received = float(np.sqrt(np.mean(received[:n] ** 2)))
        rms_expected = float(np.sqrt(np.mean(expected[:n] ** 2)))
        expect_close(f"lateral offset RMS with latency {latency_s} s", rms_expected, rms_received, rtol=0.1, atol=0.005,
                     hint="feed the expert the state of the snapshot your buffer returns, not the current one")
        offsets[latency_s] = rms_received
    if offsets[0.25] < 2 * offsets[0.0]:
        raise CheckFailed(f"expected a zig-zag: RMS at 0.25 s ({offsets[0.25]:.3f} m) should be at least twice the RMS "
                          f"without latency ({offsets[0.0]:.3f} m)")
