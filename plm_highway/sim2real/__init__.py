"""Where a recording and the simulator disagree, which physics the simulator left out, and how much
a fitted term explains (``plm-highway sim2real diagnose`` / ``make-recording``).

Modules, bottom to top (one concept each):

* the recording: :mod:`.recording` (the format, readers, validation), :mod:`.consistency` (the
  recording checked against itself: units, signs, time scale);
* the model: :mod:`.chain` (the simulator's model plus every physical term, named parameters and
  numba kernels), :mod:`.filters` (how a recorded channel sees a model output),
  :mod:`.effect_spec` (what an entry of the registry is), :mod:`.effects` (the library of candidate
  effects), :mod:`.terms` (the terms outside it that discovery tries), :mod:`.replay` (the model on
  a recording, its channels, re-anchored poses);
* fitting: :mod:`.folds` (held-out blocks), :mod:`.candidates` (the candidate space),
  :mod:`.problem` (a fit problem and a candidate's fit), :mod:`.grid` (a batch of parameter sets,
  linear terms in closed form), :mod:`.gridfit` (a candidate's grid stage), :mod:`.polish` (its
  coordinates and least-squares polish), :mod:`.jitter` (the jittering delay's variance model),
  :mod:`.fitting` (one candidate end to end), :mod:`.scoring` (held-out scores and comparisons),
  :mod:`.uncertainty` (refit and intervals), :mod:`.selection` (forward selection and the decision);
* beyond the library: :mod:`.delay_track` (a delay that varies in time), :mod:`.track_bank` (a bank
  that varies along the track), :mod:`.plausibility` (checks before naming), :mod:`.discovery`
  (residual discovery), :mod:`.shapes` (the data's own view of a discovered shape);
* the diagnosis: :mod:`.diagnose` (the whole diagnosis and its JSON), :mod:`.report` (figures);
* proving it: :mod:`.synth` (recordings from richer physics with a known answer),
  :mod:`.benchmark` (seed sweeps), :mod:`.workflow` (the commands' work). See ``README.md`` here.
"""
