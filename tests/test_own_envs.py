"""RLVC on envs a user writes: unusual but valid ones learn, broken ones are refused naming
what is wrong before work is lost."""

import re
import threading
import warnings

import gymnasium as gym
import numpy as np
import pytest

from vistask.agents import RLJCAgent, RLVCAgent
from vistask.checks import env_identity
from vistask.envs.tapestry import make_tapestry
from vistask.experiments.compare import compare
from vistask.experiments.comparison import Comparison
from vistask.rlvc import check_image_env
from vistask.wrappers import JointClasses, VisualClasses, VisualFeatures

PHOTO = make_tapestry(48, 520, tile=48, seed=3)


class Corridor(gym.Env):
    """Cells 0..cells-1 along a photo strip, the goal at the right end (reward 1). Actions:
    ``start + 1`` steps right, any other left (or ``Box`` > 0 right). Views of the cells in
    ``blank`` are grey: the view stays while the agent walks there."""

    def __init__(self, cells=10, start=0, first=None, blank=(), position=int, action_space=None):
        self.cells, self.start, self.first, self.blank = cells, start, first, set(blank)
        self.position_info = position
        self.observation_space = gym.spaces.Box(0, 255, (48, 48, 3), np.uint8)
        self.action_space = action_space or gym.spaces.Discrete(2, start=start)

    def _view(self):
        view = PHOTO[:, self.cell * 52 : self.cell * 52 + 48].copy()
        if self.cell in self.blank:
            view[:] = 128
        return view

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        first = self.np_random.integers(self.cells - 1) if self.first is None else self.first
        self.cell = int(first)
        return self._view(), {"position": self.position_info(self.cell)}

    def step(self, action):
        if isinstance(self.action_space, gym.spaces.Box):
            right = float(np.ravel(action)[0]) > 0
        else:
            right = int(action) == self.start + 1
        self.cell = int(np.clip(self.cell + (1 if right else -1), 0, self.cells - 1))
        done = self.cell == self.cells - 1
        return self._view(), float(done), done, False, {"position": self.position_info(self.cell)}


def corridor(steps=30, **kwargs):
    return gym.wrappers.TimeLimit(Corridor(**kwargs), steps)


SMALL = dict(n_words=64, n_envs=8, seed=0)


def greedy_steps(agent, env, seed=1, limit=30):
    obs, _ = env.reset(seed=seed)
    for step in range(1, limit + 1):
        action, _ = agent.predict(obs)
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            return step if terminated else None
    return None


def test_exploring_episodes_go_on_through_unchanged_views_with_max_blocked_0():
    def rewards_met(**kwargs):
        agent = RLVCAgent(corridor(first=0, blank=range(2, 7)), **SMALL, **kwargs)
        return agent.learn(4000).rewards_seen

    cut, kept = rewards_met(), rewards_met(max_blocked=0)
    assert kept > 2 * cut


def test_actions_of_a_discrete_space_that_starts_at_1_are_the_envs(tmp_path):
    env = corridor(start=1, action_space=gym.spaces.Discrete(3, start=1))
    agent = RLVCAgent(env, **SMALL).learn(3000)
    views = np.stack([env.reset(seed=s)[0] for s in range(20)])
    assert set(agent.predict(views)[0].tolist()) <= {1, 2, 3}
    assert agent.predict(views[0], deterministic=False)[0] in {1, 2, 3}
    assert greedy_steps(agent, env) is not None
    agent.save(tmp_path / "agent.pt")  # the start is kept: loaded, it acts with the env's ids
    for loaded in (
        RLVCAgent.load(tmp_path / "agent.pt"),
        RLVCAgent.load(tmp_path / "agent.pt", env),
    ):
        assert loaded.action_space == env.action_space
        assert np.array_equal(loaded.predict(views)[0], agent.predict(views)[0])


def test_tabular_q_counts_states_and_actions_from_their_spaces_start(tmp_path):
    from vistask.agents import TabularQAgent

    class Chain(gym.Env):  # states 10..14, actions 1 (left) and 2 (right), the goal at 14
        observation_space = gym.spaces.Discrete(5, start=10)
        action_space = gym.spaces.Discrete(2, start=1)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.state = 10
            return self.state, {}

        def step(self, action):
            assert self.action_space.contains(action), action
            self.state = int(np.clip(self.state + (1 if action == 2 else -1), 10, 14))
            return self.state, float(self.state == 14), self.state == 14, False, {}

    env = gym.wrappers.TimeLimit(Chain(), 30)
    agent = TabularQAgent(env, seed=0).learn(3000)
    assert agent.predict(np.arange(10, 14))[0].tolist() == [2, 2, 2, 2]
    agent.save(tmp_path / "q.pt")
    assert TabularQAgent.load(tmp_path / "q.pt", env).predict(12)[0] == 2
    with pytest.raises(ValueError, match="states from id 10 and 2 actions from id 1"):
        TabularQAgent.load(tmp_path / "q.pt", gym.make("FrozenLake-v1"))


