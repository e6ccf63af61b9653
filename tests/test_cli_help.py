"""Help pages are fast: they import no torch (nor the simulator), and say each default once."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
HEAVY = ("torch", "highway_env", "matplotlib", "scipy")

SCRIPT = """
import sys
from plm_highway.cli import main
code = main(sys.argv[1:])
print("HEAVY", *[name for name in {heavy!r} + ("nbformat",) if name in sys.modules])
print("EXIT", code)
"""


def help_page(*words: str) -> tuple[str, list[str]]:
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    result = subprocess.run([sys.executable, "-c", SCRIPT.format(heavy=HEAVY), *words], env=env, cwd=REPO_ROOT,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    heavy = next(line for line in lines if line.startswith("HEAVY")).split()[1:]
    assert next(line for line in lines if line.startswith("EXIT")) == "EXIT 0"
    return result.stdout, heavy


def every_command() -> list[tuple[str, ...]]:
    """The words of every command and sub-command of the CLI, as its router lists them."""
    import importlib

    from plm_highway.cli import ADAPTERS

    words = []
    for name in ADAPTERS:
        module = importlib.import_module(f"plm_highway.cli.{name}")
        if getattr(module, "GROUP_HELP", None) is None:
            words.append((module.COMMANDS[0].name,))
        else:
            words += [(name,)] + [(name, command.name) for command in module.COMMANDS]
    return words


def test_the_command_list_is_the_whole_cli():
    commands = every_command()
    assert {("train", "bm"), ("train", "tapm"), ("reproduce",), ("population",), ("bench", "models"),
            ("sim2real", "diagnose"), ("lessons", "build"), ("docs", "render")} <= set(commands)
    assert len(commands) == len(set(commands)) > 25


@pytest.mark.parametrize("words", [(), ("demo", "zigzag"), ("evaluate",)])
def test_help_pages_import_no_torch_and_no_simulator(words):
    page, heavy = help_page(*words, "--help")
    assert "usage: plm-highway" in page
    assert heavy == []


@pytest.mark.parametrize("words", every_command(), ids=" ".join)
def test_every_help_page_imports_no_torch_no_simulator_no_plotting(words):
    page, heavy = help_page(*words, "--help")
    assert f"usage: plm-highway {' '.join(words)}" in " ".join(page.split())
    assert not {"torch", "highway_env", "matplotlib", "nbformat"} & set(heavy), heavy
    if words != ("sim2real", "make-recording"):  # its help lists each effect's parameters, held by objects in code
        assert "scipy" not in heavy


def test_the_evaluate_help_says_each_default_once_and_no_none():
    page, _ = help_page("evaluate", "--help")
    flat = " ".join(page.split())
    assert "(default: None)" not in flat and "(default: False)" not in flat
    assert "(default: the shipped pair)" in flat and flat.count("(default:") == flat.count("(default: ") > 0
    assert "(default: the shipped pair) (default" not in flat
    assert "(default: const:0.25)" in flat  # a real default is still shown


def test_the_top_help_has_no_internal_labels():
    page, _ = help_page("--help")
    assert "seed paper" not in page.lower()


def test_the_help_read_from_source_equals_the_imported_library():
    from plm_highway.cli._common import defaults_of, static_defaults, static_names
    from plm_highway.evaluation.demo import zigzag
    from plm_highway.evaluation.evaluate import evaluate
    from plm_highway.rollout import conditions, policies

    assert static_defaults("plm_highway.evaluation.evaluate", "evaluate") == defaults_of(evaluate)
    assert static_defaults("plm_highway.evaluation.demo", "zigzag") == defaults_of(zigzag)
    for name in ("CONDITION_NAMES", "LATENCY_SOURCE_NAMES"):
        assert static_names("plm_highway.rollout.conditions", name) == tuple(getattr(conditions, name))
    assert static_names("plm_highway.rollout.conditions", "INJECTION_LATENCY_SOURCE") == \
        tuple(conditions.INJECTION_LATENCY_SOURCE)
    assert static_names("plm_highway.rollout.policies", "POLICY_NAMES") == policies.POLICY_NAMES


def test_the_defaults_other_help_pages_read_from_source_equal_the_imported_library():
    from pathlib import Path

    from plm_highway.cli._common import defaults_of, static_defaults, static_fields, static_names, static_value
    from plm_highway.data import collect
    from plm_highway.envs import config
    from plm_highway.evaluation import calibration, reproduce, response
    from plm_highway.models import tapm
    from plm_highway.population import plan, recipe, remedies
    from plm_highway.road import geometry
    from plm_highway.rollout import conditions, policies
    from plm_highway.sweep import grid, runner
    from plm_highway.training import train

    def fields_equal(module, cls):
        read = static_fields(module.__name__, cls.__name__)
        assert read and read == {name: value for name, value in defaults_of(cls).items() if name in read}
        return read

    assert fields_equal(train, train.TrainConfig)["epochs"] == train.TrainConfig().epochs
    for module, cls in ((collect, collect.CollectConfig), (reproduce, reproduce.ReproduceOptions),
                        (calibration, calibration.CalibrationOptions), (grid, grid.SweepGrid)):
        fields_equal(module, cls)
    assert static_fields("plm_highway.sweep.grid", "SweepGrid")["latencies"] == grid.SweepGrid().latencies
    for module, function in ((response, response.bm_response), (runner, runner.run_sweep)):
        read = static_defaults(module.__name__, function.__name__)
        assert read == {name: value for name, value in defaults_of(function).items() if name in read}
    assert {"track", "conditions", "segment"} <= set(static_defaults(response.__name__, "bm_response"))
    constants = [(tapm, "DEFAULT_DELTA_GRID_S"), (config, "MAX_PROCESSING_DELAY_STEPS"),
                 (config, "MAX_STEERING_TIME_CONSTANT_S"), (calibration, "DEFAULT_OUT"), (response, "DEFAULT_OUT"),
                 (conditions, "FRICTION_RANGE"), (grid, "MAX_STEPS"), (plan, "DEFAULT_SIM_SEEDS"),
                 (plan, "MAX_PAIRS"), (remedies, "REMEDIES")]
    for module, name in constants:
        assert static_value(module.__name__, name) == getattr(module, name), name
    assert isinstance(static_value(calibration.__name__, "DEFAULT_OUT"), Path)
    for module, name in ((collect, "CAMERAS"), (collect, "DEMONSTRATORS"), (calibration, "READINGS"),
                         (conditions, "SPEED_LOGICS"), (geometry, "SEGMENTS"), (recipe, "RECIPES"),
                         (policies, "POLICY_NAMES")):
        assert static_names(module.__name__, name) == tuple(getattr(module, name)), name
    from plm_highway.bench import metrics as bench_metrics
    from plm_highway.bench import models as bench_models
    from plm_highway.bench import sweep as bench_sweep
    from plm_highway.evaluation import latency_estimation, plm_vs_ekf
    from plm_highway.lane_ekf import table3
    from plm_highway.sim2real import benchmark, workflow

    for module, cls in ((plm_vs_ekf, plm_vs_ekf.CompareConfig), (latency_estimation, latency_estimation.LatencySuite)):
        fields_equal(module, cls)
    for module, function in ((plm_vs_ekf, plm_vs_ekf.compare), (bench_sweep, bench_sweep.bench_reproduce),
                             (workflow, workflow.diagnose_file)):
        read = static_defaults(module.__name__, function.__name__)  # a computed default (compare's config) is left out
        assert read == {name: value for name, value in defaults_of(function).items() if name in read}, function.__name__
    assert static_defaults(plm_vs_ekf.__name__, "compare")["seeds"] == defaults_of(plm_vs_ekf.compare)["seeds"]
    from plm_highway.grading import notebooks

    for module, name in ((notebooks, "DEFAULT_SOLUTIONS"), (notebooks, "DEFAULT_LESSONS"),
                         (notebooks, "DEFAULT_FIGURES"),
                         (table3, "MAX_SEEDS"), (plm_vs_ekf, "MAX_SEEDS"), (bench_models, "TRAIN_BATCH_SIZE"),
                         (bench_metrics, "DEFAULT_POINTS"), (bench_metrics, "DEFAULT_REPEAT"),
                         (bench_metrics, "DEFAULT_SEED")):
        assert static_value(module.__name__, name) == getattr(module, name), name
    for module, name in ((table3, "MEASUREMENTS"), (bench_models, "PRESETS"), (bench_models, "WEIGHTS"),
                         (benchmark, "CASE_SETS")):
        assert static_names(module.__name__, name) == tuple(getattr(module, name)), name
    paper = conditions.CONDITIONS["paper"]  # calibrate's help names the paper conditions' actuator by its constants
    assert static_value(conditions.__name__, "PAPER_PROCESSING_DELAY_STEPS") == paper.processing_delay_steps
    assert static_value(conditions.__name__, "PAPER_STEERING_TIME_CONSTANT_S") == paper.steering_time_constant_s


def test_a_computed_default_is_refused_by_name_not_guessed():
    from plm_highway.cli._common import static_value

    with pytest.raises(ValueError, match="not a constant"):
        static_value("plm_highway.evaluation.response", "OFFSETS_M")


def test_the_formatter_adds_a_default_only_where_the_help_lacks_one():
    from plm_highway.cli import DefaultsOnceFormatter

    parser = argparse.ArgumentParser(formatter_class=DefaultsOnceFormatter)
    parser.add_argument("--a", default=3, help="a number")
    parser.add_argument("--b", help="a directory (default: the shipped one)")
    parser.add_argument("--c", action="store_true", help="a switch")
    text = " ".join(parser.format_help().split())
    assert "a number (default: 3)" in text
    assert "a directory (default: the shipped one) --c" in text
    assert "a switch" in text and "(default: False)" not in text
