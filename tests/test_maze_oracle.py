"""The oracle: value iteration on true positions, and the evaluation protocol."""

import numpy as np
import pytest

from vistask.envs import MazeGeometry, MazeOracle, VisualMazeEnv, evaluate_policy, start_positions

GAMMA = 0.9


def corridor() -> MazeGeometry:
    """Noise-free maze with an exit strip at x > 0.8 and moves of two cells (0.2)."""
    return MazeGeometry(obstacles=(), exits=((0.8, 0.0, 1.0, 1.0),), step=0.2, noise_std=0.0)


def test_oracle_matches_hand_computed_values_on_a_corridor():
    oracle = MazeOracle.solve(corridor(), grid=10)
    row = oracle.values[5]  # any row: the maze is the same along y
    # From cell centre x, moving right by 0.2: exit reached after n moves, V = 100 gamma^(n-1).
    expected = {0.05: 100 * GAMMA**3, 0.25: 100 * GAMMA**2, 0.45: 100 * GAMMA, 0.65: 100.0}
    for x, v in expected.items():
        assert row[int(x * 10)] == pytest.approx(v)
    assert row[1] == pytest.approx(100 * GAMMA**3)  # 0.15 -> 0.35 -> 0.55 -> 0.75 -> 0.95
    assert (oracle.policy[:, :8] == 1).all()  # always go right


def test_oracle_respects_walls():
    geometry = MazeGeometry(
        obstacles=((0.4, 0.0, 0.6, 0.8),), exits=((0.8, 0.0, 1.0, 0.2),), noise_std=0.0, step=0.1
    )
    oracle = MazeOracle.solve(geometry, grid=10)
    # Just left of the wall near the top, right is blocked: the way out is down around the
    # wall's end at y = 0.8; the same cell mirrored right of the wall is much closer to the exit.
    assert oracle.policy[1, 3] == 2
    assert oracle.values[1, 3] < oracle.values[1, 6]


def test_evaluate_policy_scores_the_oracle_above_random():
    env = VisualMazeEnv()
    oracle = MazeOracle.solve(env.geometry, grid=30, samples=16)
    starts = start_positions(env.geometry, 20)
    best = evaluate_policy(env, oracle.as_policy(), starts)
    rng = np.random.default_rng(0)
    rand = evaluate_policy(env, lambda obs, pos: rng.integers(4, size=len(obs)), starts)
    assert best.returns.shape == (20,)
    assert best.mean > 2 * rand.mean
    again = evaluate_policy(env, oracle.as_policy(), starts)
    np.testing.assert_array_equal(best.returns, again.returns)  # fixed noise seeds


def test_discounted_return_is_computed_from_the_exit_step():
    env = VisualMazeEnv(
        **{
            k: v
            for k, v in vars(corridor()).items()
            if k in ("obstacles", "exits", "step", "noise_std")
        }
    )
    result = evaluate_policy(
        env, lambda obs, pos: np.ones(len(obs)), starts=np.array([[0.45, 0.5]])
    )
    assert result.returns[0] == pytest.approx(100 * GAMMA)  # 0.45 -> 0.65 -> 0.85 (exit)
    assert result.steps[0] == 2


def test_start_positions_are_free_and_fixed():
    geometry = MazeGeometry()
    a, b = start_positions(geometry, 50), start_positions(geometry, 50)
    np.testing.assert_array_equal(a, b)
    assert geometry.is_free(a).all()


def test_lockstep_evaluation_equals_one_episode_at_a_time_through_the_env():
    env = VisualMazeEnv()
    oracle = MazeOracle.solve(env.geometry, grid=30, samples=16)
    starts = start_positions(env.geometry, 8)
    batched = evaluate_policy(env, oracle.as_policy(), starts, seed=5)
    for i, start in enumerate(starts):
        _, info = env.reset(seed=5 + i, options={"position": start})
        ret = 0.0
        for t in range(100):
            _, reward, terminated, _, info = env.step(int(oracle.act(info["position"])[0]))
            ret += env.gamma**t * reward
            if terminated:
                break
        assert batched.returns[i] == pytest.approx(ret)


def test_policy_returning_bad_actions_is_rejected():
    env = VisualMazeEnv()
    with pytest.raises(ValueError, match=r"actions in 0\.\.3"):
        evaluate_policy(
            env, lambda obs, pos: np.full(len(obs), 7), start_positions(env.geometry, 3)
        )
