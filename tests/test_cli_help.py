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
print("HEAVY", *[name for name in {heavy!r} if name in sys.modules])
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


@pytest.mark.parametrize("words", [("--help",), ("evaluate", "--help"), ("demo", "zigzag", "--help")])
def test_help_pages_import_no_torch_and_no_simulator(words):
    page, heavy = help_page(*words)
    assert "usage: plm-highway" in page
    assert heavy == []


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
    from plm_highway.evaluation.evaluate import evaluate
    from plm_highway.rollout import conditions, policies

    from plm_highway.evaluation.demo import zigzag

    assert static_defaults("plm_highway.evaluation.evaluate", "evaluate") == defaults_of(evaluate)
    assert static_defaults("plm_highway.evaluation.demo", "zigzag") == defaults_of(zigzag)
    for name in ("CONDITION_NAMES", "LATENCY_SOURCE_NAMES"):
        assert static_names("plm_highway.rollout.conditions", name) == tuple(getattr(conditions, name))
    assert static_names("plm_highway.rollout.conditions", "INJECTION_LATENCY_SOURCE") == \
        tuple(conditions.INJECTION_LATENCY_SOURCE)
    assert static_names("plm_highway.rollout.policies", "POLICY_NAMES") == policies.POLICY_NAMES


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
