"""Wrappers and agents: Gymnasium compliance, end-to-end RLVC on a small maze, persistence."""

import json
import multiprocessing
import warnings
from dataclasses import asdict

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from small_maze import SMALL, small_maze
from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback

from vistask.agents import Compaction, RLJCAgent, RLVCAgent, TabularQAgent
from vistask.envs import MazeOracle, VisualMazeEnv, evaluate_policy, start_positions
from vistask.experiments.hyperparams import agent_kwargs, hyperparams_for, parse_overrides
from vistask.experiments.tasks import MazeTask
from vistask.experiments.train_rljc import train_rljc
from vistask.experiments.train_rlvc import (
    agent_policy,
    seen_percepts_policy,
    train_rlvc,
    true_grid_policy,
)
from vistask.features import VisualFeatureExtractor, propose
from vistask.features.compounds import presence_of_candidates
from vistask.rlvc import ClassBDD, ClassTree, VisualClassifier, collect
from vistask.wrappers import VisualClasses, VisualFeatures

FUSED = Compaction(structures=3, during_learning=True)  # three class structures, fused


@pytest.fixture(scope="module")
def small_agent() -> RLVCAgent:
    return RLVCAgent(small_maze(), n_words=512, nearest_seen=True, seed=0).learn(4000)


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
    task = MazeTask(maze, 1)
    ceiling = evaluate_policy(maze, true_grid_policy(task, database, grid=8), starts)
    assert ceiling.mean >= 0.9 * oracle
    # Acting as on the database's percept nearest in true state scores like the agent.
    greedy = small_agent.rlvc.greedy(database.presence).numpy()
    seen = evaluate_policy(maze, seen_percepts_policy(task, database, greedy), starts)
    assert seen.mean >= 0.85 * oracle
    with pytest.raises(ValueError, match="one action per percept"):
        seen_percepts_policy(task, database, greedy[1:])


def test_true_grid_aggregation_of_random_interactions_is_near_the_oracle():
    maze = VisualMazeEnv(**SMALL)
    starts = start_positions(maze.geometry, 60)
    oracle = evaluate_policy(maze, MazeOracle.solve(maze.geometry).as_policy(), starts).mean
    database = collect(maze, 3000, seed=0)
    task = MazeTask(maze, 1)
    ceiling = evaluate_policy(maze, true_grid_policy(task, database, grid=8), starts)
    coarse = evaluate_policy(maze, true_grid_policy(task, database, grid=1), starts)
    assert ceiling.mean >= 0.9 * oracle > coarse.mean
    database.positions = None
    with pytest.raises(ValueError, match="true states"):
        true_grid_policy(task, database)


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
    # New percepts take the class of the nearest percepts learned on, in the agent, in its
    # classifier and in a classifier saved on its own.
    presence = small_agent.extractor.presence(images)
    nearest = small_agent.rlvc.seen.nearest(presence)
    assert torch.equal(small_agent.classifier.classify(images), nearest)
    small_agent.classifier.save(tmp_path / "classes.pt")
    assert torch.equal(VisualClassifier.load(tmp_path / "classes.pt").classify(images), nearest)
    with pytest.raises(RuntimeError, match=r"no env to learn on: load it with load\(path, env"):
        RLVCAgent.load(tmp_path / "agent.pt").learn(1000)


def test_min_effect_reaches_the_learner_and_is_saved(tmp_path):
    agent = RLVCAgent(small_maze(), n_words=64, n_envs=8, min_effect=0.05, seed=0).learn(1000)
    assert agent.rlvc.min_effect == 0.05
    agent.save(tmp_path / "agent.pt")
    loaded = RLVCAgent.load(tmp_path / "agent.pt", small_maze())
    assert loaded.min_effect == 0.05 and loaded.rlvc.min_effect == 0.05


