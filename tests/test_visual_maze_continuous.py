"""The continuous-action visual maze: move angles, batching, the directional oracle, pictures."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.envs import (
    ACTION_ANGLES,
    MazeGeometry,
    MazeOracle,
    VisualMazeContinuousEnv,
    VisualMazeContinuousVectorEnv,
    VisualMazeEnv,
    angle_directions,
    direction_angles,
    evaluate_policy,
    start_positions,
)
from vistask.envs.visual_maze import ACTION_DIRECTIONS

ID = "vistask/VisualMazeContinuous-v0"


# The action is an angle in radians by design, not a normalized [-1, 1] box.
@pytest.mark.filterwarnings("ignore:.*symmetric and normalized space")
def test_gymnasium_env_checker_passes():
    env = gym.make(ID)
    assert env.spec.max_episode_steps == 50
    assert env.action_space == gym.spaces.Box(-np.pi, np.pi, (1,), np.float32)
    check_env(env.unwrapped, skip_render_check=True)


def test_angle_directions_follow_the_y_down_convention():
    np.testing.assert_allclose(angle_directions(ACTION_ANGLES), ACTION_DIRECTIONS, atol=1e-15)
    np.testing.assert_allclose(
        angle_directions([-np.pi, np.pi / 4]), [[-1, 0], [2**-0.5, 2**-0.5]], atol=1e-15
    )
    angles = direction_angles(32)
    assert angles[0] == -np.pi and np.isin(ACTION_ANGLES[:3], angles).all()  # left, up, right, down


@pytest.mark.parametrize(
    ("action", "expected"),
    [
        (np.array([0.0], np.float32), (0.6, 0.5)),  # right
        (np.array([-np.pi / 2]), (0.5, 0.4)),  # up
        (np.pi / 2, (0.5, 0.6)),  # down, as a Python float
        (np.array([np.float32(np.pi)]), (0.4, 0.5)),  # left, π rounded up to float32
        ([3 * np.pi / 4], (0.5 - 0.1 * 2**-0.5, 0.5 + 0.1 * 2**-0.5)),  # down-left
    ],
)
def test_angles_move_the_agent_one_step_that_way(action, expected):
    env = VisualMazeContinuousEnv(obstacles=(), noise_std=0.0)
    env.reset(seed=0, options={"position": (0.5, 0.5)})
    _, reward, terminated, _, info = env.step(action)
    np.testing.assert_allclose(info["position"], expected, atol=1e-7)
    assert (reward, terminated) == (0.0, False)


def test_diagonal_moves_are_blocked_by_walls_and_reach_exits():
    env = VisualMazeContinuousEnv(
        obstacles=((0.55, 0.0, 0.6, 0.5),), exits=((0.9, 0.9, 1.0, 1.0),), noise_std=0.0
    )
    env.reset(seed=0, options={"position": (0.5, 0.45)})
    _, _, _, _, info = env.step(np.array([-np.pi / 4]))  # up-right, into the wall
    np.testing.assert_array_equal(info["position"], [0.5, 0.45])
    env.reset(seed=0, options={"position": (0.88, 0.88)})
    _, reward, terminated, _, _ = env.step(np.array([np.pi / 4]))  # down-right, into the exit
    assert (reward, terminated) == (100.0, True)


@pytest.mark.parametrize("action", [np.array([np.nan]), 4.0, np.array([0.1, 0.2]), -3.2, 0, "up"])
def test_invalid_angles_are_rejected(action):
    env = VisualMazeContinuousEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"invalid action .*within \[-π, π\]"):
        env.step(action)


def test_vector_env_gives_the_episodes_of_separate_seeded_envs():
    n, kwargs = 5, {"step": 0.15, "max_episode_steps": 6}
    batch = gym.make_vec(ID, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    assert isinstance(batch.unwrapped, VisualMazeContinuousVectorEnv)
    single = gym.vector.SyncVectorEnv(
        [lambda: gym.make(ID, **kwargs)] * n, autoreset_mode=gym.vector.AutoresetMode.DISABLED
    )
    rng = np.random.default_rng(0)
    views, info = batch.reset(seed=3)
    expected, expected_info = single.reset(seed=3)
    np.testing.assert_array_equal(info["position"], expected_info["position"])
    ended = 0
    for t in range(40):
        np.testing.assert_array_equal(views, expected)
        actions = rng.uniform(-np.pi, np.pi, size=(n, 1)).astype(np.float32)
        given = actions[:, 0] if t % 2 else actions  # (n,) is accepted as well as (n, 1)
        views, rewards, terminated, truncated, info = batch.step(given)
        expected, *outcome, expected_info = single.step(actions)
        for got, want in zip((rewards, terminated, truncated), outcome, strict=True):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(info["position"], expected_info["position"])
        done = terminated | truncated
        if done.any():
            ended += done.sum()
            views, info = batch.reset(options={"reset_mask": done})
            expected, expected_info = single.reset(options={"reset_mask": done})
            np.testing.assert_array_equal(info["position"][done], expected_info["position"][done])
    assert ended > n
    copies = VisualMazeContinuousEnv().vector_copies(2)
    assert isinstance(copies, VisualMazeContinuousVectorEnv)


def test_vector_env_rejects_bad_angles():
    batch = VisualMazeContinuousVectorEnv(num_envs=2)
    with pytest.raises(RuntimeError, match="reset"):
        batch.step(np.zeros((2, 1)))
    batch.reset(seed=0)
    for actions in (np.zeros((3, 1)), np.array([[0.0], [np.nan]]), np.array([[0.0], [3.5]])):
        with pytest.raises(ValueError, match=r"2 actions as a \(2, 1\)"):
            batch.step(actions)
    with pytest.raises(TypeError, match="vector_copies"):
        VisualMazeContinuousVectorEnv.like(VisualMazeEnv(), 2)


def test_directional_oracle_beats_the_four_actions():
    geometry = MazeGeometry()
    four = MazeOracle.solve(geometry, grid=30, samples=16)
    many = MazeOracle.solve(geometry, grid=30, samples=16, n_directions=32)
    assert four.angles is None and many.q.shape == (32, 30, 30)
    np.testing.assert_array_equal(many.angles, direction_angles(32))
    starts = start_positions(geometry)
    r4 = evaluate_policy(VisualMazeEnv(), four.as_policy(), starts)
    r32 = evaluate_policy(VisualMazeContinuousEnv(), many.as_policy(), starts)
    print(f"mean return: 4 actions {r4.mean:.2f}, 32 directions {r32.mean:.2f}")
    assert r32.mean >= r4.mean
    np.testing.assert_array_equal(four.angle(starts), ACTION_ANGLES[four.act(starts)])
    np.testing.assert_array_equal(many.angle(starts), many.angles[many.act(starts)])


def test_actions_and_their_angles_score_the_same():
    oracle = MazeOracle.solve(MazeGeometry(), grid=30, samples=16)
    starts = start_positions(oracle.geometry, 30)
    discrete = evaluate_policy(VisualMazeEnv(), oracle.as_policy(), starts, seed=7)
    angles = evaluate_policy(  # as (n, 1) angles, as a continuous agent would give them
        VisualMazeContinuousEnv(), lambda obs, pos: oracle.angle(pos)[:, None], starts, seed=7
    )
    np.testing.assert_array_equal(angles.returns, discrete.returns)
    np.testing.assert_array_equal(angles.steps, discrete.steps)


def test_policy_returning_bad_angles_is_rejected():
    env = VisualMazeContinuousEnv()
    starts = start_positions(env.geometry, 3)
    for bad in (np.full(3, 4.0), np.full(2, 0.0), np.array([0.0, np.inf, 0.0])):
        with pytest.raises(ValueError, match="3 move angles"):
            evaluate_policy(env, lambda obs, pos, bad=bad: bad, starts)


def test_plot_directions_writes_a_png(tmp_path):
    from vistask.envs.maze_plots import plot_directions

    env = VisualMazeContinuousEnv(pixels_per_unit=200.0)
    angles = np.random.default_rng(0).uniform(-np.pi, np.pi, (10, 10))
    angles[0, 0] = np.nan  # no arrow
    path = plot_directions(env, angles, tmp_path / "directions.png", title="random")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
