"""RLJC: the joint tree against brute force, the threshold split search, the joint Q solver, the
learner on a synthetic problem, and RLJCAgent on a small continuous-direction maze."""

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from small_maze import SMALL

from vistask.agents import RLJCAgent, RLVCAgent
from vistask.envs import MazeOracle, evaluate_policy, start_positions
from vistask.experiments.tasks import MazeTask
from vistask.rlvc import (
    RLJC,
    InteractionDatabase,
    JointClassifier,
    JointTree,
    Split,
    ThresholdSplit,
    collect,
    find_threshold_splits,
    joint_values,
)
from vistask.wrappers import JointClasses


def random_tree(rng: np.random.Generator, n_features: int = 6, splits: int = 25) -> JointTree:
    tree = JointTree(n_features, [-1.0, 0.0], [1.0, 2.0])
    for _ in range(splits):
        c = int(rng.integers(tree.n_classes))
        if rng.random() < 0.5:
            tree.split_feature(c, int(rng.integers(n_features)))
        else:
            dim = int(rng.integers(2))
            low, high = tree.box_low[c, dim], tree.box_high[c, dim]
            tree.split_action(c, dim, float(rng.uniform(low, high)))
    return tree


def test_compatible_classes_equal_brute_force_on_random_trees():
    rng = np.random.default_rng(0)
    for _ in range(20):
        tree = random_tree(rng)
        presence = torch.as_tensor(rng.random((30, 6)) < 0.5)
        rows, classes = tree.compatible(presence)
        got = torch.zeros(30, tree.n_classes, dtype=torch.bool)
        got[rows, classes] = True
        # Class j is compatible with x iff some action reaches j from x: the centre of j's
        # box satisfies every action test on j's path, so it reaches j iff x does.
        centres = (tree.box_low + tree.box_high) / 2
        percepts = torch.arange(30).repeat_interleave(tree.n_classes)
        reached = tree.classify(presence, torch.as_tensor(np.tile(centres, (30, 1))), percepts)
        expected = reached.view(30, -1) == torch.arange(tree.n_classes)
        assert torch.equal(got, expected)
        # The compatible boxes tile the action space, and an action lands in the box of the
        # class that classify gives.
        volume = np.prod(tree.box_high - tree.box_low, axis=1)
        assert np.allclose(got.double().numpy() @ volume, 4.0)
        actions = rng.uniform([-1, 0], [1, 2], size=(30, 2))
        joint = tree.classify(presence, actions)
        assert got[torch.arange(30), joint].all()
        low, high = tree.box_low[joint.numpy()], tree.box_high[joint.numpy()]
        assert np.all((low <= actions) & (actions <= high))


def test_cells_group_percepts_with_the_same_compatible_classes():
    rng = np.random.default_rng(1)
    tree = random_tree(rng)
    presence = torch.as_tensor(rng.random((200, 6)) < 0.5)
    cell, member_cell, member_class = tree.cells(presence)
    rows, classes = tree.compatible(presence)
    sets = [frozenset(classes[rows == i].tolist()) for i in range(200)]
    for i in range(0, 200, 7):
        for j in range(200):
            assert (cell[i] == cell[j]) == (sets[i] == sets[j])
        members = frozenset(member_class[member_cell == cell[i]].tolist())
        assert members == sets[i]


def test_joint_tree_round_trips_and_refuses_bad_splits():
    tree = random_tree(np.random.default_rng(2))
    again = JointTree.from_state_dict(tree.state_dict())
    assert again.leaf_class == tree.leaf_class
    assert np.array_equal(again.box_low, tree.box_low)
    assert np.array_equal(again.box_high, tree.box_high)
    with pytest.raises(ValueError, match="does not cut"):
        JointTree(3, [0.0], [1.0]).split_action(0, 0, 1.5)
    with pytest.raises(ValueError, match="dimension"):
        JointTree(3, [0.0], [1.0]).split_action(0, 1, 0.5)
    with pytest.raises(ValueError, match="low < high"):
        JointTree(3, [1.0], [0.0])
    boxes = tree.box_low.copy(), tree.box_high.copy()
    for bad in (-1, tree.n_classes):  # refused before anything changes
        with pytest.raises(ValueError, match="no class"):
            tree.split_action(bad, 0, 0.0)
        with pytest.raises(ValueError, match="no class"):
            tree.split_feature(bad, 0)
    assert np.array_equal(tree.box_low, boxes[0]) and np.array_equal(tree.box_high, boxes[1])


