"""plm-highway bench sweep: every side drives the same runs; the report prints them side by side."""

from __future__ import annotations

import json

import pytest

from plm_highway.bench.sweep import bench_sweep, report_lines
from plm_highway.cli import main


@pytest.mark.slow
def test_every_side_drives_the_same_runs(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "sweep", "--envs", "3", "--steps", "4", "--workers", "1", "--policy", "bm",
                 "--repeats", "2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    sides = result["sides"]
    assert len(sides) == 8 and any(name.endswith("warm") for name in sides)
    for figures in sides.values():  # the median of the repeats
        assert len(figures["wall_s_repeats"]) == 2
        assert figures["wall_s"] == pytest.approx(sum(figures["wall_s_repeats"]) / 2)
    serial = [name for name in sides if name.startswith("one env at a time")]
    assert max(sides[name]["speed_up"] for name in serial) == 1.0  # ratios against the fastest serial side
    for name, figures in sides.items():
        if "default kernels" not in name:  # every batch-invariant side is the reference side, bit for bit
            assert figures["max_steering_difference"] == 0.0, name
        else:
            assert figures["max_steering_difference"] < 1e-5, name
        assert figures["policy_steps_per_s"] == pytest.approx(3 * 4 / figures["wall_s"])
    printed = capsys.readouterr().out
    assert all(name in printed for name in sides) and "load average" in printed


def test_report_lines_show_every_side_and_its_ratio():
    result = {"envs": 2, "steps": 5, "policy": "plm", "track": "test", "latency": "const:0.1",
              "load_average_1min": 3.0, "cpus": 2,
              "sides": {"one env at a time": {"wall_s": 4.0, "policy_steps_per_s": 2.5, "speed_up": 1.0},
                        "batched, own envs": {"wall_s": 1.0, "policy_steps_per_s": 10.0, "speed_up": 4.0,
                                              "max_steering_difference": 1e-8}}}
    lines = report_lines(result)
    assert "4.00x" in lines[-1] and "1.00e-08" in lines[-1] and "load average 3.00" in lines[0]


@pytest.mark.slow
def test_bench_reproduce_drives_the_same_runs_three_ways(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "reproduce", "--seeds", "1", "--max-steps", "3", "--workers", "2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["runs"] == 1 + 2 * 5 and len(result["sides"]) == 3
    assert all(figures["identical_to_serial"] for figures in result["sides"].values())
    printed = capsys.readouterr().out
    assert "load average" in printed and all(name in printed for name in result["sides"])


def test_bad_sizes_are_refused_before_work(monkeypatch):
    assert main(["bench", "sweep", "--envs", "0"]) == 2

    def no_work(*args, **kwargs):
        raise AssertionError("a model or a worker pool was made before the bad input was refused")

    monkeypatch.setattr("plm_highway.bench.sweep.make_policy", no_work)  # the names bench_sweep calls
    monkeypatch.setattr("plm_highway.bench.sweep.worker_pool", no_work)
    with pytest.raises(ValueError, match="const:abc"):
        bench_sweep(n_envs=1, steps=3, policy="bm", latency="const:abc")
    with pytest.raises(FileNotFoundError, match="no-such-track"):
        bench_sweep(n_envs=1, steps=3, policy="bm", track="no-such-track")
