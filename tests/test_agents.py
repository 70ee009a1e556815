"""Wrappers and agents: Gymnasium compliance, end-to-end RLVC on a small maze, persistence."""

import json

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from vistask.agents import RLVCAgent, TabularQAgent
from vistask.envs import MazeOracle, VisualMazeEnv, evaluate_policy, start_positions
from vistask.features import VisualFeatureExtractor
from vistask.rlvc import VisualClassifier, collect
from vistask.experiments.train_rlvc import agent_policy, train_rlvc, true_grid_policy
from vistask.wrappers import VisualClasses, VisualFeatures

SMALL = dict(
    obstacles=((0.45, 0.0, 0.55, 0.6),),
    exits=((0.0, 0.0, 0.2, 0.2), (0.8, 0.0, 1.0, 0.2)),
    step=0.2,
    window=64,
    pixels_per_unit=240.0,
)


@pytest.fixture(scope="module")
def small_agent() -> RLVCAgent:
    env = VisualMazeEnv(**SMALL)
    return RLVCAgent(env, n_words=512, seed=0).learn(4000, progress_bar=False)


def test_rlvc_reaches_near_oracle_return_on_a_small_maze(small_agent):
    maze = small_agent.env.unwrapped
    starts = start_positions(maze.geometry, 60)
    oracle = evaluate_policy(maze, MazeOracle.solve(maze.geometry).as_policy(), starts).mean
    rlvc = evaluate_policy(maze, agent_policy(small_agent), starts).mean
    rng = np.random.default_rng(0)
    random = evaluate_policy(maze, lambda obs, pos: rng.integers(4, size=len(obs)), starts).mean
    assert rlvc >= 0.85 * oracle > random
    assert small_agent.rlvc.n_classes > 4
    # The agent keeps the interactions it learned from, with positions for the ceiling.
    database = small_agent.database
    assert len(database) == small_agent.num_timesteps == 4000
    assert database.positions is not None and len(database.positions) == len(database.presence)
    ceiling = evaluate_policy(maze, true_grid_policy(maze.geometry, database, grid=8), starts)
    assert ceiling.mean >= 0.9 * oracle


def test_true_grid_aggregation_of_random_interactions_is_near_the_oracle():
    maze = VisualMazeEnv(**SMALL)
    starts = start_positions(maze.geometry, 60)
    oracle = evaluate_policy(maze, MazeOracle.solve(maze.geometry).as_policy(), starts).mean
    database = collect(maze, 3000, seed=0)
    ceiling = evaluate_policy(maze, true_grid_policy(maze.geometry, database, grid=8), starts)
    coarse = evaluate_policy(maze, true_grid_policy(maze.geometry, database, grid=1), starts)
    assert ceiling.mean >= 0.9 * oracle > coarse.mean
    database.positions = None
    with pytest.raises(ValueError, match="true positions"):
        true_grid_policy(maze.geometry, database)


def test_visual_features_wrapper_passes_check_env(small_agent):
    env = VisualFeatures(gym.make("vistask/VisualMaze-v0", **SMALL), small_agent.extractor)
    assert env.observation_space == gym.spaces.MultiBinary(512)
    check_env(env.unwrapped)  # the raw env
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (512,) and obs.dtype == np.int8 and obs.sum() > 0


def test_visual_classes_wrapper_matches_the_agent_and_passes_check_env(small_agent):
    env = VisualClasses(gym.make("vistask/VisualMaze-v0", **SMALL), small_agent.classifier)
    check_env(env, skip_render_check=True)
    assert env.observation_space == gym.spaces.Discrete(small_agent.rlvc.n_classes)
    raw = VisualMazeEnv(**SMALL)
    image, _ = raw.reset(seed=3)
    state, _ = env.reset(seed=3)
    assert state == small_agent.classifier(image)


def test_wrappers_reject_non_image_observations(small_agent):
    cartpole = gym.make("CartPole-v1")
    with pytest.raises(TypeError, match="image observations"):
        VisualFeatures(cartpole, small_agent.extractor)
    with pytest.raises(TypeError, match="image observations"):
        VisualClasses(cartpole, small_agent.classifier)
    with pytest.raises(TypeError, match="image observations"):
        RLVCAgent(cartpole)


def test_agent_predicts_single_images_and_batches(small_agent):
    maze = VisualMazeEnv(**SMALL)
    images = np.stack([maze.percept_at(p) for p in start_positions(maze.geometry, 5)])
    batch, _ = small_agent.predict(images)
    singles = [small_agent.predict(image)[0] for image in images]
    assert batch.tolist() == singles
    with pytest.raises(TypeError, match="uint8"):
        small_agent.predict(images.astype(np.float32))


def test_agent_save_load_round_trip_gives_identical_classes(small_agent, tmp_path):
    small_agent.save(tmp_path / "agent.pt")
    loaded = RLVCAgent.load(tmp_path / "agent.pt", VisualMazeEnv(**SMALL))
    maze = VisualMazeEnv(**SMALL)
    images = [maze.percept_at(p) for p in start_positions(maze.geometry, 30)]
    assert torch.equal(loaded.classifier.classify(images), small_agent.classifier.classify(images))
    assert np.array_equal(
        loaded.predict(np.stack(images))[0], small_agent.predict(np.stack(images))[0]
    )
    # Files saved before ``databases`` replaced ``database_size`` still load.
    state = torch.load(tmp_path / "agent.pt", weights_only=True)
    state["config"]["database_size"] = None
    del state["config"]["databases"], state["config"]["keep_databases"]
    del state["config"]["max_blocked"], state["config"]["n_envs"]
    torch.save(state, tmp_path / "old.pt")
    assert RLVCAgent.load(tmp_path / "old.pt").classifier.n_classes == loaded.classifier.n_classes


