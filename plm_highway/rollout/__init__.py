"""Closed-loop driving, shared by data collection, evaluation, sweeps, benchmarks and the grading.

- :mod:`~plm_highway.rollout.conditions`: the conditions a run is driven under (``ideal``, ``paper``), their
  ``with_*`` variants, each seed's start and the scored step count;
- :mod:`~plm_highway.rollout.closed_loop`: the one loop (:func:`~plm_highway.rollout.closed_loop.drive_batched`,
  one forward pass per model and step; :func:`~plm_highway.rollout.closed_loop.drive`: that loop with one run),
  a run's log and the run described as data (:class:`~plm_highway.rollout.closed_loop.RunCell`);
- :mod:`~plm_highway.rollout.policies`: policies by name (expert, Base Model, PLM-Net, EKF) and checkpoint pairs;
- :mod:`~plm_highway.rollout.cells`: :func:`~plm_highway.rollout.cells.run_cells`, the one way to drive a list of
  runs (serial, batched, or over a backend's workers), and cells under conditions;
- :mod:`~plm_highway.rollout.backends`: where chunks of runs go (this process, a local process pool, Ray);
- :mod:`~plm_highway.rollout.seeds`: seeds as the commands take them.
"""
