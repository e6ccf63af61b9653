"""The PLM-Net papers' steering unit and the steering ratio this project reads it with.

The papers give steering normalised to [-1, 1], 1 = 450 deg of steering wheel, and state no steering
ratio. The reproduction converts the paper's 0.1714 to "about 0.11 rad at the front wheels", i.e.
0.1714 * 450 deg / 0.11 rad = 12.2:1; we use 12. The car agrees: the papers drove OSCAR's ``fusion``,
which its README says is based on OSRF's ``car_demo`` Prius. That car's URDF
(``prius_description/urdf/prius.urdf``) limits the steering wheel to +-7.85 rad (450 deg) and the
tyres to ``max_steer`` 0.6458 rad, and its plugin's ratio is tyre range over wheel range,
7.85 / 0.6458 = 12.16:1. The same file gives the Gazebo wheels a friction coefficient of 0.9.

One place, read by the evaluation protocol, the human-like demonstrator and the original's speed logic.
"""

from __future__ import annotations

import math

PAPER_FULL_SCALE_DEG = 450.0  # the paper's unit: steering 1 = 450 deg of steering wheel
PAPER_STEERING_RATIO = 12.0


def paper_unit_to_front_wheel_rad(value: float) -> float:
    """The paper's steering unit (1 = 450 deg of steering wheel) in front-wheel radians."""
    return value * math.radians(PAPER_FULL_SCALE_DEG) / PAPER_STEERING_RATIO
