"""plm-highway: perception latency in vision-based lane keeping, on highway-env.

Importing the package registers ``plm_highway/LaneKeeping-v0`` with gymnasium.
"""

from plm_highway.envs import register_envs

__version__ = "0.1.0"

register_envs()