def test_an_agent_on_enlarged_views_keeps_them_when_saved(tmp_path):
    agent = RLVCAgent(small_maze(), n_words=64, n_envs=8, enlarge=2, seed=0).learn(1000)
    assert agent.extractor.keypoints.enlarge == 2
    # min_count="auto" splits enlarged views on 5 interactions a side, other views on 10;
    # min_effect="auto" asks a margin of 0.01 of the value range of enlarged views, else 0.
    assert agent.split_count == agent.rlvc.min_count == 5
    assert agent.split_margin == agent.rlvc.min_effect == 0.01
    assert RLVCAgent(small_maze()).split_count == 10
    assert RLVCAgent(small_maze()).split_margin == 0.0
    assert RLVCAgent(small_maze(), min_count=7).split_count == 7
    assert RLVCAgent(small_maze(), enlarge=2, min_effect=0).split_margin == 0.0
    agent.save(tmp_path / "agent.pt")
    loaded = RLVCAgent.load(tmp_path / "agent.pt")
    assert loaded.enlarge == loaded.extractor.keypoints.enlarge == 2
    maze = VisualMazeEnv(**SMALL)
    images = np.stack([maze.percept_at(p) for p in start_positions(maze.geometry, 30)])
    assert np.array_equal(loaded.predict(images)[0], agent.predict(images)[0])
    # Files saved before ``enlarge`` existed saw every view as it is.
    assert RLVCAgent._params_from_state({"seed": 0})["enlarge"] == 1
    # By default ("auto") views under 56 pixels of a photograph are enlarged, and the
    # decision is the saved vocabulary's.
    small_views = gym.make("vistask/VisualMaze-v0", **{**SMALL, "window": 32})
    auto = RLVCAgent(small_views, n_words=64, n_envs=8, seed=0).learn(1000)
    assert auto.enlarge == "auto" and auto.extractor.keypoints.enlarge == 2
    auto.save(tmp_path / "auto.pt")
    loaded = RLVCAgent.load(tmp_path / "auto.pt")
    assert loaded.extractor.keypoints.enlarge == 2 and loaded.split_count == 5
    assert loaded.min_effect == "auto" and loaded.rlvc.min_effect == 0.01
    # Files saved before ``min_effect`` existed split on any significant difference.
    assert RLVCAgent._params_from_state({"seed": 0})["min_effect"] == 0.0
    with pytest.raises(ValueError, match="enlarge must be 'auto' or an integer >= 1"):
        RLVCAgent(small_maze(), enlarge="big")
    with pytest.raises(ValueError, match="min_count must be 'auto' or an integer >= 2"):
        RLVCAgent(small_maze(), min_count="big")
    with pytest.raises(ValueError, match=r"min_effect must be 'auto' or in \[0, 1\)"):
        RLVCAgent(small_maze(), min_effect="0.5")


def test_load_refuses_other_spaces_and_bad_files(small_agent, tmp_path):
    path = tmp_path / "agent.pt"
    small_agent.save(path)
    assert RLVCAgent.load(path).env_id == "vistask/VisualMaze-v0"
    with pytest.raises(ValueError, match=r"\(48, 48, 3\)"):
        RLVCAgent.load(path, env=gym.make("vistask/VisualMaze-v0", **{**SMALL, "window": 48}))
    with pytest.raises(ValueError, match="observation must be one image of shape"):
        small_agent.predict(np.zeros((48, 48, 3), np.uint8))
    (tmp_path / "truncated.pt").write_bytes(path.read_bytes()[:1000])
    (tmp_path / "garbage.pt").write_bytes(b"not a model")
    for name in ("truncated.pt", "garbage.pt"):
        with pytest.raises(ValueError, match=f"{name} cannot be read as a saved RLVCAgent"):
            RLVCAgent.load(tmp_path / name)
    tabular = TabularQAgent(None, n_states=3, n_actions=2)
    tabular.save(tmp_path / "q.pt")
    with pytest.raises(ValueError, match="holds a TabularQAgent, not a RLVCAgent"):
        RLVCAgent.load(tmp_path / "q.pt")


def test_classifier_load_refuses_a_mismatched_vocabulary(small_agent, tmp_path):
    small_agent.classifier.save(tmp_path / "classes.pt")
    other = VisualFeatureExtractor(
        small_agent.extractor.keypoints, small_agent.extractor.centroids + 1.0
    )
    with pytest.raises(ValueError, match="vocabulary mismatch"):
        VisualClassifier.load(tmp_path / "classes.pt", other)
    same = VisualClassifier.load(tmp_path / "classes.pt", small_agent.extractor)
    assert same.n_classes == small_agent.classifier.n_classes