@pytest.mark.parametrize(
    "position", [lambda c: {"x": c}, lambda c: f"cell{c}", lambda c: list(range(c + 1))]
)
def test_an_info_position_that_is_not_numbers_is_ignored(position):
    agent = RLVCAgent(corridor(position=position), **SMALL).learn(1000)
    assert agent.database.positions is None


class NanReward(Corridor):
    def step(self, action):
        view, _, terminated, truncated, info = super().step(action)
        return view, float("nan"), terminated, truncated, info


class WrongSize(Corridor):
    def step(self, action):
        view, *rest = super().step(action)
        return view[:40], *rest


@pytest.mark.parametrize(("env", "named"), [(NanReward, "reward nan"), (WrongSize, "(40, 48, 3)")])
def test_a_broken_env_output_is_refused_naming_it(env, named):
    with pytest.raises(ValueError, match=re.escape(named)):
        RLVCAgent(gym.wrappers.TimeLimit(env(), 20), **SMALL).learn(1000)


class Uncopyable(Corridor):
    def __init__(self):
        super().__init__()
        self.lock = threading.Lock()


def test_an_env_that_cannot_be_copied_is_refused_before_any_work_unless_n_envs_is_1():
    agent = RLVCAgent(gym.wrappers.TimeLimit(Uncopyable(), 20), **SMALL)
    with pytest.raises(TypeError, match="n_envs=1"):
        agent.learn(1000)
    assert agent.num_timesteps == 0
    RLVCAgent(gym.wrappers.TimeLimit(Uncopyable(), 20), n_words=64, n_envs=1).learn(1000)


class Heavy(Corridor):
    def __init__(self):
        super().__init__()
        self.table = np.ones(50 * 2**17)  # 50 MB


def test_the_memory_check_counts_the_env_copies(monkeypatch):
    import vistask.agents.visual_agent as visual_agent

    class Memory:
        available = 1500 * 2**20

    monkeypatch.setattr(visual_agent.psutil, "virtual_memory", lambda: Memory)
    with pytest.raises(MemoryError, match="env's copies"):
        RLVCAgent(gym.wrappers.TimeLimit(Heavy(), 20), n_words=64, n_envs=64).learn(1000)
    RLVCAgent(gym.wrappers.TimeLimit(Heavy(), 20), n_words=64, n_envs=2).learn(1000)


def shaping(reward):
    return 2 * reward


def registered() -> str:
    if "test_own_envs/Corridor-v0" not in gym.registry:
        gym.register("test_own_envs/Corridor-v0", entry_point=Corridor, max_episode_steps=20)
    return "test_own_envs/Corridor-v0"


def test_an_env_made_with_a_function_argument_is_the_same_env_in_every_process():
    identity = env_identity(gym.make(registered(), position=shaping))
    assert identity[1]["position"] == f"{__name__}.shaping"


@pytest.mark.parametrize(
    ("shape", "dtype", "hint", "fix"),
    [
        (
            (48, 48, 1),
            np.uint8,
            "ReshapeObservation",
            lambda e: gym.wrappers.ReshapeObservation(e, (48, 48)),
        ),
        ((3, 48, 48), np.uint8, "transpose(1, 2, 0)", None),
        ((48, 48, 4), np.uint8, "o[..., :3]", None),
        ((48, 48, 3), np.float32, "(o * 255)", None),
    ],
)
def test_image_like_observations_are_refused_with_the_wrapper_that_fixes_them(
    shape, dtype, hint, fix
):
    env = Corridor()
    env.observation_space = gym.spaces.Box(0, 255, shape, dtype)
    with pytest.raises(TypeError, match=re.escape(hint)):
        check_image_env(env)
    if fix is not None:
        check_image_env(fix(env))


def test_a_discount_attribute_out_of_range_is_named_as_the_envs():
    env = Corridor()
    env.gamma = 1.0
    with pytest.raises(ValueError, match="the env's gamma attribute"):
        RLVCAgent(env)
    assert RLVCAgent(env, gamma=0.9).gamma == 0.9


def test_rljc_on_float64_actions_loads_and_acts_in_float64(tmp_path):
    env = corridor(action_space=gym.spaces.Box(-1, 1, (1,), np.float64))
    agent = RLJCAgent(env, **SMALL).learn(1500)
    agent.save(tmp_path / "rljc.pt")
    view = env.reset(seed=1)[0]
    for loaded in (RLJCAgent.load(tmp_path / "rljc.pt"), RLJCAgent.load(tmp_path / "rljc.pt", env)):
        assert loaded.action_space == env.action_space
        assert loaded.predict(view)[0].dtype == np.float64


def test_joint_classes_refuse_an_env_with_other_action_bounds():
    learned = corridor(action_space=gym.spaces.Box(-1, 1, (1,), np.float32))
    agent = RLJCAgent(learned, **SMALL).learn(1500)
    JointClasses(learned, agent.classifier)
    wider = corridor(action_space=gym.spaces.Box(-5, 5, (1,), np.float32))
    with pytest.raises(ValueError, match="boxes cover actions"):
        JointClasses(wider, agent.classifier)


