"""Gymnasium environments of vistask (installed as ``vistask.envs``).

Importing this package registers ``vistask/VisualMaze-v0`` and ``vistask/GraspTrial-v0``.
Robosuite-based modules (``scene``, ``tabletop``, ``grasp_trial``) are imported only when
used: importing robosuite takes seconds.
"""

from gymnasium.envs.registration import register, registry

from vistask.envs.maze_oracle import (
    EvaluationResult,
    MazeOracle,
    evaluate_policy,
    start_positions,
)
from vistask.envs.visual_maze import (
    ACTION_NAMES,
    MazeGeometry,
    VisualMazeEnv,
    VisualMazeVectorEnv,
    draw_maze,
)

if "vistask/VisualMaze-v0" not in registry:
    register(
        id="vistask/VisualMaze-v0",
        entry_point="vistask.envs.visual_maze:VisualMazeEnv",
        vector_entry_point="vistask.envs.visual_maze:VisualMazeVectorEnv",
        max_episode_steps=50,
    )
if "vistask/GraspTrial-v0" not in registry:
    register(id="vistask/GraspTrial-v0", entry_point="vistask.envs.grasp_trial:GraspTrialEnv")

__all__ = [
    "ACTION_NAMES",
    "EvaluationResult",
    "MazeGeometry",
    "MazeOracle",
    "VisualMazeEnv",
    "VisualMazeVectorEnv",
    "draw_maze",
    "evaluate_policy",
    "start_positions",
]