def test_the_agent_merges_its_classes_when_learning_ends_and_acts_as_saved(tmp_path):
    tree = RLVCAgent(small_maze(), n_words=128, compaction=False, seed=0).learn(4000)
    merged = RLVCAgent(small_maze(), n_words=128, seed=0).learn(4000)
    assert isinstance(tree.rlvc.structure, ClassTree)
    assert isinstance(merged.rlvc.structure, ClassBDD)
    # The same tree is learned; the merge leaves fewer classes, each percept's class Q.
    assert len(merged.rlvc.history) == len(tree.rlvc.history)
    assert merged.rlvc.n_classes < tree.rlvc.n_classes
    db = merged.database
    torch.testing.assert_close(
        merged.rlvc.q, merged.rlvc.solve(db, merged.rlvc.structure.classify(db.presence))
    )
    maze = small_maze().unwrapped
    images = np.stack([maze.percept_at(p) for p in start_positions(maze.geometry, 60)])
    merged.save(tmp_path / "agent.pt")
    loaded = RLVCAgent.load(tmp_path / "agent.pt")
    assert loaded.compaction == Compaction() and loaded.rlvc.n_classes == merged.rlvc.n_classes
    assert np.array_equal(loaded.predict(images)[0], merged.predict(images)[0])


def test_unlearned_agent_explains_itself():
    agent = RLVCAgent(small_maze())
    with pytest.raises(RuntimeError, match="not learned"):
        agent.predict(np.zeros((64, 64, 3), np.uint8))
    with pytest.raises(TypeError, match=r"n_words must be an integer, got 100\.5"):
        RLVCAgent(small_maze(), n_words=100.5)
    with pytest.raises(ValueError, match="databases must be >= 1, got 0"):
        RLVCAgent(small_maze(), databases=0)
    with pytest.raises(ValueError, match=r"epsilon must be in \[0, 1\], got 2.0"):
        RLVCAgent(small_maze(), epsilon=2.0)
    with pytest.raises(ValueError, match="structures must be >= 1, got 0"):
        RLVCAgent(small_maze(), compaction=Compaction(structures=0))
    with pytest.raises(ValueError, match="while learning: set during_learning=True"):
        Compaction(structures=3)
    with pytest.raises(ValueError, match=r"tolerance must be in \[0, 1\), got 1.5"):
        Compaction(tolerance=1.5)
    with pytest.raises(ValueError, match="nearest_seen on the classes of the nearest"):
        RLVCAgent(small_maze(), compaction=FUSED, nearest_seen=True)
    # Strings are not switches: "False" would be truthy.
    for option in ("compounds", "compaction", "nearest_seen"):
        with pytest.raises(TypeError, match=f"{option} must be True or False.*, got .False."):
            RLVCAgent(small_maze(), **{option: "False"})
    with pytest.raises(ValueError, match="vocabulary_groups must be >= 1, got 0"):
        RLVCAgent(small_maze(), vocabulary_groups=0)
    with pytest.raises(ValueError, match="total_timesteps must be an integer >= databases"):
        agent.learn(2)


def test_fused_structures_refuse_a_worker_process_that_imports_an_unguarded_script(monkeypatch):
    # As multiprocessing marks a new process while it imports its parent's main script.
    monkeypatch.setattr(multiprocessing.current_process(), "_inheriting", True, raising=False)
    with pytest.raises(RuntimeError, match='under `if __name__ == "__main__":`'):
        RLVCAgent(small_maze(), compaction=FUSED)
    RLVCAgent(small_maze(), compaction=True)  # one structure starts no process


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
    steps = []
    agent.learn(100, callback=lambda _l, _g: steps.append(1) or len(steps) < 10)
    assert len(steps) == 10 == agent.num_timesteps  # once per step; False stops
    agent.learn(50, reset_num_timesteps=False)
    assert agent.num_timesteps == 60  # the count goes on, as the comparison's budgets need
    agent.save(tmp_path / "q.pt")
    loaded = TabularQAgent.load(tmp_path / "q.pt", env)
    np.testing.assert_array_equal(loaded.q, agent.q)
    with pytest.raises(ValueError, match="state ids"):
        agent.predict(99)
    with pytest.raises(TypeError, match="Discrete observation"):
        TabularQAgent(gym.make("vistask/VisualMaze-v0"))


