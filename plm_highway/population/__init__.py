"""Populations of trained pairs: PLM-Net judged across K independent trainings with one recipe.

- :mod:`~plm_highway.population.recipe`: the recipe every pair shares, and each pair's seeds;
- :mod:`~plm_highway.population.plan`: the plan (pairs, settings, simulator seeds), on record before any run;
- :mod:`~plm_highway.population.training` and :mod:`~plm_highway.population.driving`: one pair made, one pair driven;
- :mod:`~plm_highway.population.analysis`: statistics with the pair as the unit, and the verdicts;
- :mod:`~plm_highway.population.study`: the resumable run over the sweep backends;
- :mod:`~plm_highway.population.report`: results.csv, report.md and figures.
"""