def test_threshold_split_search_finds_the_brute_force_best_cut():
    rng = np.random.default_rng(3)
    n = 300
    states = torch.as_tensor(rng.integers(3, size=n))
    actions = torch.as_tensor(rng.uniform(-1, 1, size=(n, 2)))
    cut = {0: 0.3, 1: -0.5}  # class 2's TD errors do not depend on the action
    deltas = torch.as_tensor(rng.normal(size=n) * 0.1)
    for s, t in cut.items():
        mine = states == s
        deltas[mine] += (actions[mine, s] >= t).double()
    splits = {split.state: split for split in find_threshold_splits(states, actions, deltas, 3)}
    assert set(splits) == {0, 1}
    for s, t in cut.items():
        assert splits[s].dim == s and abs(splits[s].threshold - t) < 0.05
        # Brute force: the variance reduction of every midpoint of the class's sorted actions.
        d, a = deltas[states == s].numpy(), actions[states == s, s].numpy()
        values = np.sort(a)

        def sse(x):
            return ((x - x.mean()) ** 2).sum()

        best = max(
            sse(d) - sse(d[a < m]) - sse(d[a >= m])
            for m in (values[:-1] + values[1:]) / 2
            if 10 <= (a < m).sum() <= len(a) - 10
        )
        assert splits[s].reduction == pytest.approx(best)


def test_joint_values_equal_a_plain_value_iteration():
    rng = np.random.default_rng(4)
    n, n_classes, n_cells = 400, 6, 4
    classes = torch.as_tensor(rng.integers(n_classes, size=n))
    rewards = torch.as_tensor(rng.normal(size=n))
    next_cells = torch.as_tensor(rng.integers(n_cells, size=n))
    terminal = torch.as_tensor(rng.random(n) < 0.1)
    members = [(c, j) for c in range(n_cells) for j in range(n_classes) if rng.random() < 0.5]
    members += [(c, c) for c in range(n_cells)]
    member_cell = torch.tensor([c for c, _ in members])
    member_class = torch.tensor([j for _, j in members])
    q, _ = joint_values(
        classes, rewards, next_cells, terminal, member_cell, member_class, n_classes, 0.8
    )
    # A plain loop over interactions, iterated to its fixed point.
    expected = np.zeros(n_classes)
    for _ in range(300):
        v = [max(expected[j] for c2, j in members if c2 == c) for c in range(n_cells)]
        target = rewards.numpy() + 0.8 * np.where(terminal.numpy(), 0.0, np.take(v, next_cells))
        expected = np.array([target[classes.numpy() == j].mean() for j in range(n_classes)])
    assert np.allclose(q.numpy(), expected, atol=1e-6)


def synthetic_database(seed: int = 0) -> InteractionDatabase:
    """One-step episodes: with feature 0 present, actions >= 0.3 pay 1; without it, actions
    below -0.2 pay 1. Other features are noise."""
    rng = np.random.default_rng(seed)
    m, n, f = 200, 4000, 6
    presence = torch.as_tensor(rng.random((m, f)) < 0.5)
    obs = torch.as_tensor(rng.integers(m, size=n))
    a = rng.uniform(-1, 1, size=(n, 1))
    feature = presence[obs, 0].numpy()
    r = np.where(feature, a[:, 0] >= 0.3, a[:, 0] < -0.2).astype(float)
    terminal = torch.ones(n, dtype=torch.bool)
    return InteractionDatabase(
        presence, obs, torch.as_tensor(a), torch.as_tensor(r), obs.clone(), terminal
    )