def test_classifier_load_refuses_a_mismatched_vocabulary(small_agent, tmp_path):
    small_agent.classifier.save(tmp_path / "classes.pt")
    other = VisualFeatureExtractor(
        small_agent.extractor.keypoints, small_agent.extractor.centroids + 1.0
    )
    with pytest.raises(ValueError, match="vocabulary mismatch"):
        VisualClassifier.load(tmp_path / "classes.pt", other)
    same = VisualClassifier.load(tmp_path / "classes.pt", small_agent.extractor)
    assert same.n_classes == small_agent.classifier.n_classes


def test_unlearned_agent_explains_itself():
    agent = RLVCAgent(VisualMazeEnv(**SMALL))
    with pytest.raises(RuntimeError, match="not learned"):
        agent.predict(np.zeros((64, 64, 3), np.uint8))


def test_tabular_q_learning_solves_a_deterministic_gridworld(tmp_path):
    env = gym.make("FrozenLake-v1", is_slippery=False)
    agent = TabularQAgent(env, learning_rate=0.5, gamma=0.9, epsilon=0.3, seed=0)
    agent.learn(6000)
    state, _ = env.reset(seed=0)
    for _ in range(20):
        state, reward, terminated, _, _ = env.step(int(agent.predict(state)[0]))
        if terminated:
            break
    assert reward == 1.0
    agent.save(tmp_path / "q.pt")
    loaded = TabularQAgent.load(tmp_path / "q.pt", env)
    np.testing.assert_array_equal(loaded.q, agent.q)
    with pytest.raises(ValueError, match="state ids"):
        agent.predict(99)
    with pytest.raises(TypeError, match="Discrete observation"):
        TabularQAgent(gym.make("vistask/VisualMaze-v0"))


def test_later_databases_are_collected_on_the_current_classes_and_kept_or_replaced():
    kept = RLVCAgent(VisualMazeEnv(**SMALL), n_words=128, databases=(0.6, 0.4), seed=0)
    kept.learn(2500, progress_bar=False)
    refreshed = RLVCAgent(
        VisualMazeEnv(**SMALL),
        n_words=128,
        databases=(0.5, 0.5),
        keep_databases=False,
        refresh_every=3,
        seed=0,
    )
    refreshed.learn(2500, progress_bar=False)
    assert kept.num_timesteps == refreshed.num_timesteps == 2500
    assert len(refreshed.rlvc.history) >= 4  # three stages on the first database, more later
    assert kept.rlvc.n_classes > 1 and refreshed.rlvc.n_classes > 1
    with pytest.raises(ValueError, match="summing to 1"):
        RLVCAgent(VisualMazeEnv(**SMALL), databases=(0.5, 0.2))
    with pytest.raises(ValueError, match="cannot fill"):
        RLVCAgent(VisualMazeEnv(**SMALL), databases=(0.999, 0.001)).learn(100)
    assert RLVCAgent(VisualMazeEnv(**SMALL), databases=4).databases == (0.25,) * 4
    with pytest.raises(ValueError, match=">= 1"):
        RLVCAgent(VisualMazeEnv(**SMALL), databases=0)


def test_train_rlvc_writes_a_summary_that_its_saved_agent_reproduces(tmp_path):
    summary = train_rlvc(
        env_kwargs=SMALL,
        interactions=2000,
        n_words=256,
        vocabulary_groups=8,
        blocked_is_stuck=True,
        max_keypoints=20,
        eval_starts=30,
        out=tmp_path,
        progress=False,
    )
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    for key in ("return_ratio", "rlvc_return", "oracle_return", "stages", "classes"):
        assert on_disk[key] == pytest.approx(summary[key])
    assert summary["interactions"] == 2000 and summary["vocabulary_size"] == 256
    assert len(summary["databases"]) == 3  # the paper's protocol by default
    assert summary["selected_features"] <= summary["classes"] - 1  # a test per internal node
    assert summary["return_ratio"] == pytest.approx(
        summary["rlvc_return"] / summary["oracle_return"]
    )
    for picture in ("value_functions.png", "rlvc_policy.png", "oracle_policy.png"):
        assert (tmp_path / picture).stat().st_size > 0
    assert any((tmp_path / "tensorboard").iterdir())
    # The saved agent acts as the one that was scored, from the same starts.
    env = gym.make("vistask/VisualMaze-v0", **SMALL)
    agent = RLVCAgent.load(tmp_path / "rlvc_agent.pt", env)
    assert agent.blocked_is_stuck and agent.rlvc.blocked_is_stuck
    assert agent.extractor.keypoints.max_keypoints == summary["max_keypoints"] == 20
    result = evaluate_policy(env, agent_policy(agent), start_positions(env.unwrapped.geometry, 30))
    assert result.mean == pytest.approx(summary["rlvc_return"])
    assert summary["starts_never_exiting"] == int((result.returns == 0).sum())
