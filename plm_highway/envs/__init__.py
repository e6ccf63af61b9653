"""The lane-keeping environment, registered with gymnasium as ``plm_highway/LaneKeeping-v0``."""

import gymnasium

ENV_ID = "plm_highway/LaneKeeping-v0"


def register_envs() -> None:
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="plm_highway.envs.lane_keeping:LaneKeepingCameraEnv")