def test_a_second_learn_continues_where_the_first_stopped():
    agent = RLVCAgent(small_maze(), n_words=256, nearest_seen=True, seed=0).learn(1500)
    stages, classes = len(agent.rlvc.history), agent.rlvc.n_classes
    first_database = agent.database
    agent.learn(900, reset_num_timesteps=False)
    assert agent.num_timesteps == 2400 == len(agent.database)
    # The earlier interactions stay; the new ones come from new episodes.
    assert torch.equal(agent.database.actions[:1500], first_database.actions)
    assert len(agent.rlvc.history) > stages and agent.rlvc.n_classes >= classes
    agent.learn(300)  # SB3's default: the count restarts, the learning does not
    assert agent.num_timesteps == 300 and len(agent.database) == 2700
    # It remembers the percepts of every database, the later ones too.
    assert agent.rlvc.seen.counts.sum() == len(agent.database.presence)


def test_the_stage_cap_holds_per_database_and_every_interaction_is_collected():
    agent = RLVCAgent(small_maze(), n_words=256, max_stages=1, databases=3, seed=0).learn(1500)
    assert agent.num_timesteps == 1500 == len(agent.database)
    assert len(agent.rlvc.history) == 3  # one stage after each database
    assert agent.rlvc.seen is None and agent.classifier.seen is None  # the default: the tree


def test_sb3_callbacks_run_once_per_stage_and_can_stop_learning(tmp_path):
    checkpoints = CheckpointCallback(save_freq=2, save_path=str(tmp_path), name_prefix="rlvc")
    calls = []

    def stop_after_three(_locals, _globals) -> bool:
        calls.append(1)
        return len(calls) < 3

    agent = RLVCAgent(small_maze(), n_words=256, seed=0, tensorboard_log=tmp_path / "tb")
    agent.learn(1500, callback=[checkpoints, stop_after_three])
    assert len(agent.rlvc.history) == 3 == len(calls)
    saved = sorted(tmp_path.glob("rlvc_*_steps.zip"))
    assert len(saved) == 1 and RLVCAgent.load(saved[0]).rlvc.n_classes >= 1
    assert any((tmp_path / "tb").rglob("events.out.tfevents.*"))


def test_eval_callback_evaluates_the_agent_as_an_sb3_model(tmp_path, monkeypatch):
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where SB3 puts its logger folders
    evaluations = EvalCallback(
        small_maze(), eval_freq=1, n_eval_episodes=3, log_path=str(tmp_path), verbose=0
    )
    agent = RLVCAgent(small_maze(), n_words=256, seed=0).learn(1500, callback=evaluations)
    assert not list(tmp_path.glob("SB3-*"))  # no TensorBoard folder given: no logger folder
    assert len(evaluations.evaluations_results) == len(agent.rlvc.history)
    assert all(len(rewards) == 3 for rewards in evaluations.evaluations_results)
    assert np.isfinite(evaluations.last_mean_reward)
    # With TensorBoard, the callback's points lie on the run's axis, the stages, as the
    # agent's own: EvalCallback dumps at its interaction count, which the run does not use.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    every_third = EvalCallback(small_maze(), eval_freq=3, n_eval_episodes=2, verbose=0)
    logged = RLVCAgent(small_maze(), n_words=256, seed=0, tensorboard_log=tmp_path / "tb")
    logged.learn(1500, callback=every_third)
    (events,) = (tmp_path / "tb").rglob("events.out.tfevents.*")
    run = EventAccumulator(str(events)).Reload()
    stages = [e.step for e in run.Scalars("rlvc/classes")]
    assert stages == list(range(len(logged.rlvc.history)))  # the stages' indices, from 0
    assert [e.step for e in run.Scalars("eval/mean_reward")] == stages[2::3]
    assert {e.step for e in run.Scalars("rollout/ep_rew_mean")} <= set(stages)


