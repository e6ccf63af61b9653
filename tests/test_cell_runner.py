"""One run_cells, three ways (serial, batched, on a process pool): the reproduction's cells, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from plm_highway.evaluation.reproduce import plan_cells
from plm_highway.road.track import load_track
from plm_highway.rollout.backends import LocalPool
from plm_highway.rollout.cells import Cell, chunk_count, run_cells, runs_under
from plm_highway.rollout.closed_loop import LOG_COLUMNS
from plm_highway.rollout.conditions import CONDITIONS
from plm_highway.rollout.policies import make_policies


@pytest.fixture(scope="module", params=["ideal", "paper"])
def serial(request):
    conditions = CONDITIONS[request.param]
    track_spec = load_track("test")
    settings = ["const:0.2", conditions.time_varying[-1]]
    # As reproduce plans them (under the legacy FIFO the BM baseline of the varying profile is constant), plus a
    # sweep cell with a wrong latency estimate.
    cells = [*plan_cells(settings, [0, 3], track_spec.name, conditions),
             Cell("sweep", "plm", "const:0.2", 3, latency_bias_s=0.05)]
    policies = make_policies(None, conditions)
    runs = runs_under(cells, track_spec, conditions, policies, max_steps=18)
    return cells, track_spec, conditions, policies, run_cells(runs, serial=True)


def assert_same_logs(logs, references):
    assert len(logs) == len(references)
    for log, reference in zip(logs, references):
        assert log.name == reference.name and log.steps == reference.steps
        for column in LOG_COLUMNS:
            np.testing.assert_array_equal(log.columns[column], reference.columns[column], err_msg=column)
        assert (log.left_road, log.completed_fraction, log.extras) == \
            (reference.left_road, reference.completed_fraction, reference.extras)


@pytest.mark.slow
@pytest.mark.parametrize("batch_size,threads", [(32, 1), (4, 2)])
def test_batched_in_this_process_equals_the_serial_runs(serial, batch_size, threads):
    cells, track_spec, conditions, policies, references = serial
    runs = runs_under(cells, track_spec, conditions, policies, max_steps=18)
    logs = run_cells(runs, preset=conditions.checkpoint_preset, batch_size=batch_size, threads=threads)
    assert_same_logs(logs, references)


@pytest.mark.slow
def test_a_process_pool_equals_the_serial_runs(serial):
    cells, track_spec, conditions, _, references = serial
    runs = runs_under(cells, track_spec, conditions, None, max_steps=18)  # by name: each worker loads them
    with LocalPool(2) as pool:
        logs = run_cells(runs, preset=conditions.checkpoint_preset, batch_size=3, backend=pool)
    assert_same_logs(logs, references)


def test_runs_that_cannot_be_driven_as_asked_are_refused_before_any_starts():
    cells = plan_cells(["const:0.2"], [0], "test")
    track_spec, conditions = load_track("test"), CONDITIONS["ideal"]
    with pytest.raises(ValueError, match="one policy object in two cells"):  # stepped together, they would share it
        run_cells(runs_under(cells, track_spec, conditions, {"bm": object(), "plm": object()}, max_steps=2))
    with pytest.raises(ValueError, match="by name"):  # a worker cannot use this process's objects
        run_cells(runs_under(cells, track_spec, conditions, make_policies(None, conditions), max_steps=2),
                  backend=LocalPool(1))
    with pytest.raises(ValueError, match="neither given as an object nor one of"):
        runs_under([Cell("reference", "pid", "const:0", 0)], track_spec, conditions)
    with pytest.raises(ValueError, match="serial runs take no threads"):
        run_cells(runs_under(cells, track_spec, conditions, max_steps=2), serial=True, threads=2)
    with pytest.raises(ValueError, match="on a backend take no threads"):
        run_cells(runs_under(cells, track_spec, conditions, max_steps=2), threads=2, backend=LocalPool(1))


@given(n_runs=st.integers(1, 500), workers=st.integers(1, 8), batch_size=st.integers(1, 64))
def test_runs_split_into_chunks_no_larger_than_a_batch_and_balanced_over_the_workers(n_runs, workers, batch_size):
    n_chunks = chunk_count(n_runs, workers, batch_size)
    assert 1 <= n_chunks <= n_runs
    assert math.ceil(n_runs / n_chunks) <= batch_size  # the largest chunk (runs dealt round-robin)
    assert n_chunks >= min(workers, n_runs)
    if n_runs >= workers * math.ceil(max(workers, math.ceil(n_runs / batch_size)) / workers):
        assert n_chunks % workers == 0  # no worker idles while the others run a last round


def test_75_runs_of_batch_32_on_2_workers_are_4_chunks():
    assert chunk_count(75, 2, 32) == 4  # was 3: one worker idle for the last third of a track


def test_a_latency_bias_is_what_plm_net_is_told(serial):
    cells, track_spec, conditions, policies, references = serial
    [unbiased] = [log for cell, log in zip(cells, references) if cell.key == ("mitigated", "const:0.2", 3)]
    biased_log = references[-1]
    assert not np.array_equal(biased_log.columns["steering"], unbiased.columns["steering"])
    [again] = run_cells(runs_under([Cell("sweep", "plm", "const:0.2", 3, latency_bias_s=0.05)], track_spec, conditions,
                                   policies, max_steps=18), serial=True)
    np.testing.assert_array_equal(again.columns["steering"], biased_log.columns["steering"])


def test_the_latency_sweep_driven_one_at_a_time_equals_it_driven_batched():
    from plm_highway.evaluation import sweep

    conditions, track_spec = CONDITIONS["ideal"], load_track("test")
    policies = make_policies(None, conditions)
    [reference] = run_cells(runs_under([Cell("reference", "bm", "const:0", 0)], track_spec, conditions, policies,
                                       max_steps=20), serial=True)

    def batched(runs):
        cells = [Cell("sweep", "bm" if key == "bm" else "plm", f"const:{latency_s:g}", 0, latency_bias_s=bias_s)
                 for key, latency_s, bias_s in runs]
        return run_cells(runs_under(cells, track_spec, conditions, policies, max_steps=20))

    arguments = (track_spec, policies["bm"], policies["plm"], reference, 0, 20, [0.0, 0.2])
    one_at_a_time, together = sweep.latency_sweep(*arguments), sweep.latency_sweep(*arguments, drive_runs=batched)
    assert one_at_a_time == together
    by_policy = {(row["policy"], row["latency_s"]): row["steering_mae"] for row in together["rows"]}
    assert by_policy[("plm_bias+0.05", 0.2)] != by_policy[("plm", 0.2)]  # the bias reached PLM-Net


def test_a_pool_s_workers_end_when_the_process_that_made_them_is_killed(tmp_path):
    """A parent killed by a signal it cannot catch leaves no worker driving runs for nobody."""
    import signal
    import subprocess
    import sys
    import time

    pids = tmp_path / "pids"
    script = f"""
import os, time
from plm_highway.rollout.backends import worker_pool
if __name__ == "__main__":
    pool = worker_pool(2)
    workers = [pool.submit(os.getpid).result() for _ in range(4)]
    open({str(pids)!r}, "w").write(" ".join(map(str, set(workers))))
    pool.submit(time.sleep, 600)
    time.sleep(600)
"""
    parent = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 120
        while not (pids.exists() and pids.read_text()) and time.monotonic() < deadline:
            time.sleep(0.2)
        workers = [int(p) for p in pids.read_text().split()]
        assert workers and all(_alive(pid) for pid in workers)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 20
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_alive(pid) for pid in workers)
    finally:
        if parent.poll() is None:
            parent.kill()


def _alive(pid: int) -> bool:
    import os

    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (ended, not yet reaped) is not driving anything
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False