def test_rljc_splits_on_the_feature_and_on_the_action_thresholds():
    db = synthetic_database()
    rljc = RLJC(db.n_features, [-1.0], [1.0], gamma=0.9).learn(db, progress=False)
    tree = rljc.structure
    assert tree.selected_features == [0]
    thresholds = sorted(t for t, d in zip(tree.threshold, tree.dim, strict=True) if d >= 0)
    assert any(abs(t - 0.3) < 0.05 for t in thresholds)
    assert any(abs(t + 0.2) < 0.05 for t in thresholds)
    greedy = rljc.greedy(db.presence)[:, 0]
    present = db.presence[:, 0].numpy()
    assert np.all(greedy[present] >= 0.3) and np.all(greedy[~present] < -0.2)
    explored = rljc.explore(db.presence, 0.5, np.random.default_rng(0))
    assert explored.shape == (len(db.presence), 1) and np.all(np.abs(explored) <= 1)
    again = RLJC.from_state_dict(rljc.state_dict())
    assert np.array_equal(again.greedy(db.presence), rljc.greedy(db.presence))


def test_classes_moved_along_with_splits_equal_classes_found_from_the_root():
    db = synthetic_database(seed=5)
    rljc = RLJC(db.n_features, [-1.0], [1.0], gamma=0.9)
    rng = np.random.default_rng(5)
    classes = rljc.structure.classify(db.presence, db.actions, db.obs)
    pair_rows, pair_classes = rljc.structure.compatible(db.presence)
    for _ in range(6):  # stages of random splits, each class at most once a stage
        splits = {}
        for state in rng.choice(rljc.n_classes, size=min(3, rljc.n_classes), replace=False):
            low, high = rljc.structure.box_low[state, 0], rljc.structure.box_high[state, 0]
            if rng.random() < 0.5:
                splits[int(state)] = ThresholdSplit(int(state), 0, rng.uniform(low, high), 1, 0)
            else:
                splits[int(state)] = Split(int(state), int(rng.integers(6)), 0, 1.0, 0.0)
        classes, pair_rows, pair_classes = rljc._apply(splits, db, classes, pair_rows, pair_classes)
        assert torch.equal(classes, rljc.structure.classify(db.presence, db.actions, db.obs))
        rows, expected = rljc.structure.compatible(db.presence)
        order = np.lexsort((pair_classes.numpy(), pair_rows.numpy()))
        assert torch.equal(pair_rows[order], rows) and torch.equal(pair_classes[order], expected)


def test_collect_keeps_continuous_actions_given_as_a_flat_batch():
    env = gym.make("vistask/VisualMazeContinuous-v0", **SMALL)
    flat = collect(env, 40, lambda obs, rng: rng.uniform(-3, 3, size=len(obs)), n_envs=4)
    assert flat.actions.shape == (40, 1) and flat.actions.dtype == np.float64
    assert not np.all(flat.actions == np.round(flat.actions))


def test_rljc_refuses_a_database_of_discrete_actions():
    db = synthetic_database()
    db.actions = torch.zeros(len(db), dtype=torch.long)
    with pytest.raises(ValueError, match="continuous actions"):
        RLJC(db.n_features, [-1.0], [1.0], gamma=0.9).learn(db, progress=False)


@pytest.fixture(scope="module")
def small_agent() -> RLJCAgent:
    env = gym.make("vistask/VisualMazeContinuous-v0", **SMALL)
    return RLJCAgent(env, n_words=512, seed=0).learn(6000)


def test_rljc_agent_learns_a_small_continuous_maze(small_agent):
    maze = small_agent.env.unwrapped
    starts = start_positions(maze.geometry, 60)
    oracle = MazeOracle.solve(maze.geometry, n_directions=32).as_policy()
    best = evaluate_policy(maze, oracle, starts).mean
    rng = np.random.default_rng(0)
    random = evaluate_policy(maze, lambda p, s: rng.uniform(-np.pi, np.pi, len(p)), starts).mean
    rljc = evaluate_policy(maze, lambda p, s: small_agent.predict(p)[0], starts).mean
    assert rljc > 0.5 * best > random
    assert small_agent.rljc.structure.action_tests > 0