def test_a_loaded_agent_goes_on_logging_where_it_was_saved_from(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    agent = RLVCAgent(small_maze(), n_words=256, seed=0, tensorboard_log=tmp_path / "tb")
    agent.learn(1000).save(tmp_path / "rlvc.pt")
    first = len(agent.rlvc.history)
    loaded = RLVCAgent.load(tmp_path / "rlvc.pt", env=small_maze())
    assert loaded.tensorboard_log == str(tmp_path / "tb")
    loaded.learn(1000, reset_num_timesteps=False)
    (run,) = (tmp_path / "tb").iterdir()  # the same run, its stages on after the first
    stages = [e.step for e in EventAccumulator(str(run)).Reload().Scalars("rlvc/classes")]
    assert len(stages) > first and stages == list(range(len(stages)))
    loaded.tensorboard_log = None
    loaded.save(tmp_path / "quiet.pt")
    assert RLVCAgent.load(tmp_path / "quiet.pt").tensorboard_log is None
    tabular = TabularQAgent(gym.make("FrozenLake-v1"), tensorboard_log=tmp_path / "q")
    tabular.learn(100).save(tmp_path / "q.pt")
    assert TabularQAgent.load(tmp_path / "q.pt").tensorboard_log == str(tmp_path / "q")


def test_predict_is_epsilon_greedy_when_not_deterministic(small_agent):
    maze = small_agent.env.unwrapped
    images = np.stack([maze.percept_at(p) for p in start_positions(maze.geometry, 200)])
    greedy = small_agent.predict(images)[0]
    epsilon = small_agent.epsilon
    small_agent.epsilon = 1.0
    random = small_agent.predict(images, deterministic=False)[0]
    small_agent.epsilon = 0.0
    assert np.array_equal(small_agent.predict(images, deterministic=False)[0], greedy)
    small_agent.epsilon = epsilon
    assert set(random.tolist()) == {0, 1, 2, 3} and (random != greedy).mean() > 0.5


def test_rlvc_with_its_defaults_solves_a_pixel_gridworld_it_was_not_written_for():
    """MiniGrid's 5x5 room, seen as the agent's egocentric 56x56 RGB view: 7 actions, 100-step
    episodes (the env's own limit), reward 1 - 0.9 * steps / 100. The shortest path takes 5
    steps, so the optimum is 0.955 from the fixed start."""
    pytest.importorskip("minigrid")
    from minigrid.wrappers import ImgObsWrapper, RGBImgPartialObsWrapper

    def make() -> gym.Env:
        return ImgObsWrapper(RGBImgPartialObsWrapper(gym.make("MiniGrid-Empty-5x5-v0")))

    agent = RLVCAgent(make(), seed=0).learn(10_000)
    env = make()
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        for _ in range(100):
            obs, reward, terminated, truncated, _ = env.step(agent.predict(obs)[0])
            if terminated or truncated:
                break
        assert terminated and reward == pytest.approx(1 - 0.9 * 5 / 100)


def test_train_rlvc_writes_a_summary_that_its_saved_agent_reproduces(tmp_path):
    summary = train_rlvc(env_kwargs=SMALL, interactions=2000, out=tmp_path, progress=False)
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    for key in ("return_ratio", "rlvc_return", "oracle_return", "stages", "classes"):
        assert on_disk[key] == pytest.approx(summary[key])
    assert summary["interactions"] == 2000 and summary["enlarge"] == 1  # 64-pixel views
    splits = sum(record["splits"] for record in on_disk["history"])
    assert summary["selected_features"] <= splits  # a test per split, merged classes or not
    assert summary["return_ratio"] == pytest.approx(
        summary["rlvc_return"] / summary["oracle_return"]
    )
    for picture in ("value_functions.png", "rlvc_policy.png", "oracle_policy.png"):
        assert (tmp_path / picture).stat().st_size > 0
    # Fewer stages than between two evaluations: the learned agent is scored when learning ends.
    assert summary["stages"] < 50
    assert on_disk["evaluations"] == [[summary["stages"], summary["rlvc_return"]]]
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    (events,) = (tmp_path / "tensorboard").rglob("events.out.tfevents.*")
    logged = EventAccumulator(str(events)).Reload().Scalars("eval/return")
    last = summary["stages"] - 1  # the run's axis counts the stages from 0
    assert [(e.step, e.value) for e in logged] == [(last, pytest.approx(summary["rlvc_return"]))]
    # The saved agent acts as the one that was scored, from the same starts.
    env = gym.make("vistask/VisualMaze-v0", **SMALL)
    agent = RLVCAgent.load(tmp_path / "rlvc_agent.pt", env)
    starts = start_positions(env.unwrapped.geometry, 100)
    result = evaluate_policy(env, agent_policy(agent), starts)
    assert result.mean == pytest.approx(summary["rlvc_return"])
    assert summary["starts_never_exiting"] == int((result.returns == 0).sum())


def test_train_rlvc_passes_its_hyperparams_to_the_agent_and_keeps_them_for_resuming(tmp_path):
    run = dict(env_kwargs=SMALL, interactions=2000, out=tmp_path, progress=False, pictures=False)
    options = {"compounds": True, "compaction": {"tolerance": 0.01}, "vocabulary_groups": 4}
    summary = train_rlvc(**run, hyperparams=options)
    assert summary["hyperparams"] == options  # the maze has no entry in the table
    assert summary["compaction_tolerance"] == 0.01 and summary["vocabulary_groups"] == 4
    agent = RLVCAgent.load(tmp_path / "rlvc_agent.pt", gym.make("vistask/VisualMaze-v0", **SMALL))
    assert agent.compaction == Compaction(tolerance=0.01)
    assert agent.vocabulary_groups == 4 and len(agent.extractor.groups.centres) == 4
    # A compound's parts are the groups of its words (or earlier compounds, above them).
    words = agent.extractor.n_features
    for compound in agent.rlvc.compounds:
        assert all(p < 4 or p >= words for p in (compound.first, compound.second))
    with pytest.raises(ValueError, match=r"other settings \(hyperparams \{.* there, \{.* now\)"):
        train_rlvc(**run, hyperparams={**options, "vocabulary_groups": 8})
    with pytest.raises(ValueError, match="unknown hyperparameter 'seed'"):
        train_rlvc(**run, hyperparams={"seed": 1})


def test_train_rljc_passes_its_hyperparams_to_the_agent_and_keeps_them_for_resuming(tmp_path):
    run = dict(env_id="vistask/VisualMazeContinuous-v0", env_kwargs=SMALL, interactions=1500)
    run |= dict(out=tmp_path, progress=False, pictures=False)
    train_rljc(**run, hyperparams={"n_words": 64, "max_blocked": 0})
    agent = RLJCAgent.load(tmp_path / "rljc_agent.pt")
    assert agent.extractor.n_features == 64 and agent.max_blocked == 0
    with pytest.raises(ValueError, match=r"other settings \(hyperparams \{.* there, \{.* now\)"):
        train_rljc(**run, hyperparams={"n_words": 32})
    with pytest.raises(ValueError, match="unknown hyperparameter 'compounds': RLJCAgent takes"):
        train_rljc(**run, hyperparams={"compounds": True})


def test_hyperparams_take_the_env_entry_and_override_a_mapping_key_by_key():
    car = hyperparams_for("vistask/VisualMountainCar-v0")
    assert car["compounds"] and car["compaction"]["structures"] == 11
    fewer = hyperparams_for(
        "vistask/VisualMountainCar-v0", parse_overrides(["compaction={structures: 3}"])
    )
    assert fewer["compaction"] == {**car["compaction"], "structures": 3}
    assert agent_kwargs(fewer)["compaction"] == Compaction(0.01, structures=3, during_learning=True)
    assert hyperparams_for("vistask/VisualMaze-v0") == {}  # the defaults
    assert parse_overrides(["compounds=true", "alpha=0.01", "gamma=null"]) == {
        "compounds": True,
        "alpha": 0.01,
        "gamma": None,
    }
    with pytest.raises(ValueError, match="key=value"):
        parse_overrides(["compounds"])
    with pytest.raises(ValueError, match="compaction takes true, false or a mapping"):
        hyperparams_for("vistask/VisualMaze-v0", {"compaction": {"tolerence": 0.01}})


def test_train_rlvc_fuses_class_structures_and_the_saved_agent_acts_on_them(tmp_path):
    run = dict(env_kwargs=SMALL, interactions=2000, out=tmp_path, progress=False, pictures=False)
    fused = {"structures": 3, "during_learning": True}
    summary = train_rlvc(**run, hyperparams={"compaction": fused})
    assert summary["structures"] == 3
    env = gym.make("vistask/VisualMaze-v0", **SMALL)
    agent = RLVCAgent.load(tmp_path / "rlvc_agent.pt", env)
    assert agent.structures == 3 and agent.rlvc.n_classes == summary["classes"]
    assert len(agent.rlvc.committee.structures) == 3  # the policy acts on them
    starts = start_positions(env.unwrapped.geometry, 100)
    assert evaluate_policy(env, agent_policy(agent), starts).mean == pytest.approx(
        summary["rlvc_return"]
    )


def test_a_classifier_with_compounds_round_trips_and_tests_them(small_agent, tmp_path):
    maze = VisualMazeEnv(**SMALL)
    images = [maze.percept_at(p) for p in start_positions(maze.geometry, 60)]
    extractor = small_agent.extractor
    words = extractor.occurrences(images)
    compound = propose(words, tolerances=(1.0,), min_count=5)[0]  # a relation seen in 5+ percepts
    tree = ClassTree(extractor.n_features + 1)
    tree.split(0, extractor.n_features)  # the compound present -> class 1
    classifier = VisualClassifier(extractor, tree, [compound])
    expected = presence_of_candidates(words, [compound])[:, 0].long()
    assert 0 < int(expected.sum()) < len(images)
    assert torch.equal(classifier.classify(images), expected)
    classifier.save(tmp_path / "classes.pt")
    loaded = VisualClassifier.load(tmp_path / "classes.pt")
    assert loaded.compounds == [compound]
    assert torch.equal(loaded.classify(images), expected)
    with pytest.raises(ValueError, match="1 compounds"):
        VisualClassifier(extractor, ClassTree(extractor.n_features + 2), [compound])


def test_train_rlvc_on_the_car_scores_against_its_oracle_and_draws_it(tmp_path):
    env_id = "vistask/VisualMountainCar-v0"
    # 20 starts: the score of an agent this young takes most of the time at the 100 default.
    # The car's entry in the table, but one structure without compaction: quicker.
    run = dict(interactions=2000, out=tmp_path, progress=False, eval_starts=20)
    summary = train_rlvc(env_id, **run, hyperparams={"compaction": False})
    assert summary["hyperparams"]["compounds"] and summary["vocabulary_groups"] == 16
    for key in ("stages", "classes", "selected_features", "compound_features", "seconds"):
        assert key in summary
    assert summary["interactions"] == 2000
    assert summary["return_ratio"] == pytest.approx(
        summary["rlvc_return"] / summary["oracle_return"]
    )
    assert summary["oracle_return"] > 0.5  # the oracle reaches the top from every start
    failing, gap = summary["starts_failing"], summary["return_gap_failing_starts"]
    assert (failing == 0) == (gap == 0) and gap >= 0  # a failing start loses all it could get
    assert 0 < summary["seen_percepts_return_ratio"] <= 1.05
    assert summary["velocity_r2_best_word"] < 0.2  # no single word reads the gauge
    assert summary["compounds_made"] >= summary["compound_features"] > 0
    for picture in ("road_and_gauge.png", "car_policy.png", "car_classes.png"):
        assert (tmp_path / picture).stat().st_size > 0
    # That a saved agent reproduces its return is checked on the maze, where it is cheap.
    loaded = RLVCAgent.load(tmp_path / "rlvc_agent.pt")
    assert loaded.rlvc.compounds
    assert loaded.extractor.keypoints.panel_widths == (96, 96)  # the road and the gauge alone
    with pytest.raises(ValueError, match="eval_starts must be >= 1, got 0"):
        train_rlvc(env_id, out=tmp_path / "none", eval_starts=0)


def test_one_progress_bar_counts_the_interactions_of_the_whole_learn_call(capsys, tmp_path):
    agent = RLVCAgent(small_maze(), n_words=256, seed=1, tensorboard_log=tmp_path)
    agent.learn(2000, progress_bar=True)
    screen = capsys.readouterr().err.replace("\r", "\n")
    # One bar, to the call's end: it moves while collecting, then shows the stages' classes.
    assert "2000/2000" in screen and screen.count("0/2000") >= 1
    for shown in ("collecting", "SIFT", "stages", "db=4/4", "classes=", "ep_return="):
        assert shown in screen, shown
    assert f"classes={agent.rlvc.n_classes}" in screen
    # The mean return of the episodes each database ended goes to TensorBoard as SB3's.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    (run,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    events = EventAccumulator(str(run))
    events.Reload()
    assert "rollout/ep_rew_mean" in events.Tags()["scalars"]


def test_learning_without_a_single_reward_says_so():
    env = gym.wrappers.TransformReward(small_maze(), lambda reward: 0.0)
    agent = RLVCAgent(env, n_words=256, databases=1, seed=0)
    with pytest.warns(UserWarning, match="no reward in the 1000 interactions learned on"):
        agent.learn(1000)
    assert agent.rewards_seen == 0
    assert RLVCAgent(small_maze(), n_words=256, databases=1).learn(1000).rewards_seen > 0


def test_agents_refuse_seeds_discounts_and_images_they_would_coerce(small_agent):
    with pytest.raises(TypeError, match=r"seed must be an integer, got 1\.7"):
        RLVCAgent(small_maze(), seed=1.7)
    with pytest.raises(ValueError, match="seed must be >= 0, got -1"):
        RLVCAgent(small_maze(), seed=-1)
    frozen_lake = gym.make("FrozenLake-v1")
    for gamma in (1.5, float("nan")):
        with pytest.raises(ValueError, match="gamma must be"):
            TabularQAgent(frozen_lake, gamma=gamma)
    image = np.zeros((64, 64, 3), np.uint8)
    with pytest.raises(TypeError, match="dtype uint8, got bool"):
        small_agent.predict([image, image.astype(bool)])
    assert len(small_agent.predict([image, image])[0]) == 2


def test_an_agent_knows_the_env_arguments_it_learned_on(small_agent, tmp_path):
    other_layout = gym.make("vistask/VisualMaze-v0", **{**SMALL, "step": 0.25})
    with pytest.raises(ValueError, match="Learning on would mix their interactions"):
        small_agent.set_env(other_layout)  # it holds the databases it learned from
    small_agent.save(tmp_path / "agent.pt")
    with pytest.warns(UserWarning, match="acting on another env than it learned on"):
        RLVCAgent.load(tmp_path / "agent.pt", env=other_layout)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        agent = RLVCAgent.load(tmp_path / "agent.pt", env=small_maze())
    assert agent.env_kwargs == small_agent.env_kwargs and agent.env_kwargs["step"] == 0.2


def test_saved_settings_of_either_form_give_the_same_compaction():
    legacy = {"compaction": True, "compact_every": 5, "compaction_tolerance": 0.01, "structures": 3}
    assert RLVCAgent._params_from_state(legacy)["compaction"] == Compaction(0.01, 5, 3, True)
    # Files from before ``during_learning`` merged during learning.
    saved = {"compaction": {"tolerance": 0.05, "every": None, "structures": 1}}
    assert RLVCAgent._params_from_state(saved)["compaction"] == Compaction(0.05, None, 1, True)
    merged_at_end = {"compaction": asdict(Compaction())}
    assert RLVCAgent._params_from_state(merged_at_end)["compaction"] == Compaction()
    assert RLVCAgent._params_from_state({"compaction": None})["compaction"] is False
