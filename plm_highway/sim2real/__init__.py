"""Where a recording and the simulator disagree, which physics the simulator left out, and how much
a fitted term explains (``plm-highway sim2real diagnose`` / ``make-recording``).

Modules, top to bottom: :mod:`.recording` (the format, readers, validation), :mod:`.effects` (the
library of candidate physical terms and their kernels), :mod:`.replay` (the simulator's model on
a recording, re-anchored), :mod:`.selection` (fit inside the model, choose on held-out data),
:mod:`.diagnose` (the whole diagnosis and its JSON), :mod:`.report` (figures), :mod:`.synth`
(recordings from richer physics with a known answer), :mod:`.cli`. See ``README.md`` here.
"""
