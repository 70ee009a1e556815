"""The visual maze: dynamics, percepts, seeding, Gymnasium compliance, errors."""

import cv2
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.envs import MazeGeometry, VisualMazeEnv, VisualMazeVectorEnv
from vistask.envs.tapestry import load_photo, make_tapestry, photo_names

OPEN = MazeGeometry(obstacles=(), exits=((0.9, 0.9, 1.0, 1.0),))


def test_noise_statistics_match_the_specification():
    rng = np.random.default_rng(0)
    n = 20_000
    start = np.full((n, 2), 0.5)
    new, exited = OPEN.move(start, np.full(n, 1), rng.standard_normal((n, 2)))  # right
    displacement = new - start
    assert not exited.any()
    np.testing.assert_allclose(displacement.mean(0), [OPEN.step, 0.0], atol=1e-3)
    np.testing.assert_allclose(displacement.std(0), [0.02, 0.02], rtol=0.03)


@pytest.mark.parametrize(
    ("start", "action"),
    [((0.27, 0.3), 1), ((0.39, 0.3), 3), ((0.5, 0.35), 2)],  # into the walls x=0.30..0.36, y<0.6
)
def test_moves_into_obstacles_leave_the_position_unchanged(start, action):
    geometry = MazeGeometry(obstacles=((0.30, 0.0, 0.36, 0.6), (0.3, 0.38, 0.7, 0.42)))
    points = np.array([start])
    new, exited = geometry.move(points, np.array([action]), np.zeros((1, 2)))
    np.testing.assert_array_equal(new, points)
    assert not exited[0]


def test_thin_wall_cannot_be_jumped_over():
    geometry = MazeGeometry(obstacles=((0.50, 0.0, 0.51, 1.0),), step=0.2)
    new, _ = geometry.move(np.array([[0.45, 0.5]]), np.array([1]), np.zeros((1, 2)))
    np.testing.assert_array_equal(new, [[0.45, 0.5]])


def test_moves_out_of_the_maze_are_blocked():
    points = np.array([[0.5, 0.02], [0.98, 0.5]])
    new, _ = OPEN.move(points, np.array([0, 1]), np.zeros((2, 2)))
    np.testing.assert_array_equal(new, points)


def test_reaching_an_exit_terminates_with_reward_100():
    env = VisualMazeEnv(obstacles=(), exits=((0.9, 0.0, 1.0, 1.0),), noise_std=0.0, step=0.1)
    env.reset(seed=0, options={"position": (0.75, 0.5)})
    _, reward, terminated, truncated, _ = env.step(1)
    assert (reward, terminated, truncated) == (0.0, False, False)
    _, reward, terminated, _, info = env.step(1)
    assert (reward, terminated) == (100.0, True)
    np.testing.assert_allclose(info["position"], [0.95, 0.5])
    assert env.gamma == 0.9


def test_observation_is_the_tapestry_window_centred_on_the_agent():
    env = VisualMazeEnv(window=48, pixels_per_unit=300.0)
    obs, info = env.reset(seed=3)
    cx, cy = np.rint(24 + info["position"] * 300.0).astype(int)
    np.testing.assert_array_equal(obs, env.tapestry[cy - 24 : cy + 24, cx - 24 : cx + 24])
    assert obs.shape == (48, 48, 3) and obs.dtype == np.uint8
    obs[:] = 0  # a fresh array: writing into it must not touch the world
    assert env.percept_at(info["position"]).any()


def test_tapestry_is_deterministic_in_its_seed():
    a, b, c = (
        make_tapestry(200, 300, seed=1),
        make_tapestry(200, 300, seed=1),
        make_tapestry(200, 300, seed=2),
    )
    assert a.shape == (200, 300, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_seeding_reproduces_episodes():
    def rollout(seed):
        env = gym.make("vistask/VisualMaze-v0")
        obs, _ = env.reset(seed=seed)
        frames, positions = [obs], []
        for action in [0, 1, 2, 3, 1, 1, 2]:
            obs, _, terminated, _, info = env.step(action)
            frames.append(obs)
            positions.append(info["position"])
            if terminated:
                break
        return np.stack(frames), np.stack(positions)

    (f1, p1), (f2, p2), (_, p3) = rollout(7), rollout(7), rollout(8)
    np.testing.assert_array_equal(f1, f2)
    np.testing.assert_array_equal(p1, p2)
    assert not np.array_equal(p1[: len(p3)], p3[: len(p1)])


def test_gymnasium_env_checker_passes():
    check_env(gym.make("vistask/VisualMaze-v0").unwrapped, skip_render_check=False)


def test_render_draws_the_whole_maze():
    env = gym.make("vistask/VisualMaze-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8


@pytest.mark.parametrize("action", [4, -1, 1.5, "up"])
def test_invalid_actions_are_rejected(action):
    env = VisualMazeEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="invalid action"):
        env.step(action)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"step": -0.1},
        {"step": 2.0},
        {"noise_std": -1.0},
        {"gamma": 1.0},
        {"obstacles": ((0.5, 0.5, 0.4, 0.6),)},
        {"obstacles": ((0.5, 0.5, 1.5, 0.6),)},
        {"exits": ()},
        {"window": 4},
        {"pixels_per_unit": 0},
        {"render_mode": "ansi"},
    ],
)
def test_bad_kwargs_raise_clear_errors(kwargs):
    with pytest.raises(ValueError):
        VisualMazeEnv(**kwargs)