def test_a_vector_env_is_refused_saying_that_the_agent_makes_its_own_copies():
    from stable_baselines3.common.vec_env import DummyVecEnv

    for vector in (gym.vector.SyncVectorEnv([corridor, corridor]), DummyVecEnv([corridor])):
        with pytest.raises(TypeError, match="a vector env: pass one env, of which agents run"):
            RLVCAgent(vector)


def test_observations_that_hold_an_image_are_told_how_to_keep_it_alone():
    env = Corridor()
    image = env.observation_space
    env.observation_space = gym.spaces.Dict({"direction": gym.spaces.Discrete(4), "image": image})
    with pytest.raises(TypeError, match=r"TransformObservation\(env, lambda o: o\['image'\]"):
        RLVCAgent(env)
    kept = gym.wrappers.TransformObservation(env, lambda o: o["image"], image)
    RLVCAgent(kept, **SMALL)  # the hint's wrapper is accepted


class Wide(Corridor):
    def __init__(self):
        super().__init__()
        self.observation_space = gym.spaces.Box(0, 255, (48, 52, 3), np.uint8)

    def _view(self):
        return np.ascontiguousarray(PHOTO[:, self.cell * 52 : self.cell * 52 + 52])


def test_the_wrappers_refuse_an_env_of_other_images_than_the_classes_were_learned_on(tmp_path):
    agent = RLVCAgent(corridor(), **SMALL).learn(1000)
    agent.save(tmp_path / "agent.pt")
    loaded = RLVCAgent.load(tmp_path / "agent.pt")
    for learned in (agent, loaded):
        VisualClasses(corridor(), learned.classifier)
        with pytest.raises(ValueError, match=re.escape("images of shape (48, 48, 3)")):
            VisualClasses(gym.wrappers.TimeLimit(Wide(), 20), learned.classifier)
        with pytest.raises(ValueError, match="VisualFeatures: the vocabulary"):
            VisualFeatures(gym.wrappers.TimeLimit(Wide(), 20), learned.extractor)


def test_the_wrappers_warn_where_the_classes_were_learned_on_another_registered_env(tmp_path):
    if "test_own_envs/OtherCorridor-v0" not in gym.registry:
        gym.register("test_own_envs/OtherCorridor-v0", entry_point=Corridor, max_episode_steps=20)
    agent = RLVCAgent(gym.make(registered()), **SMALL).learn(1000)
    agent.save(tmp_path / "agent.pt")
    for learned in (agent, RLVCAgent.load(tmp_path / "agent.pt")):
        with pytest.warns(UserWarning, match="learned on test_own_envs/Corridor-v0's images"):
            VisualClasses(gym.make("test_own_envs/OtherCorridor-v0"), learned.classifier)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            VisualClasses(gym.make(registered()), learned.classifier)
            VisualFeatures(corridor(), learned.extractor)  # not registered: nothing to compare


def test_a_setting_changed_after_gym_make_is_named_since_the_copies_do_not_see_it():
    env = gym.make(registered(), cells=10)
    env.unwrapped.cells = 8
    with pytest.warns(UserWarning, match=r"cells 8 \(copies: 10\)"):
        RLVCAgent(env, n_words=64, n_envs=2).learn(600)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        RLVCAgent(gym.make(registered(), cells=10), n_words=64, n_envs=2).learn(600)
    assert not any("copies:" in str(w.message) for w in caught)


def test_a_comparison_with_sb3_runs_on_an_env_without_an_oracle(tmp_path):
    env_id = registered()
    assert "tabular" not in Comparison(env_id=env_id).methods
    with pytest.raises(ValueError, match="tabular baseline learns on the true state"):
        Comparison(env_id=env_id, methods=("rlvc", "tabular"))
    with pytest.warns(UserWarning, match=r"ppo first updates its network after 1024"):
        Comparison(env_id=env_id, methods=("ppo",), budgets=(500, 2000))
    config = Comparison.quick(
        env_id=env_id, methods=("rlvc", "ppo", "random"), budgets=(300, 600), eval_starts=5
    )
    summary = compare(config, tmp_path, progress=False, workers=1)
    assert summary["failed"] == [] and summary["oracle_return"] is None
    rlvc = summary["methods"]["rlvc"]
    assert rlvc["final_ratio"] is None and "interactions_to_90pct" not in rlvc
    # Episodes end at the goal with reward 1: RLVC's greedy walk reaches it from every start.
    assert rlvc["final_return"] == 1.0
    assert summary["methods"]["random"]["final_return"] < 1.0
    table = (tmp_path / "table.md").read_text()
    assert "no oracle" in table and "| rlvc | 1.00 [" in table
    for picture in ("curves", "aggregates", "profiles", "wallclock"):
        assert (tmp_path / f"{picture}.png").stat().st_size > 0


def test_learn_warns_when_a_budget_too_small_leaves_one_class():
    # 48-pixel views are enlarged and split on 5 interactions a side: 8 cannot part one.
    with pytest.warns(UserWarning, match="one class after 8 interactions"):
        agent = RLVCAgent(corridor(cells=6), n_words=64, n_envs=8).learn(8)
    assert agent.rewards_seen > 0 and agent.rlvc.n_classes == 1
