"""The wrong inputs of ``scripts/sweep_wrong_inputs.py``: over the agents, the learners, the
SE(3) densities, object models and NBP, grasp learning, the envs and the scripts, by kind.

Example:
    >>> cases = api_cases(tmp_path)
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.agents import Compaction, RLJCAgent, RLVCAgent, TabularQAgent
from vistask.experiments.wrong_input_geometry import (
    density_cases,
    grasp_cases,
    sample_density,
    sample_poses,
)
from vistask.experiments.wrong_input_misuse import misuse_cases, stepped
from vistask.experiments.wrong_inputs import Case, case, type_cases
from vistask.grasp import GraspLearner
from vistask.rlvc import RLJC, RLVC
from vistask.se3 import (
    SE3KDE,
    fit_density,
    select_bandwidth,
)

MAZE = "vistask/VisualMaze-v0"
CONTINUOUS_MAZE = "vistask/VisualMazeContinuous-v0"
CAR = "vistask/VisualMountainCar-v0"
PLACES = "vistask/PlaceNavigation-v0"
GRASP = "vistask/GraspTrial-v0"


@cache
def _maze() -> gym.Env:
    return gym.make(MAZE)


@cache
def _continuous_maze() -> gym.Env:
    return gym.make(CONTINUOUS_MAZE)


@cache
def _frozen_lake() -> gym.Env:
    return gym.make("FrozenLake-v1")


@cache
def _learned_maze_agent(folder: Path) -> Path:
    path = folder / "maze_agent.pt"
    agent = RLVCAgent(_maze(), n_words=64, databases=1, max_stages=3, seed=0)
    agent.learn(1000)
    agent.save(path)
    return path


@cache
def _learned_tabular(folder: Path) -> Path:
    path = folder / "tabular.pt"
    TabularQAgent(_frozen_lake(), seed=0).learn(200).save(path)
    return path


def _int_box_env() -> gym.Env:
    """The continuous maze with an integer action Box."""
    env = gym.make(CONTINUOUS_MAZE)
    env.action_space = gym.spaces.Box(-3, 3, (2,), np.int64)
    return env


def _box_env(low, high) -> gym.Env:
    env = gym.make(CONTINUOUS_MAZE)
    env.action_space = gym.spaces.Box(np.asarray(low, np.float32), np.asarray(high, np.float32))
    return env


def _agent_cases() -> Iterator[Case]:
    maze, cmaze = _maze, _continuous_maze
    yield from type_cases("RLVCAgent", RLVCAgent, env=maze())
    yield from type_cases("RLJCAgent", RLJCAgent, env=cmaze())
    yield from type_cases("TabularQAgent", TabularQAgent, env=_frozen_lake())
    yield from type_cases("Compaction", Compaction)
    yield from type_cases("RLVC", RLVC, n_features=40, n_actions=4, gamma=0.9)
    yield from type_cases("RLJC", RLJC, n_features=40, low=[-1.0], high=[1.0], gamma=0.9)
    for name, values in {
        "n_words": (0, 1, -5),
        "databases": (0, -1),
        "alpha": (0.0, 1.0, 1.5),
        "min_count": (0, -3, 2.5, True, "big"),
        "min_effect": (-0.1, 1.0, math.nan, "big", "0.5", 1j),
        "max_stages": (0,),
        "epsilon": (-0.1, 1.5),
        "n_envs": (0,),
        "max_keypoints": (-1,),
        "enlarge": (0, -2, 1.7, True, "big"),
        "contrast_threshold": (0.0, -1.0, math.inf),
        "vocabulary_groups": (0, -3),
        "novelty": (-0.1, math.nan, math.inf),
        "gamma": (1.0, -0.5, 2.0),
        "seed": (-1,),
    }.items():
        for value in values:
            yield case(
                "ranges",
                f"RLVCAgent({name}={value!r})",
                lambda n=name, v=value: RLVCAgent(maze(), **{n: v}),
                name,
            )
    for name, value in {"gamma": 1.5, "epsilon": 2.0, "n_words": 0, "alpha": -0.1}.items():
        yield case(
            "ranges",
            f"RLJCAgent({name}={value!r})",
            lambda n=name, v=value: RLJCAgent(cmaze(), **{n: v}),
            name,
        )
    for name, value in {
        "gamma": 1.5,
        "epsilon": -1,
        "learning_rate": 2.0,
        "initial_q": math.inf,
        "n_states": 0,
        "n_actions": -1,
    }.items():
        yield case(
            "ranges",
            f"TabularQAgent({name}={value!r})",
            lambda n=name, v=value: TabularQAgent(_frozen_lake(), **{n: v}),
            name,
        )
    for name, value in [("tolerance", -0.1), ("tolerance", 1.5), ("every", 0), ("structures", 0)]:
        yield case(
            "ranges",
            f"Compaction({name}={value!r})",
            lambda n=name, v=value: Compaction(**{n: v}),
            name,
        )
    for total in (0, -100):
        yield case(
            "ranges",
            f"agent.learn({total})",
            lambda t=total: RLVCAgent(maze()).learn(t),
            "total_timesteps",
        )
    yield case(
        "ranges",
        "TabularQAgent.learn(-5)",
        lambda: TabularQAgent(_frozen_lake()).learn(-5),
        "total_timesteps",
    )
    yield case(
        "ranges",
        "TabularQAgent.learn(checkpoint_every=0)",
        lambda: TabularQAgent(_frozen_lake()).learn(10, checkpoint="x.pt", checkpoint_every=0),
        "checkpoint_every",
    )
    # Learners
    for name, value in {
        "n_features": 0,
        "n_actions": 0,
        "gamma": 1.0,
        "alpha": 2.0,
        "min_count": 0,
        "compaction_tolerance": -1.0,
    }.items():
        kwargs = {"n_features": 40, "n_actions": 4, "gamma": 0.9, name: value}
        if name == "compaction_tolerance":
            kwargs["compaction"] = True
        yield case("ranges", f"RLVC({name}={value!r})", lambda k=kwargs: RLVC(**k), name)
    yield case("ranges", "RLJC(low=[1], high=[-1])", lambda: RLJC(40, [1.0], [-1.0], 0.9), "low")
    yield case(
        "ranges", "RLJC(low=[0, 0], high=[1])", lambda: RLJC(40, [0.0, 0.0], [1.0], 0.9), "low"
    )
    # Options that only matter with another
    yield case(
        "needs",
        "RLVC(compact_every=5) without compaction",
        lambda: RLVC(40, 4, 0.9, compact_every=5),
        "compact_every",
        "compaction",
    )
    yield case(
        "needs",
        "RLVC(compaction_tolerance=0.01) without compaction",
        lambda: RLVC(40, 4, 0.9, compaction_tolerance=0.01),
        "compaction_tolerance",
        "compaction",
    )
    yield case(
        "needs",
        "RLVC(compound_tolerances=(0.5,)) without use_compounds",
        lambda: RLVC(40, 4, 0.9, compound_tolerances=(0.5,)),
        "compound_tolerances",
        "use_compounds",
    )
    yield case(
        "needs",
        "TabularQAgent.learn(checkpoint_every=50) without checkpoint",
        lambda: TabularQAgent(_frozen_lake()).learn(10, checkpoint_every=50),
        "checkpoint_every",
        "checkpoint",
    )
    yield case(
        "needs",
        "fit_density(sigma_t_grid=...) with method='rule'",
        lambda: fit_density(sample_poses(20), sigma_t_grid=[0.01, 0.02]),
        "sigma_t_grid",
        "method",
    )
    yield case(
        "needs",
        "select_bandwidth(sigma_r_grid=...) with method='rule'",
        lambda: select_bandwidth(sample_poses(20), sigma_r_grid=[0.1]),
        "sigma_r_grid",
        "method",
    )
    yield case(
        "needs",
        "PlaceNavigation(cache_dir=..., disk_cache=False)",
        lambda: gym.make(PLACES, cache_dir="views", disk_cache=False),
        "cache_dir",
        "disk_cache",
    )
    # Action spaces
    yield case(
        "types", "RLJCAgent on an integer action Box", lambda: RLJCAgent(_int_box_env()), "action"
    )
    yield case(
        "ranges",
        "RLJCAgent on a Box with low == high",
        lambda: RLJCAgent(_box_env([0.0, 0.0], [0.0, 1.0])),
        "action",
    )
    yield case(
        "ranges",
        "RLJCAgent on a Box with infinite bounds",
        lambda: RLJCAgent(_box_env([-np.inf, 0.0], [1.0, 1.0])),
        "action",
    )
    yield case(
        "ranges",
        "RLJCAgent on an empty Box",
        lambda: RLJCAgent(_box_env(np.zeros(0), np.zeros(0))),
        "action",
    )
    yield case("types", "RLVCAgent on a continuous env", lambda: RLVCAgent(cmaze()), "action")
    yield case("types", "RLJCAgent on a discrete env", lambda: RLJCAgent(maze()), "action")
    yield case(
        "types",
        "RLVCAgent on FrozenLake (no images)",
        lambda: RLVCAgent(_frozen_lake()),
        "observation",
    )
    yield case(
        "types", "TabularQAgent on an image env", lambda: TabularQAgent(maze()), "observation"
    )


def _predict_cases(folder: Path) -> Iterator[Case]:
    def agent() -> RLVCAgent:
        return RLVCAgent.load(_learned_maze_agent(folder))

    def image(**kw) -> np.ndarray:
        return _maze().observation_space.sample()

    shape = _maze().observation_space.shape
    wrong = {
        "a bool image in a batch": lambda: [image(), image().astype(bool)],
        "a float64 image": lambda: image().astype(np.float64),
        "a float image in a list": lambda: [image().astype(np.float32)],
        "an image of another size": lambda: np.zeros((32, 32, 3), np.uint8),
        "a grey image": lambda: np.zeros(shape[:2], np.uint8),
        "a string": lambda: "image.png",
        "None": lambda: None,
        "an empty batch": lambda: np.zeros((0, *shape), np.uint8),
        "images of two sizes": lambda: [image(), np.zeros((10, 10, 3), np.uint8)],
        "a torch tensor of floats": lambda: torch.rand(shape),
    }
    for what, make in wrong.items():
        yield case(
            "types", f"agent.predict({what})", lambda m=make: agent().predict(m()), "observation"
        )
    yield case(
        "types",
        "agent.predict(deterministic='no')",
        lambda: agent().predict(image(), deterministic="no"),
        "deterministic",
    )
    yield case(
        "types",
        "TabularQAgent.predict(1.5)",
        lambda: TabularQAgent.load(_learned_tabular(folder)).predict(1.5),
        "state",
    )
    yield case(
        "types",
        "TabularQAgent.predict('3')",
        lambda: TabularQAgent.load(_learned_tabular(folder)).predict("3"),
        "state",
    )


def _file_cases(folder: Path) -> Iterator[Case]:
    other = folder / "other.pt"
    garbage = folder / "garbage.pt"
    garbage.write_bytes(b"\x00\x01 not a model")
    text = folder / "text.pt"
    text.write_text("hello")
    empty = folder / "empty.pt"
    empty.write_bytes(b"")

    def other_file() -> Path:
        sample_density().save(other)
        return other

    for cls in (RLVCAgent, RLJCAgent, TabularQAgent, SE3KDE, RLVC, GraspLearner):
        for path, what in (
            (garbage, "garbage"),
            (text, "text"),
            (empty, "an empty file"),
            (folder / "missing.pt", "a missing file"),
            (folder, "a folder"),
        ):
            yield case(
                "files", f"{cls.__name__}.load({what})", lambda c=cls, p=path: c.load(p), str(path)
            )
        if cls is not SE3KDE:
            yield case(
                "files",
                f"{cls.__name__}.load(an SE3KDE file)",
                lambda c=cls: c.load(other_file()),
                "SE3KDE",
            )
    yield case("types", "SE3KDE.save(path=3)", lambda: sample_density().save(3), "path")


def _other_env_cases(folder: Path) -> Iterator[Case]:
    saved = _learned_maze_agent(folder)
    others = {
        "another layout": lambda: gym.make(MAZE, layout_seed=7),
        "another photo seed": lambda: gym.make(MAZE, tapestry_seed=3),
        "the car": lambda: gym.make(CAR),
        "another window": lambda: gym.make(MAZE, window=48),
    }
    for what, make in others.items():
        yield case(
            "other env",
            f"RLVCAgent.load(maze agent, env={what}) then learn",
            lambda m=make: RLVCAgent.load(saved, env=m()).learn(200),
            "env",
        )
    tabular = _learned_tabular(folder)
    yield case(
        "other env",
        "TabularQAgent.load(FrozenLake agent, env=8x8 lake)",
        lambda: TabularQAgent.load(tabular, env=gym.make("FrozenLake-v1", map_name="8x8")),
        "env",
    )
    yield case(
        "other env",
        "TabularQAgent.load(FrozenLake agent, env=slippery off) then learn",
        lambda: TabularQAgent.load(tabular, env=gym.make("FrozenLake-v1", is_slippery=False)).learn(
            10
        ),
        "env",
    )


def _env_cases() -> Iterator[Case]:
    wrong = [
        (MAZE, "size", 0.0),
        (MAZE, "step", 0.0),
        (MAZE, "step", -0.1),
        (MAZE, "noise_std", -1.0),
        (MAZE, "gamma", 1.0),
        (MAZE, "window", 0),
        (MAZE, "pixels_per_unit", 0.0),
        (MAZE, "tile", 0),
        (MAZE, "photo", "no_such_photo.png"),
        (MAZE, "layout_seed", -1),
        (MAZE, "tapestry_seed", -1),
        (MAZE, "obstacles", ((0.5, 0.5, 0.4, 0.6),)),
        (MAZE, "exits", ()),
        (CONTINUOUS_MAZE, "step", -0.1),
        (CONTINUOUS_MAZE, "gamma", 1.5),
        (CONTINUOUS_MAZE, "window", -8),
        (CAR, "height", 0),
        (CAR, "road_width", 0),
        (CAR, "road_blur", -1.0),
        (CAR, "gamma", 1.5),
        (CAR, "tile", 0),
        (CAR, "pixels_per_unit", -1.0),
        (CAR, "road_seed", -2),
        (PLACES, "rows", 0),
        (PLACES, "cols", 1),
        (PLACES, "goal", 100),
        (PLACES, "extra_open", 1.5),
        (PLACES, "gamma", 1.0),
        (PLACES, "image_size", 0),
        (PLACES, "views_per_state", 0),
        (PLACES, "fovy", 0.0),
        (PLACES, "fovy", 200.0),
        (PLACES, "spacing", 0.0),
        (GRASP, "placement_range", 5.0),
        (GRASP, "lift_height", -0.1),
        (GRASP, "reach_tolerance", (-1.0, 0.4)),
        (GRASP, "image_size", 0),
        (GRASP, "n_distractors", -1),
        (GRASP, "n_distractors", 10),
        (GRASP, "tip_probability", 1.5),
        (GRASP, "control_freq", 0),
        (GRASP, "cameras", ("nowhere",)),
        (GRASP, "object_kind", "teapot"),
        (GRASP, "distractors", ("unicorn",)),
        (GRASP, "pregrasp_distance", -0.01),
        (GRASP, "lift_threshold", 1.0),
    ]
    for env_id, name, value in wrong:
        yield case(
            "env kwargs",
            f"gym.make({env_id!r}, {name}={value!r})",
            lambda e=env_id, n=name, v=value: gym.make(e, **{n: v}).reset(seed=0),
            name,
        )
    for env_id in (MAZE, CAR):
        yield case(
            "env kwargs",
            f"gym.make({env_id!r}, speed=2)",
            lambda e=env_id: gym.make(e, speed=2),
            "speed",
        )
        yield case(
            "types",
            f"gym.make({env_id!r}, gamma='0.9')",
            lambda e=env_id: gym.make(e, gamma="0.9"),
            "gamma",
        )
    yield case(
        "types",
        "gym.make(GRASP, placement_range='0.1')",
        lambda: gym.make(GRASP, placement_range="0.1"),
        "placement_range",
    )
    yield case(
        "types",
        "gym.make(GRASP, cameras='front')",
        lambda: gym.make(GRASP, cameras="front").reset(seed=0),
        "cameras",
    )
    yield case(
        "types", "gym.make(MAZE).reset(seed=1.5)", lambda: gym.make(MAZE).reset(seed=1.5), "seed"
    )
    for action in (4, -1, 1.5, "up"):
        yield case(
            "ranges",
            f"maze env.step({action!r})",
            lambda a=action: stepped(gym.make(MAZE), a),
            "action",
        )
    for action in ([2.0, 0.0], [math.nan], [4.0]):
        yield case(
            "ranges",
            f"continuous maze env.step({action!r})",
            lambda a=action: stepped(gym.make(CONTINUOUS_MAZE), np.asarray(a, np.float32)),
            "action",
        )


def api_cases(folder: Path) -> list[Case]:
    """The cases over the Python API; ``folder`` holds the files they write and read."""
    folder.mkdir(parents=True, exist_ok=True)
    return [
        *_agent_cases(),
        *_predict_cases(folder),
        *_file_cases(folder),
        *_other_env_cases(folder),
        *density_cases(),
        *grasp_cases(),
        *_env_cases(),
        *misuse_cases(folder),
    ]
