"""The reproduction's cells batched and on a process pool (issue 13.1-2): the serial runs, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from plm_highway.evaluation.cell_runner import drive_cells
from plm_highway.evaluation.closed_loop import LOG_COLUMNS
from plm_highway.evaluation.reproduce import plan_cells
from plm_highway.evaluation.run import CONDITIONS, make_policies, run_cells
from plm_highway.road.track import load_track


@pytest.fixture(scope="module", params=["ideal", "paper"])
def serial(request):
    conditions = CONDITIONS[request.param]
    track_spec = load_track("test")
    settings = ["const:0.2", conditions.time_varying[-1]]
    cells = plan_cells(settings, [0, 3], track_spec.name)
    policies = make_policies(None, conditions)
    return cells, track_spec, conditions, policies, run_cells(cells, track_spec, conditions, policies, max_steps=18)


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
    logs = drive_cells(cells, track_spec, conditions, policies, max_steps=18, batch_size=batch_size, threads=threads)
    assert_same_logs(logs, references)


@pytest.mark.slow
def test_a_process_pool_equals_the_serial_runs(serial):
    cells, track_spec, conditions, _, references = serial
    logs = drive_cells(cells, track_spec, conditions, None, None, max_steps=18, workers=2, batch_size=3)
    assert_same_logs(logs, references)


def test_a_cell_whose_policy_is_neither_a_model_nor_a_name_is_refused():
    cells = plan_cells(["const:0.2"], [0], "test")
    with pytest.raises(ValueError, match="neither a model policy"):
        drive_cells(cells, load_track("test"), CONDITIONS["ideal"], {"bm": object(), "plm": object()}, max_steps=2)
    with pytest.raises(ValueError, match="workers -1"):
        drive_cells(cells, load_track("test"), CONDITIONS["ideal"], None, max_steps=2, workers=-1)
