"""plm-highway: perception latency in vision-based lane keeping, on highway-env.

Importing the package registers ``plm_highway/LaneKeeping-v0`` with gymnasium.
"""

from plm_highway._version import __version__
from plm_highway.envs import register_envs

__all__ = ["__version__"]

register_envs()
