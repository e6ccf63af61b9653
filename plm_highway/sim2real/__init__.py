"""Where a recording and the simulator disagree, which physics the simulator left out, and how much
a fitted term explains (``plm-highway sim2real diagnose`` / ``make-recording``).

Subpackages, bottom to top, each importing only those before it:

* :mod:`.record`: the recording: :mod:`~.record.recording` (the format, readers, validation),
  :mod:`~.record.consistency` (the recording checked against itself: units, signs, time scale);
* :mod:`.physics`: the models: :mod:`~.physics.chain` (the simulator's model plus every physical term,
  named parameters and numba kernels), :mod:`~.physics.filters` (how a recorded channel sees a model
  output), :mod:`~.physics.effect_spec` (what an entry of the registry is), :mod:`~.physics.effects` (the
  library of candidate effects), :mod:`~.physics.terms` (the terms outside it that discovery tries),
  :mod:`~.physics.replay` (the model on a recording, its channels, re-anchored poses),
  :mod:`~.physics.synth` (recordings from richer physics with a known answer);
* :mod:`.fit`: fitting: :mod:`~.fit.folds` (held-out blocks), :mod:`~.fit.candidates` (the candidate
  space), :mod:`~.fit.problem` (a fit problem and a candidate's fit), :mod:`~.fit.grid` (a batch of
  parameter sets, linear terms in closed form), :mod:`~.fit.gridfit` (a candidate's grid stage),
  :mod:`~.fit.polish` (its coordinates and least-squares polish), :mod:`~.fit.jitter` (the jittering
  delay's variance model), :mod:`~.fit.fitting` (one candidate end to end), :mod:`~.fit.scoring`
  (held-out scores and comparisons), :mod:`~.fit.uncertainty` (refit and intervals),
  :mod:`~.fit.selection` (forward selection and the decision), :mod:`~.fit.plausibility` (checks
  before naming);
* :mod:`.residual`: beyond the library: :mod:`~.residual.delay_track` (a delay that varies in time),
  :mod:`~.residual.track_bank` (a bank that varies along the track), :mod:`~.residual.discovery`
  (residual discovery), :mod:`~.residual.shapes` (the data's own view of a discovered shape);
* the diagnosis: :mod:`.diagnosis` (the record, its verdicts and their thresholds), :mod:`.diagnose`
  (the pipeline), :mod:`.rendering` (its printed summary and JSON), :mod:`.report` (figures);
* the commands and proofs: :mod:`.workflow` (the commands' work), :mod:`.benchmark` (seed sweeps),
  :mod:`.perception_delay` and :mod:`.perception_tie_in` (the camera's delay beside the car's).
  See ``README.md`` here.
"""
