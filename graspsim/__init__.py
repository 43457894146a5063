"""graspsim: planar grasp detection with simulation in the loop.

Importing the package registers the gymnasium environment ``graspsim/Grasp-v0`` (by string
entry point, so pybullet is only imported when the environment is made).
"""

from __future__ import annotations

import gymnasium

__all__ = ["ENV_ID"]

ENV_ID = "graspsim/Grasp-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="graspsim.env:GraspEnv",
        max_episode_steps=10,
    )
