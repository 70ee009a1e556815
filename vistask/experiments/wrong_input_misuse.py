"""Wrong inputs of ``scripts/sweep_wrong_inputs.py`` that misuse the API rather than mistype a
number: another object where one is expected, calls out of order, shapes and geometry that
make no sense (a maze with no free place, a camera that is no rigid transform), options a
reset does not know.

Example:
    >>> cases = list(misuse_cases(tmp_path))
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.agents import RLVCAgent, TabularQAgent
from vistask.envs import VisualMazeEnv, VisualMountainCarEnv, hill_step
from vistask.experiments.wrong_input_geometry import sample_density
from vistask.experiments.wrong_inputs import Case, case
from vistask.features import SiftExtractor, VisualFeatureExtractor
from vistask.grasp import GraspLearner, Workspace, reachable, scripted_teacher_grasps
from vistask.grasp.importance import Trials, local_success_rates
from vistask.objects import NBP
from vistask.se3 import (
    SE3KDE,
    compose,
    cross_validate_bandwidth,
    identity_poses,
    inverse,
    make_poses,
    mixture,
    random_poses,
    rotation_distance,
)
from vistask.vision import Camera, depth_buffer_to_metres, look_at, pixel_grid
from vistask.wrappers import VisualClasses, VisualFeatures

MAZE = "vistask/VisualMaze-v0"


def stepped(env: gym.Env, action) -> None:
    """Reset ``env`` and take ``action`` in it."""
    env.reset(seed=0)
    env.step(action)


def misuse_cases(folder: Path) -> Iterator[Case]:
    """Cases of another object, a call out of order or senseless geometry."""
    maze = gym.make(MAZE)
    lake = gym.make("FrozenLake-v1")
    poses = random_poses(4, generator=torch.Generator().manual_seed(3))
    (folder / "a_folder.pt").mkdir(parents=True, exist_ok=True)
    # Another object where one is expected
    yield case("objects", "RLVCAgent('vistask/VisualMaze-v0')", lambda: RLVCAgent(MAZE), "env")
    yield case("objects", "TabularQAgent('FrozenLake-v1')", lambda: TabularQAgent("x"), "env")
    yield case(
        "objects",
        "learn(callback='print')",
        lambda: TabularQAgent(lake).learn(5, "print"),
        "callback",
    )
    yield case(
        "objects", "learn(callback=42)", lambda: TabularQAgent(lake).learn(5, [42]), "callback"
    )
    yield case("objects", "GraspLearner(a tensor)", lambda: GraspLearner(poses), "hypothesis")
    yield case(
        "objects",
        "GraspLearner(workspace='table')",
        lambda: GraspLearner(sample_density(), workspace="table"),
        "workspace",
    )
    yield case("objects", "reachable(grasps, 'ws')", lambda: reachable(poses, "ws"), "workspace")
    yield case(
        "objects",
        "density.sample(5, generator=numpy's)",
        lambda: sample_density().sample(5, generator=np.random.default_rng(0)),
        "generator",
    )
    yield case("objects", "density.reweight(2.0)", lambda: sample_density().reweight(2.0), "fn")
    yield case(
        "numbers",
        "density.reweight(negative values)",
        lambda: sample_density().reweight(lambda x: -torch.ones(len(x))),
        "fn",
    )
    yield case(
        "objects",
        "mixture([d, d], 'ab')",
        lambda: mixture([sample_density()] * 2, "ab"),
        "coefficients",
    )
    yield case(
        "objects", "compose(numpy, numpy)", lambda: compose(poses.numpy(), poses.numpy()), "a"
    )
    yield case(
        "objects",
        "NBP().infer(patches, model) swapped",
        lambda: NBP().infer(poses, sample_density()),
        "model",
    )
    yield case(
        "objects", "VisualClasses(maze, None)", lambda: VisualClasses(maze, None), "classifier"
    )
    yield case(
        "objects",
        "VisualFeatures(maze, an agent)",
        lambda: VisualFeatures(maze, RLVCAgent(maze)),
        "extractor",
    )
    yield case(
        "objects",
        "SiftExtractor(panel_widths=96)",
        lambda: SiftExtractor(panel_widths=96),
        "panel_widths",
    )
    yield case(
        "objects",
        "TabularQAgent.load(file, env=an image env)",
        lambda: _tabular_on(folder, maze),
        "env",
    )
    # Calls out of order, files where folders are
    yield case(
        "order", "VisualMazeEnv().step(0) before reset", lambda: VisualMazeEnv().step(0), "reset"
    )
    yield case(
        "order",
        "VisualMountainCarEnv().step(0) before reset",
        lambda: VisualMountainCarEnv().step(0),
        "reset",
    )
    yield case(
        "order",
        "RLVCAgent(maze).predict(image) before learn",
        lambda: RLVCAgent(maze).predict(np.zeros((64, 64, 3), np.uint8)),
        "learn",
    )
    yield case(
        "files",
        "save into an existing folder",
        lambda: sample_density().save(folder / "a_folder.pt"),
        "folder",
    )
    yield case(
        "files",
        "learn(checkpoint=a folder)",
        lambda: TabularQAgent(lake).learn(5, checkpoint=folder / "a_folder.pt"),
        "checkpoint",
    )
    # Geometry and shapes
    for what, kwargs, name in (
        ("obstacles=[0.1, 0.2, 0.3]", {"obstacles": [0.1, 0.2, 0.3]}, "obstacles"),
        ("a NaN obstacle", {"obstacles": ((math.nan, 0.1, 0.5, 0.6),)}, "obstacles"),
        ("an obstacle over the whole maze", {"obstacles": ((0, 0, 1, 1),)}, "cover"),
        ("an exit over the whole maze", {"exits": ((0, 0, 1, 1),)}, "cover"),
        ("window=10**6", {"window": 10**6}, "window"),
        ("photo with tile", {"photo": "hubble_deep_field", "tile": 50}, "tile"),
    ):
        yield case(
            "env kwargs",
            f"gym.make(MAZE, {what})",
            lambda k=kwargs: gym.make(MAZE, **k).reset(seed=0),
            name,
        )
    yield case(
        "env kwargs",
        "gym.make(car, pixels_per_unit=1e9)",
        lambda: gym.make("vistask/VisualMountainCar-v0", pixels_per_unit=1e9),
        "pixels_per_unit",
    )
    yield case(
        "env kwargs",
        "gym.make(GraspTrial, render_mode='human')",
        lambda: gym.make("vistask/GraspTrial-v0", render_mode="rgbarray"),
        "render_mode",
    )
    yield case(
        "env kwargs",
        "maze.reset(options={'positon': ...})",
        lambda: gym.make(MAZE).reset(options={"positon": [0.5, 0.5]}),
        "positon",
    )
    yield case(
        "env kwargs",
        "car.reset(options={'position': ...})",
        lambda: gym.make("vistask/VisualMountainCar-v0").reset(options={"position": [0.0, 0.0]}),
        "position",
    )
    yield case("ranges", "maze.step(True)", lambda: stepped(gym.make(MAZE), True), "action")
    for what, kwargs, name in (
        ("substeps=0", {"substeps": 0}, "substeps"),
        ("dt=-0.1", {"dt": -0.1}, "dt"),
    ):
        yield case(
            "ranges",
            f"hill_step(..., {what})",
            lambda k=kwargs: hill_step(np.zeros((1, 2)), np.zeros(1), **k),
            name,
        )
    yield case(
        "numbers",
        "hill_step(NaN state)",
        lambda: hill_step(np.array([[math.nan, 0.0]]), np.zeros(1)),
        "states",
    )
    yield case("ranges", "SE3KDE(sigma_t=1e200)", lambda: SE3KDE(poses, sigma_t=1e200), "sigma_t")
    yield case(
        "ranges",
        "random_poses(3, dtype=torch.int32)",
        lambda: random_poses(3, dtype=torch.int32),
        "dtype",
    )
    yield case("ranges", "compose of 6-column poses", lambda: compose(poses[:, :6], poses), "a")
    yield case(
        "numbers",
        "inverse(a zero quaternion)",
        lambda: inverse(torch.tensor([0.0, 0, 0, 0, 0, 0, 2])),
        "quaternion",
    )
    yield case(
        "numbers",
        "rotation_distance(zeros(7), pose)",
        lambda: rotation_distance(torch.zeros(7), poses[0]),
        "quaternion",
    )
    yield case(
        "ranges",
        "make_poses(t (3,), q (3,))",
        lambda: make_poses(torch.zeros(3), torch.zeros(3)),
        "quaternion",
    )
    yield case(
        "ranges",
        "cross_validate_bandwidth(sigma_t_grid=[])",
        lambda: cross_validate_bandwidth(random_poses(20), sigma_t_grid=[]),
        "sigma_t_grid",
    )
    yield case(
        "numbers",
        "cross_validate_bandwidth(sigma_t_grid=[nan, 0.01])",
        lambda: cross_validate_bandwidth(random_poses(20), sigma_t_grid=[math.nan, 0.01]),
        "sigma_t_grid",
    )
    yield case(
        "ranges",
        "cross_validate_bandwidth(max_points=0)",
        lambda: cross_validate_bandwidth(random_poses(20), max_points=0),
        "max_points",
    )
    yield case(
        "ranges",
        "look_at(eye (2,), target (2,))",
        lambda: look_at(torch.zeros(2), torch.ones(2)),
        "eye",
    )
    yield case(
        "numbers", "Camera(K=zeros)", lambda: Camera(torch.zeros(3, 3), torch.eye(4), 4, 4), "K"
    )
    yield case(
        "numbers",
        "Camera(cam_to_world=zeros)",
        lambda: Camera(torch.eye(3), torch.zeros(4, 4), 4, 4),
        "cam_to_world",
    )
    yield case(
        "ranges",
        "depth_buffer_to_metres(near=20, far=10)",
        lambda: depth_buffer_to_metres(torch.zeros(2, 2), 20.0, 10.0),
        "near",
    )
    yield case("ranges", "pixel_grid(-1, 4)", lambda: pixel_grid(-1, 4), "height")
    yield case(
        "ranges",
        "Trials.add(cycle=-1)",
        lambda: Trials().add(identity_poses(2), torch.ones(2, dtype=torch.bool), -1),
        "cycle",
    )
    yield case(
        "types",
        "Trials.add(cycle=2.7)",
        lambda: Trials().add(identity_poses(2), torch.ones(2, dtype=torch.bool), 2.7),
        "cycle",
    )
    yield case(
        "types",
        "Trials.add(success=0.5s)",
        lambda: Trials().add(identity_poses(2), torch.full((2,), 0.5), 0),
        "success",
    )
    yield case(
        "ranges",
        "scripted_teacher_grasps(min > max)",
        lambda: scripted_teacher_grasps(torch.tensor([[0.1] * 3, [-0.1] * 3])),
        "bounds",
    )
    yield case(
        "ranges",
        "scripted_teacher_grasps(depth=-0.05)",
        lambda: scripted_teacher_grasps(torch.tensor([[-0.1] * 3, [0.1] * 3]), -0.05),
        "depth",
    )
    trials = Trials()
    trials.add(identity_poses(2), torch.ones(2, dtype=torch.bool), 0)
    yield case(
        "ranges",
        "local_success_rates(prior=-1)",
        lambda: local_success_rates(trials, torch.ones(2), 0.01, 0.2, prior=-1.0),
        "prior",
    )
    yield case("ranges", "SiftExtractor(threads=-2)", lambda: SiftExtractor(threads=-2), "threads")
    yield case(
        "ranges",
        "VisualFeatureExtractor.fit(max_distance=-1)",
        lambda: VisualFeatureExtractor.fit([np.zeros((8, 8, 3), np.uint8)], max_distance=-1.0),
        "max_distance",
    )
    yield case(
        "ranges",
        "Workspace(reach=(0.5, 0.5))",
        lambda: Workspace(0.8, (0.0, 0.0, 0.9), reach=(0.5, 0.5)),
        "reach",
    )


def _tabular_on(folder: Path, env: gym.Env) -> None:
    path = folder / "lake.pt"
    TabularQAgent(gym.make("FrozenLake-v1")).save(path)
    TabularQAgent.load(path, env=env)