def test_start_position_must_be_free():
    env = VisualMazeEnv()
    with pytest.raises(ValueError, match="not a free"):
        env.reset(options={"position": (0.33, 0.2)})  # inside the first wall


def test_vector_env_gives_the_episodes_of_separate_seeded_envs():
    n, kwargs = 6, {"step": 0.15, "max_episode_steps": 7}
    batch = gym.make_vec(
        "vistask/VisualMaze-v0", num_envs=n, vectorization_mode="vector_entry_point", **kwargs
    )
    assert isinstance(batch.unwrapped, VisualMazeVectorEnv)
    single = gym.vector.SyncVectorEnv(
        [lambda: gym.make("vistask/VisualMaze-v0", **kwargs)] * n,
        autoreset_mode=gym.vector.AutoresetMode.DISABLED,
    )
    rng = np.random.default_rng(0)
    views, info = batch.reset(seed=3)
    expected, expected_info = single.reset(seed=3)
    np.testing.assert_array_equal(info["position"], expected_info["position"])
    ended = 0
    for _ in range(60):
        np.testing.assert_array_equal(views, expected)
        actions = rng.integers(4, size=n)
        views, rewards, terminated, truncated, info = batch.step(actions)
        expected, *outcome, expected_info = single.step(actions)
        for got, want in zip((rewards, terminated, truncated), outcome, strict=True):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(info["position"], expected_info["position"])
        done = terminated | truncated
        if done.any():  # only the ended copies restart, each from its own generator
            ended += done.sum()
            views, info = batch.reset(options={"reset_mask": done})
            expected, expected_info = single.reset(options={"reset_mask": done})
            np.testing.assert_array_equal(info["_position"], done)
            np.testing.assert_array_equal(info["position"][done], expected_info["position"][done])
    assert ended > n  # episodes were truncated and terminated along the way


def test_vector_env_rejects_bad_actions_and_masks():
    batch = VisualMazeVectorEnv(num_envs=2)
    with pytest.raises(RuntimeError, match="reset"):
        batch.step(np.array([0, 1]))
    batch.reset(seed=0)
    for actions in (np.array([0]), np.array([0, 4]), np.array([0.0, 1.0])):
        with pytest.raises(ValueError, match="2 integer actions"):
            batch.step(actions)
    with pytest.raises(ValueError, match="reset_mask"):
        batch.reset(options={"reset_mask": np.array([1, 0])})


def test_layout_seed_draws_connected_mazes_with_their_own_tapestry():
    from vistask.envs.visual_maze import _connected

    a, b = VisualMazeEnv(layout_seed=1), VisualMazeEnv(layout_seed=2)
    assert a.geometry.obstacles != b.geometry.obstacles
    assert not np.array_equal(a.tapestry, b.tapestry)
    assert VisualMazeEnv(layout_seed=1).geometry == a.geometry  # the seed fixes the layout
    for maze in (a, b):
        assert len(maze.geometry.obstacles) == 4 and len(maze.geometry.exits) == 2
        assert _connected(maze.geometry)
    with pytest.raises(ValueError, match="either layout_seed or obstacles"):
        VisualMazeEnv(layout_seed=1, obstacles=((0.1, 0.1, 0.2, 0.2),))


def test_real_image_maze_moves_over_one_photograph():
    env = VisualMazeEnv(photo="hubble_deep_field")
    side = env.tapestry.shape[0]
    assert env.tapestry.shape == (side, side, 3) == VisualMazeEnv().tapestry.shape
    obs, _ = env.reset(seed=0, options={"position": [0.5, 0.5]})
    photo = load_photo(photo_names().index("hubble_deep_field"))
    # The centre of the maze shows the centre of the photograph (resized to the canvas).
    centre = cv2.resize(photo[:, 64:936], (side, side), interpolation=cv2.INTER_AREA)
    c = side // 2
    np.testing.assert_array_equal(obs, centre[c - 32 : c + 32, c - 32 : c + 32])
    with pytest.raises(ValueError, match="hubble_deep_field"):
        VisualMazeEnv(photo="no-such-photo")
