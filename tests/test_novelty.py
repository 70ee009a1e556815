"""Directed exploration: SimHash codes of feature sets, count bonuses, and the agent that
learns its collecting classes on them."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from small_maze import small_maze
from stable_baselines3.common.callbacks import BaseCallback

from vistask.agents import RLVCAgent
from vistask.rlvc import PackedPresence
from vistask.rlvc.novelty import novelty_bonus, simhash_codes


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 40), st.integers(2, 300), st.integers(0, 2**31 - 1))
def test_equal_feature_sets_share_a_code_whatever_their_storage(m, f, seed):
    rng = np.random.default_rng(seed)
    dense = torch.from_numpy(rng.random((m, f)) < 0.1)
    codes = simhash_codes(torch.cat([dense, dense]))
    assert torch.equal(codes[:m], codes[m:])
    assert torch.equal(simhash_codes(PackedPresence.from_dense(dense)), codes[:m])
    assert codes.min() >= 0 and codes.max() < 2**32


def test_distinct_feature_sets_get_distinct_codes_and_a_seed_gives_other_projections():
    presence = torch.eye(64, dtype=torch.bool)  # 64 percepts of one feature each
    assert len(torch.unique(simhash_codes(presence))) > 60  # 32 bits: collisions are rare
    assert not torch.equal(simhash_codes(presence, seed=0), simhash_codes(presence, seed=1))
    with pytest.raises(ValueError, match=r"bits must be in 1\.\.62"):
        simhash_codes(presence, bits=63)


def test_the_bonus_is_one_over_the_root_of_the_visits_of_the_successor_code():
    presence = torch.tensor([[1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.bool)
    # Percepts 0 and 2 have the same features: reaching them counts together.
    next_obs = torch.tensor([0, 2, 1, 0, 3, 1])
    bonus = novelty_bonus(presence, next_obs)
    expected = torch.tensor([3, 3, 2, 3, 1, 2], dtype=torch.float64).rsqrt()
    assert torch.allclose(bonus, expected)


class RewardsLearnedOn(BaseCallback):
    """Records, at every stage, the interactions collected and the sum of the rewards the
    learner reads."""

    def __init__(self, agent: RLVCAgent) -> None:
        super().__init__()
        self.agent, self.seen = agent, []

    def _on_step(self) -> bool:
        self.seen.append((self.agent.num_timesteps, float(self.agent.database.rewards.sum())))
        return True


def learned_rewards(env: gym.Env, **kwargs) -> tuple[RLVCAgent, dict[int, set[float]]]:
    agent = RLVCAgent(env, n_words=256, databases=3, seed=0, **kwargs)
    callback = RewardsLearnedOn(agent)
    agent.learn(1500, callback=callback)
    by_database = {}
    for collected, total in callback.seen:
        by_database.setdefault(collected, set()).add(round(total, 9))
    return agent, by_database


def test_without_a_reward_every_collecting_database_learns_on_the_bonus_alone():
    env = gym.wrappers.TransformReward(small_maze(), lambda reward: 0.0)
    with pytest.warns(UserWarning, match="no reward"):
        agent, rewards = learned_rewards(env)
    assert sorted(rewards) == [500, 1000, 1500]
    assert min(rewards[500]) > 0 and min(rewards[1000]) > 0  # the bonus, scaled by 1
    assert rewards[1500] == {0.0}  # the acting classes: the env's rewards
    assert not agent.database.rewards.any()  # put back after learning


def test_once_a_split_can_be_rewarded_the_classes_learn_on_the_env_rewards_alone():
    agent, rewards = learned_rewards(small_maze())
    assert agent.database.rewards[:500].count_nonzero() >= agent.split_count
    for collected, seen in rewards.items():
        assert seen == {round(float(agent.database.rewards[:collected].sum()), 9)}
    plain, _ = learned_rewards(small_maze(), novelty=0.0)
    assert torch.equal(plain.database.actions, agent.database.actions)
    with pytest.raises(ValueError, match="novelty must be finite and >= 0"):
        RLVCAgent(small_maze(), novelty=-0.1)
    with pytest.raises(TypeError, match="novelty must be a number"):
        RLVCAgent(small_maze(), novelty="0.1")
