"""Gymnasium environments of vistask (installed as ``vistask.envs``).

Importing this package registers ``vistask/VisualMaze-v0``, its continuous-action variant
``vistask/VisualMazeContinuous-v0`` (the move's angle in radians), ``vistask/VisualMountainCar-v0``,
``vistask/PlaceNavigation-v0`` and ``vistask/GraspTrial-v0``.
Robosuite-based modules (``objects``: objects named by robosuite class or MJCF file;
``scene``, ``tabletop``, ``grasp_trial``) are imported only when used: importing robosuite
takes seconds. ``place_navigation`` imports MuJoCo and sets
MUJOCO_GL=egl when unset, for offscreen rendering without a display.
"""

from gymnasium.envs.registration import register, registry

from vistask.envs.car_oracle import CarOracle, evaluate_car_policy, start_states
from vistask.envs.maze_oracle import (
    EvaluationResult,
    MazeOracle,
    direction_angles,
    evaluate_policy,
    start_positions,
)
from vistask.envs.mountain_car import (
    CAR_ACTION_NAMES,
    VisualMountainCarEnv,
    VisualMountainCarVectorEnv,
    hill_step,
)
from vistask.envs.place_navigation import PlaceNavigationEnv, PlaceNavigationVectorEnv
from vistask.envs.place_oracle import PlaceOracle, evaluation_starts
from vistask.envs.place_plots import draw_world, view_sheet
from vistask.envs.place_scene import Jitter
from vistask.envs.place_world import PLACE_ACTION_NAMES, PlaceWorld
from vistask.envs.visual_maze import (
    ACTION_ANGLES,
    ACTION_NAMES,
    MazeGeometry,
    VisualMazeContinuousEnv,
    VisualMazeContinuousVectorEnv,
    VisualMazeEnv,
    VisualMazeVectorEnv,
    angle_directions,
    draw_maze,
)

if "vistask/VisualMaze-v0" not in registry:
    register(
        id="vistask/VisualMaze-v0",
        entry_point="vistask.envs.visual_maze:VisualMazeEnv",
        vector_entry_point="vistask.envs.visual_maze:VisualMazeVectorEnv",
        max_episode_steps=50,
    )
if "vistask/VisualMazeContinuous-v0" not in registry:
    register(
        id="vistask/VisualMazeContinuous-v0",
        entry_point="vistask.envs.visual_maze:VisualMazeContinuousEnv",
        vector_entry_point="vistask.envs.visual_maze:VisualMazeContinuousVectorEnv",
        max_episode_steps=50,
    )
if "vistask/VisualMountainCar-v0" not in registry:
    register(
        id="vistask/VisualMountainCar-v0",
        entry_point="vistask.envs.mountain_car:VisualMountainCarEnv",
        vector_entry_point="vistask.envs.mountain_car:VisualMountainCarVectorEnv",
        # Learning episodes: the oracle reaches the top within 25 steps from every start it can
        # win from, and short episodes restart the car often, spreading its interactions over
        # the (p, s) plane. The scoring runs episodes of 100 steps (car_oracle.EVAL_STEPS).
        max_episode_steps=20,
    )
if "vistask/PlaceNavigation-v0" not in registry:
    register(
        id="vistask/PlaceNavigation-v0",
        entry_point="vistask.envs.place_navigation:PlaceNavigationEnv",
        vector_entry_point="vistask.envs.place_navigation:PlaceNavigationVectorEnv",
        # The oracle needs at most 14 actions on the default town; gamma^50 = 0.005.
        max_episode_steps=50,
    )
if "vistask/GraspTrial-v0" not in registry:
    register(id="vistask/GraspTrial-v0", entry_point="vistask.envs.grasp_trial:GraspTrialEnv")

__all__ = [
    "ACTION_ANGLES",
    "ACTION_NAMES",
    "CAR_ACTION_NAMES",
    "PLACE_ACTION_NAMES",
    "CarOracle",
    "EvaluationResult",
    "Jitter",
    "MazeGeometry",
    "MazeOracle",
    "PlaceNavigationEnv",
    "PlaceNavigationVectorEnv",
    "PlaceOracle",
    "PlaceWorld",
    "VisualMazeContinuousEnv",
    "VisualMazeContinuousVectorEnv",
    "VisualMazeEnv",
    "VisualMazeVectorEnv",
    "VisualMountainCarEnv",
    "VisualMountainCarVectorEnv",
    "angle_directions",
    "direction_angles",
    "draw_maze",
    "draw_world",
    "evaluate_car_policy",
    "evaluate_policy",
    "evaluation_starts",
    "hill_step",
    "start_positions",
    "start_states",
    "view_sheet",
]