def test_rljc_agent_acts_inside_the_action_space_and_round_trips(small_agent, tmp_path):
    env = small_agent.env
    obs, _ = env.reset(seed=3)
    action, _ = small_agent.predict(obs)
    assert env.action_space.contains(action)
    batch = np.stack([env.reset(seed=s)[0] for s in range(12)])
    for deterministic in (True, False):
        actions, _ = small_agent.predict(batch, deterministic=deterministic)
        assert actions.shape == (12, 1) and all(env.action_space.contains(a) for a in actions)
    small_agent.save(tmp_path / "rljc.pt")
    loaded = RLJCAgent.load(tmp_path / "rljc.pt", env=env)
    assert np.array_equal(loaded.predict(batch)[0], small_agent.predict(batch)[0])
    with pytest.raises(ValueError, match="RLJCAgent, not a RLVCAgent"):
        RLVCAgent.load(tmp_path / "rljc.pt")


# The angle in radians is deliberate; check_env advises a [-1, 1] box.
@pytest.mark.filterwarnings("ignore:.*symmetric and normalized")
def test_joint_classes_wrapper_exposes_cells_and_boxes(small_agent, tmp_path):
    env = JointClasses(gym.make("vistask/VisualMazeContinuous-v0", **SMALL), small_agent.classifier)
    check_env(env.unwrapped, skip_render_check=True)
    mask, _ = env.reset(seed=0)
    assert env.observation_space.contains(mask) and mask.sum() >= 1
    # The boxes of a cell tile the action space.
    widths = (env.box_high - env.box_low)[mask == 1, 0]
    assert widths.sum() == pytest.approx(env.action_space.high[0] - env.action_space.low[0])
    small_agent.classifier.save(tmp_path / "joint.pt")
    again = JointClassifier.load(tmp_path / "joint.pt")
    obs, _ = env.unwrapped.reset(seed=0)
    assert np.array_equal(again(obs), small_agent.classifier(obs))


def test_each_agent_names_the_other_for_the_wrong_action_space():
    with pytest.raises(TypeError, match="RLJCAgent"):
        RLVCAgent(gym.make("vistask/VisualMazeContinuous-v0", **SMALL))
    with pytest.raises(TypeError, match="RLVCAgent"):
        RLJCAgent(gym.make("vistask/VisualMaze-v0", **SMALL))


def test_train_script_picks_rljc_for_continuous_actions_and_writes_its_summary(tmp_path):
    command = [
        sys.executable,
        "scripts/train_rlvc.py",
        "--env",
        "vistask/VisualMazeContinuous-v0",
        "--env-kwargs",
        json.dumps(SMALL),
        "--interactions",
        "1000",
        "--out",
        str(tmp_path),
        "--no-progress",
    ]
    subprocess.run(command, check=True, capture_output=True, cwd=Path(__file__).parents[1])
    summary = json.loads((tmp_path / "summary.json").read_text())
    for key in ("joint_classes", "perceptual_cells", "rlvc_classes_x4", "seconds"):
        assert summary[key] > 0
    assert summary["interactions"] == 1000
    assert summary["return_ratio"] == pytest.approx(
        summary["rljc_return"] / summary["oracle_return"]
    )
    # Both mazes are scored from the same starts on one scale: the four-action oracle is
    # below the 32-direction one.
    assert summary["rlvc_discrete_oracle_return"] < summary["oracle_return"]
    for picture in ("rljc_policy.png", "oracle_policy.png", "joint_space.png"):
        assert (tmp_path / picture).stat().st_size > 0
    assert any((tmp_path / "tensorboard").rglob("events.out.tfevents.*"))
    env = gym.make("vistask/VisualMazeContinuous-v0", **SMALL)
    agent = RLJCAgent.load(tmp_path / "rljc_agent.pt", env)
    task = MazeTask(env.unwrapped)
    assert task.evaluate(lambda p, s: agent.predict(p)[0]).mean == pytest.approx(
        summary["rljc_return"]
    )
