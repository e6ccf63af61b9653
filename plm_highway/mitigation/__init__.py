"""Plug-in mitigations of perception latency around a frozen Base Model.

PLM-Net's premise is kept: the trained BM is never retrained or changed. What a mitigation adds uses only what a
car has at control time: the late frame, its age (measured or estimated), the car's speed and yaw rate from its
own fast sensors, and the steering it issued itself while the frame was late. Never the true current state or the
undelayed frame (``tests/test_mitigation.py`` drives every mitigation with an info dict that refuses every other
key).

- :mod:`~plm_highway.mitigation.odometry`: where the car is now relative to where the frame was taken, dead
  reckoned from speed and yaw rate;
- :mod:`~plm_highway.mitigation.view`: the late frame re-projected to the car's present pose (a ground-plane
  homography of the kit's pinhole camera);
- :mod:`~plm_highway.mitigation.plugins`: the mitigations by name (:data:`MITIGATIONS`), each a per-run object
  the rollout's :class:`~plm_highway.rollout.policies.VisionPolicy` calls before and after the BM.
"""

from plm_highway.mitigation.plugins import MITIGATIONS, make_mitigation

__all__ = ["MITIGATIONS", "make_mitigation"]
