"""One table of policies (``rollout.policies.POLICIES``): every command that drives reads a policy's meaning from it,
so a policy is added by one entry. Each entry's claims are checked against the objects the kit builds."""

from __future__ import annotations

import argparse

import pytest
from tiny_models import tiny_checkpoints

from plm_highway.cli import build_parser
from plm_highway.expert import ExpertPolicy
from plm_highway.road.track import resolve_track
from plm_highway.rollout.cells import Cell, runs_under
from plm_highway.rollout.conditions import CONDITIONS
from plm_highway.rollout.policies import (
    MITIGATED_POLICIES,
    MITIGATING_POLICIES,
    MODEL_POLICIES,
    POLICIES,
    POLICY_NAMES,
    VisionPolicy,
    make_policy,
    policy_for_run,
    policy_kind,
)
from plm_highway.sweep.grid import SweepCell


def _choices(argv: list[str], option: str) -> tuple:
    parser = build_parser(argv)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[argv[0]]
    return tuple(next(a for a in sub._actions if option in a.option_strings).choices)


def test_the_derived_lists_are_the_tables():
    assert POLICY_NAMES == ("expert", "bm", "plm", "ekf", "bm-warp", "bm-smith")
    assert MITIGATED_POLICIES == {"bm-warp": "warp", "bm-smith": "smith"}
    assert MITIGATING_POLICIES == ("plm", "bm-warp", "bm-smith")
    assert MODEL_POLICIES == ("bm", "plm", "bm-warp", "bm-smith")
    assert all(POLICIES[kind.reference].mitigates is False for kind in POLICIES.values())


@pytest.mark.parametrize("command", [["evaluate"], ["sweep"]])
def test_the_command_line_offers_the_tables_names(command):
    assert _choices(command, "--policy") == POLICY_NAMES


def test_an_unknown_policy_is_refused_naming_the_known_ones():
    for bad in ("bogus", "", None, 3):
        with pytest.raises(ValueError, match=r"expected one of \['expert', 'bm', 'plm'"):
            policy_kind(bad)
    with pytest.raises(ValueError, match="'bogus'"):
        make_policy("bogus")


def test_a_sweeps_reference_run_is_the_policy_the_table_names():
    for name, kind in POLICIES.items():
        assert SweepCell("ideal", "test", "const:0.1", 0, name).reference.policy == kind.reference


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    return tiny_checkpoints(tmp_path_factory)


@pytest.mark.parametrize("name", POLICY_NAMES)
def test_each_policy_is_built_as_its_entry_says(checkpoints, name):
    kind = POLICIES[name]
    made = make_policy(name, checkpoints)
    if kind.model is None:
        assert not isinstance(made, VisionPolicy)
        assert isinstance(made, ExpertPolicy) == (name == "expert")
        return
    assert isinstance(made, VisionPolicy)
    assert type(made.model_policy).__name__ == {"bm": "BaseModelPolicy", "plm": "PLMNetPolicy"}[kind.model]
    assert (made.mitigation is None) == (kind.mitigation is None)
    # a run of the batched runner: the shared model told the run's latency, with the run's own mitigation
    cell = runs_under([Cell("r", name, "const:0.1", 3)], resolve_track("test"), CONDITIONS["ideal"], {}, 5)[0]
    run = policy_for_run(name, made.model_policy, seed=cell.seed, camera=cell.camera, env_config=cell.env_config,
                         latency_bias_s=0.05)
    assert run.model_policy is made.model_policy and run.latency_bias_s == 0.05
    assert (run.mitigation is None) == (kind.mitigation is None)
    if kind.mitigation is not None:
        assert run.mitigation is not made.mitigation  # each run's own state


def test_the_ekf_keepers_plant_is_the_runs_or_the_conditions():
    paper = CONDITIONS["paper"]
    from_conditions = make_policy("ekf", conditions=paper, seed=2)
    cell = runs_under([Cell("r", "ekf", "const:0.1", 2)], resolve_track("test"), paper, {}, 5)[0]
    from_run = policy_for_run("ekf", seed=2, camera=cell.camera, env_config=cell.env_config)
    assert from_run.config == from_conditions.config
    assert make_policy("ekf").config != from_conditions.config  # without conditions: the EKF's own defaults
