"""Population statistics with the pair as the unit (plm_highway.population.analysis), on hand-made rows."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from plm_highway.population import analysis
from plm_highway.population.plan import PopulationPlan, make_plan
from plm_highway.population.recipe import RECIPES, PairSeeds, Recipe, recipe_named, with_overrides


def row(pair, seed, role, setting, mae=0.0, offset=0.1, left=False):
    return {"pair": pair, "seed": seed, "role": role, "setting": setting, "steering_mae_paper": mae,
            "steering_mae_paper_common": mae, "offset_rms_m": offset, "offset_max_m": 2 * offset,
            "frechet_m": offset, "left_road": left}


def test_spread_gives_the_t_interval_and_the_wider_prediction_interval_by_hand():
    values = [10.0, 20.0, 30.0, 40.0]
    result = analysis.spread(values)
    mean, sd, t = 25.0, np.std(values, ddof=1), stats.t.ppf(0.975, 3)
    assert result.mean == pytest.approx(mean)
    assert result.ci_high - mean == pytest.approx(t * sd / 2.0)  # sd / sqrt(4)
    assert result.pi_high - mean == pytest.approx(t * sd * math.sqrt(1 + 1 / 4))
    assert result.n == 4


def test_spread_of_one_value_has_no_interval_and_of_none_is_none():
    assert analysis.spread([3.0]).pi_low is None
    assert analysis.spread([math.nan]) is None


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-100, 99), min_size=3, max_size=30), st.sampled_from(["linear", "reduction"]))
def test_the_prediction_interval_always_contains_the_confidence_interval(values, scale):
    result = analysis.spread(values, scale=scale)
    assert result.pi_low <= result.ci_low + 1e-9 and result.ci_high <= result.pi_high + 1e-9


def test_two_pairs_give_a_centre_but_no_interval():
    result = analysis.spread([0.5, 5.0], scale="positive")
    assert result.mean == pytest.approx(2.75)
    assert (result.ci_low, result.ci_high, result.pi_low, result.pi_high, result.n) == (None, None, None, None, 2)


def test_errors_and_reductions_get_their_own_scales():
    assert analysis.scale_of("plm_offset_rms_m") == "positive"
    assert analysis.scale_of("bm_steering_mae_paper") == "positive"
    assert analysis.scale_of("mae_reduction_pct") == "reduction"
    # offsets that a linear interval would take below 0 m stay above it
    offsets = analysis.spread([0.2, 0.3, 9.0], scale=analysis.scale_of("plm_offset_rms_m"))
    assert 0 < offsets.pi_low <= offsets.ci_low < offsets.mean < offsets.ci_high <= offsets.pi_high
    assert offsets.mean == pytest.approx(9.5 / 3)
    assert analysis.spread([0.2, 0.3, 9.0]).ci_low < 0


def test_pair_summaries_average_seeds_within_a_pair_before_the_reduction():
    rows = []
    for seed, (bm, plm) in enumerate([(0.2, 0.1), (0.4, 0.1)]):
        rows += [row(0, seed, "reference", "const:0", 0.0, 0.05), row(0, seed, "baseline", "const:0.25", bm, 0.6),
                 row(0, seed, "mitigated", "const:0.25", plm, 0.5), row(0, seed, "mitigated", "const:0", 0.01, 0.06)]
    summary = {s["setting"]: s for s in analysis.pair_summaries(rows, ["const:0", "const:0.25"])}
    at = summary["const:0.25"]
    assert at["bm_steering_mae_paper"] == pytest.approx(0.3)
    assert at["plm_steering_mae_paper"] == pytest.approx(0.1)
    # 100 x (1 - 0.1 / 0.3) from the seed means, not the mean of per-seed reductions (50% and 75%)
    assert at["mae_reduction_pct"] == pytest.approx(100 * (1 - 0.1 / 0.3))
    assert at["offset_rms_reduction_pct"] == pytest.approx(100 * (1 - 0.5 / 0.6))
    assert summary["const:0"]["bm_steering_mae_paper"] == 0.0  # the BM at 0 s is the reference
    assert summary["const:0"]["plm_steering_mae_paper"] == pytest.approx(0.01)


def _population(bm_maes, plm_maes, setting="const:0.25", left=None):
    rows = []
    for pair, (bm, plm) in enumerate(zip(bm_maes, plm_maes)):
        rows += [row(pair, 0, "reference", "const:0"),
                 row(pair, 0, "baseline", setting, bm, left=bool(left and left[pair])),
                 row(pair, 0, "mitigated", setting, plm)]
    return analysis.pair_summaries(rows, [setting])


def test_the_verdict_needs_three_comparable_pairs():
    paper_bm = 0.3347  # the paper's BM MAE at 0.25 s (Table A3)
    summaries = _population([paper_bm, paper_bm, 5 * paper_bm], [0.09, 0.1, 0.1])
    result = analysis.verdict("const:0.25", summaries)
    assert result["comparable_pairs"] == 2 and result["verdict"] == "not testable"


def test_a_bm_that_left_the_road_is_not_comparable():
    paper_bm = 0.3347
    summaries = _population([paper_bm] * 3, [0.09] * 3, left=[True, False, False])
    assert analysis.verdict("const:0.25", summaries)["comparable_pairs"] == 2


def test_verdicts_are_two_sided():
    paper_bm = 0.3347
    near = analysis.verdict("const:0.25", _population([paper_bm] * 4, [0.08, 0.09, 0.10, 0.11]))
    assert near["verdict"] == "reproduced"  # reductions 67-76%, the paper's 72.5% inside
    above = analysis.verdict("const:0.25", _population([paper_bm] * 4, [0.0, 0.001, 0.002, 0.003]))
    assert above["verdict"] == "ours above"
    below = analysis.verdict("const:0.25", _population([paper_bm] * 4, [0.30, 0.31, 0.32, 0.33]))
    assert below["verdict"] == "ours below"


def test_shares_count_pairs_where_plm_net_lowers_each_error():
    rows = []
    for pair, (plm_mae, plm_offset) in enumerate([(0.1, 0.7), (0.1, 0.3), (0.5, 0.3)]):
        rows += [row(pair, 0, "reference", "const:0"), row(pair, 0, "baseline", "const:0.2", 0.3, 0.5),
                 row(pair, 0, "mitigated", "const:0.2", plm_mae, plm_offset)]
    summaries = analysis.pair_summaries(rows, ["const:0.2"])
    assert analysis.shares(summaries, "const:0.2") == {"setting": "const:0.2", "pairs": 3, "lower_mae": 2,
                                                       "lower_offset_rms": 2}


def test_error_fit_recovers_a_known_line():
    bm = [0.1, 0.2, 0.3, 0.4]
    summaries = _population(bm, [0.02 + 0.25 * x for x in bm])
    fit = analysis.error_fit(summaries, ["const:0.25"])
    assert fit["slope"] == pytest.approx(0.25) and fit["intercept"] == pytest.approx(0.02)


def test_pair_k_takes_the_documented_seeds_and_pair_0_is_the_shipped_pairs():
    assert PairSeeds.of(0) == PairSeeds(0, data_seed=1, bm_seed=0, tapm_seed=0)
    assert PairSeeds.of(7) == PairSeeds(7, data_seed=8, bm_seed=7, tapm_seed=7)


def test_the_paper_recipe_is_the_shipped_pairs_recorded_commands():
    import json
    from importlib import resources

    manifest = json.loads(resources.files("plm_highway.checkpoints").joinpath("manifest.json").read_text())
    shipped = manifest["presets"]["paper"]
    recipe = RECIPES["paper"]
    assert recipe.collect_command(1).replace("DATA", "data") == shipped["data"]["command"]
    for model in ("bm", "tapm"):
        # the shipped commands name their directories and leave the balancing cap at its default (2000)
        ours = recipe.train_command(model, 0).replace(" --balance-max-per-bin 2000", "").split()
        theirs = shipped["models"][model]["command"].split()
        assert ours[:3] == theirs[:3] == ["plm-highway", "train", model]
        option_values = lambda words: {w: words[i + 1] for i, w in enumerate(words) if w.startswith("--")  # noqa: E731
                                       and w not in ("--data", "--out", "--bm")}
        assert option_values(ours) == option_values(theirs)


def test_a_plan_round_trips_and_overrides_are_recorded():
    recipe = with_overrides(recipe_named(None, "paper"), max_samples=500, epochs=1)
    plan = make_plan(recipe, "paper", 3, sim_seeds=(0, 1), max_steps=200)
    assert PopulationPlan.from_dict(plan.as_dict()) == plan
    assert recipe.overrides == {"max_samples": 500, "epochs": 1}
    assert recipe.bm.max_samples == recipe.tapm.max_samples == 500
    assert Recipe.from_dict(recipe.as_dict()) == recipe


def test_a_recipe_for_other_conditions_is_refused():
    from plm_highway.errors import BadInput

    with pytest.raises(BadInput, match="made for the 'ideal' conditions"):
        recipe_named("default", "paper")


def test_the_committed_populations_statistics_and_report_are_those_of_its_results(repo_root):
    import json

    from plm_highway.io import json_text
    from plm_highway.population.report import analyse, read_results, render_report

    directory = repo_root / "figures" / "population"
    document = json.loads((directory / "population.json").read_text(encoding="utf-8"))
    rows = read_results(directory / "results.csv")
    trainings = {int(pair): record for pair, record in document["trainings"].items()}
    numbers = json.loads(json_text(analyse(PopulationPlan.from_dict(document["plan"]), trainings, rows)))
    for key, value in numbers.items():
        assert document[key] == value, f"population.json's {key} is not what results.csv gives"
    figures = [line.split("](")[1].rstrip(")") for line in (directory / "report.md").read_text().splitlines()
               if line.startswith("![")]
    assert (directory / "report.md").read_text(encoding="utf-8") == render_report(document, figures)
