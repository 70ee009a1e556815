"""The visual car on the hill: physics, percepts, vector env, oracle and evaluation."""

import math

import cv2
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.envs import (
    CarOracle,
    VisualMountainCarEnv,
    VisualMountainCarVectorEnv,
    evaluate_car_policy,
    hill_step,
    start_states,
)
from vistask.envs.car_oracle import rollout
from vistask.envs.car_plots import percepts_at, plot_car_policy, plot_road, state_grid
from vistask.envs.mountain_car import NEEDLE_STOP, acceleration, outcome
from vistask.rlvc.database import collect

GAMMA = 0.95


@pytest.fixture(scope="module")
def env() -> VisualMountainCarEnv:
    return VisualMountainCarEnv()


@pytest.fixture(scope="module")
def oracle() -> CarOracle:
    return CarOracle.solve(grid=101)


def always(action):
    return lambda percepts, states: np.full(len(states), action)


# -- physics ----------------------------------------------------------------------------------
def plain_euler(p: float, s: float, u: float) -> tuple[float, float]:
    """Ernst et al. (2005), appendix, written out: 100 Euler steps of 1 ms."""
    for _ in range(100):
        if p < 0:
            d1, d2 = 2 * p + 1, 2.0
        else:
            d1 = (1 + 5 * p**2) ** -1.5
            d2 = -15 * p * (1 + 5 * p**2) ** -2.5
        a = u / (1 * (1 + d1**2)) - 9.81 * d1 / (1 + d1**2) - s**2 * d1 * d2 / (1 + d1**2)
        p, s = p + 0.001 * s, s + 0.001 * a
    return p, s


def test_one_step_matches_a_plain_euler_loop():
    rng = np.random.default_rng(0)
    states = np.concatenate([rng.uniform([-1, -3], [1, 3], (30, 2)), [[0.0, 0.0], [-0.02, 0.5]]])
    actions = rng.integers(2, size=len(states))
    forces = np.where(actions == 1, 4.0, -4.0)
    new, _, _ = hill_step(states, forces)  # the batched numpy path
    expected = np.array([plain_euler(p, s, u) for (p, s), u in zip(states, forces, strict=True)])
    np.testing.assert_allclose(new, expected, rtol=0, atol=1e-12)
    one_by_one = np.concatenate(
        [hill_step(states[i : i + 1], forces[i : i + 1])[0] for i in range(8)]
    )
    np.testing.assert_array_equal(one_by_one, new[:8])  # the single-car path, bit for bit


def test_acceleration_in_closed_form():
    # At the top of the slope's join (p = 0, H' = 1) at rest and without force: -g/2.
    assert acceleration(np.array([[0.0, 0.0]]), np.array([0.0]))[0] == pytest.approx(-9.81 / 2)
    # At the valley's bottom (p = -0.5, H' = 0) only the force acts, whatever the speed.
    assert acceleration(np.array([[-0.5, 2.0]]), np.array([4.0]))[0] == pytest.approx(4.0)
    # Over p >= 0: H'(0.5) = (1 + 5/4)^-1.5, H'' = -7.5 (1 + 5/4)^-2.5.
    d1, d2 = 2.25**-1.5, -7.5 * 2.25**-2.5
    want = (-4 - 9.81 * d1 - 1.0 * d1 * d2) / (1 + d1 * d1)
    assert acceleration(np.array([[0.5, 1.0]]), np.array([-4.0]))[0] == pytest.approx(want)


@pytest.mark.parametrize(
    ("state", "action", "reward"),
    [
        ((0.99, 2.0), 1, 1.0),  # over the top at a legal speed
        ((-0.99, -2.0), 0, -1.0),  # off the left edge
        ((-0.9, 2.95), 1, -1.0),  # over the speed limit while still on the hill
        ((0.9, 2.9), 1, -1.0),  # over the top, but too fast
        ((0.9, 2.9), 0, 1.0),  # braking brings it over the top under the limit
    ],
)
def test_terminal_rewards(state, action, reward):
    env = VisualMountainCarEnv()
    env.reset(options={"state": state})
    _, got, terminated, truncated, info = env.step(action)
    assert (got, terminated, truncated) == (reward, True, False)
    assert info["position"].shape == (2,)
    if state == (-0.9, 2.95):
        assert abs(info["position"][0]) <= 1 and info["position"][1] > 3


def test_outcome_inside_the_box_is_neither_reward_nor_end():
    rewards, terminal = outcome(np.array([[1.0, 3.0], [-1.0, -3.0], [0.0, 0.0], [1.01, 3.01]]))
    np.testing.assert_array_equal(rewards, [0, 0, 0, -1])
    np.testing.assert_array_equal(terminal, [False, False, False, True])


# -- environment --------------------------------------------------------------------------------
def test_gymnasium_env_checker_passes():
    check_env(gym.make("vistask/VisualMountainCar-v0").unwrapped, skip_render_check=False)


def test_registration_and_reset(env):
    made = gym.make("vistask/VisualMountainCar-v0")
    assert made.spec.max_episode_steps == 20 and made.unwrapped.gamma == GAMMA
    obs, info = made.reset(seed=0, options={"state": (-0.5, 0.25)})
    assert obs.shape == (96, 192, 3) and obs.dtype == np.uint8
    np.testing.assert_array_equal(info["position"], [-0.5, 0.25])
    starts = np.stack([made.reset(seed=i)[1]["position"] for i in range(200)])
    assert starts[:, 0].min() >= -1 and starts[:, 0].max() < 1
    assert starts[:, 1].min() >= -3 and starts[:, 1].max() < 3
    assert starts[:, 1].min() < -2.5 and starts[:, 1].max() > 2.5  # the whole plane


@pytest.mark.parametrize(
    "state", [(1.5, 0.0), (0.0, 3.5), (0.0,), (np.nan, 0.0), [[0.0, 0.0], [0.1, 0.0]]]
)
def test_bad_start_states_are_rejected(env, state):
    with pytest.raises(ValueError, match="start state"):
        env.reset(options={"state": state})


@pytest.mark.parametrize("action", [2, -1, 0.5, "right"])
def test_invalid_actions_are_rejected(env, action):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="invalid action"):
        env.step(action)


def test_percepts_differ_in_speed_on_the_gauge_only_and_in_position_on_the_road_only(env):
    w = env.percepts.road_width
    slow, fast = env.percept_at((0.2, -1.0)), env.percept_at((0.2, 1.0))
    np.testing.assert_array_equal(slow[:, :w], fast[:, :w])
    assert (slow[:, w:] != fast[:, w:]).any()
    left, right = env.percept_at((-0.3, 1.0)), env.percept_at((0.3, 1.0))
    np.testing.assert_array_equal(left[:, w:], right[:, w:])
    assert (left[:, :w] != right[:, :w]).any()
    a, b = env.percept_at((0.2, 0.30)), env.percept_at((0.2, 0.32))  # small speed changes show
    assert (a != b).any()


def test_needle_never_covers_the_numerals(env):
    view = env.percepts
    g = view.gauge_size
    yy, xx = np.mgrid[:g, :g] + 0.5
    ring = np.hypot(xx - view.centre[0], yy - view.centre[1]) > 0.22 * g  # the numerals
    numeral_ink = (view.dial.min(axis=2) < 128) & ring
    assert numeral_ink.sum() > 100  # the ring holds the numerals' ink
    for s in np.linspace(-3, 3, 121):
        gauge = env.percept_at((0.0, s))[:, view.road_width :]
        np.testing.assert_array_equal(gauge[ring], view.dial[ring])


def test_numerals_lie_outside_the_sift_windows_of_the_tip_and_the_hub(env):
    # A SIFT descriptor sees pixels up to ~10.6 sigma (= 5.3 keypoint sizes) from its
    # keypoint: numerals there would change the tip's and the hub's words with the speed.
    view = env.percepts
    g = view.gauge_size
    yy, xx = np.mgrid[:g, :g] + 0.5
    radius = np.hypot(xx - view.centre[0], yy - view.centre[1])
    grey = cv2.cvtColor(np.ascontiguousarray(view.dial), cv2.COLOR_RGB2GRAY)
    ink = (grey < 200) & (radius < view.dial_radius - 3)
    nearest_ink = radius[ink].min()
    sift = cv2.SIFT_create(contrastThreshold=0.02)
    reach = 3 * 2.5 * math.sqrt(2) / 2  # window radius per keypoint size (size = 2 sigma)
    found = 0
    for s in np.linspace(-3, 3, 25):
        gauge = np.ascontiguousarray(env.percept_at((0.0, s))[:, view.road_width :])
        keypoints = sift.detect(cv2.cvtColor(gauge, cv2.COLOR_RGB2GRAY), None)
        for point, gap in (
            (view.tip(s), nearest_ink - view.tip_radius),
            (view.centre, nearest_ink),
        ):
            sizes = [k.size for k in keypoints if math.dist(k.pt, point) < 1.5]
            found += bool(sizes)
            assert all(reach * size < gap for size in sizes), (s, point, sizes, gap)
    assert found >= 48  # tip and hub, nearly always


def test_needle_goes_on_past_the_numerals_to_its_stops(env):
    view = env.percepts
    assert view.angle(-3.0) == pytest.approx(math.radians(210))
    assert view.angle(3.0) == pytest.approx(math.radians(-30))
    assert view.angle(-3.5) > view.angle(-3.0) and view.angle(3.5) < view.angle(3.0)
    assert view.angle(-9.0) == view.angle(-NEEDLE_STOP) < math.radians(270)
    assert view.angle(9.0) == view.angle(NEEDLE_STOP) > math.radians(-90)
    # Over the speed limit the gauges differ, not one pinned needle for all.
    assert (view(np.array([0.0, -3.4])) != view(np.array([0.0, -3.0]))).any()


def test_render_shows_the_whole_road_and_the_gauge():
    env = gym.make("vistask/VisualMountainCar-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    view = env.unwrapped.percepts
    assert frame.shape[0] == 96 and frame.shape[1] > view.span + view.road_width


# -- vector env ----------------------------------------------------------------------------------
def test_vector_env_gives_the_episodes_of_separate_seeded_envs():
    n = 5
    batch = gym.make_vec(
        "vistask/VisualMountainCar-v0",
        num_envs=n,
        vectorization_mode="vector_entry_point",
        max_episode_steps=9,
    )
    assert isinstance(batch.unwrapped, VisualMountainCarVectorEnv)
    single = gym.vector.SyncVectorEnv(
        [lambda: gym.make("vistask/VisualMountainCar-v0", max_episode_steps=9)] * n,
        autoreset_mode=gym.vector.AutoresetMode.DISABLED,
    )
    rng = np.random.default_rng(0)
    views, info = batch.reset(seed=3)
    expected, expected_info = single.reset(seed=3)
    np.testing.assert_array_equal(info["position"], expected_info["position"])
    ended = terminated_any = 0
    for _ in range(40):
        np.testing.assert_array_equal(views, expected)
        actions = rng.integers(2, size=n)
        views, rewards, terminated, truncated, info = batch.step(actions)
        expected, *outcome_, expected_info = single.step(actions)
        for got, want in zip((rewards, terminated, truncated), outcome_, strict=True):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(info["position"], expected_info["position"])
        done = terminated | truncated
        terminated_any += terminated.sum()
        if done.any():
            ended += done.sum()
            views, info = batch.reset(options={"reset_mask": done})
            expected, expected_info = single.reset(options={"reset_mask": done})
            np.testing.assert_array_equal(info["position"][done], expected_info["position"][done])
    assert ended > n and terminated_any > 0


def test_vector_env_starts_at_given_states_and_rejects_bad_input():
    batch = VisualMountainCarVectorEnv(num_envs=2)
    with pytest.raises(RuntimeError, match="reset"):
        batch.step(np.array([0, 1]))
    states = np.array([[-0.5, 0.0], [0.3, -1.0]])
    _, info = batch.reset(seed=0, options={"states": states})
    np.testing.assert_array_equal(info["position"], states)
    for actions in (np.array([0]), np.array([0, 2]), np.array([0.0, 1.0])):
        with pytest.raises(ValueError, match="2 integer actions"):
            batch.step(actions)
    with pytest.raises(ValueError, match="reset_mask"):
        batch.reset(options={"reset_mask": np.array([1, 0])})
    with pytest.raises(ValueError, match="states"):
        batch.reset(options={"states": states[:1]})


def test_collect_uses_the_vector_env_and_keeps_true_states():
    env = gym.make("vistask/VisualMountainCar-v0")
    transitions = collect(env, 400, n_envs=32)
    assert len(transitions) == 400 and transitions.positions.shape == (len(transitions.percepts), 2)
    assert transitions.terminal.any()


# -- oracle and evaluation -------------------------------------------------------------------------
def test_oracle_acts_sensibly_at_hand_checked_states(oracle):
    # Pushing right at (0.9, 2.9) goes over the top too fast (-1); pushing left gets there
    # under the limit (+1): the values are exact, with no bootstrap.
    np.testing.assert_allclose(oracle.lookahead(np.array([[0.9, 2.9]])), [[1.0, -1.0]])
    # Near the left edge moving left, pushing left falls off; pushing right saves the car.
    assert oracle.act(np.array([[-0.9, -1.0]]))[0] == 1
    # At rest in the valley the force (4) is too weak to climb: always pushing right rocks
    # the car forever; the oracle first swings back left, then gets up.
    valley = np.array([[-0.5, 0.0]])
    assert rollout(always(1), valley).returns[0] == 0.0
    assert oracle.act(valley)[0] == 0
    assert rollout(oracle.as_policy(), valley).returns[0] > 0.3


def test_oracle_values_agree_with_its_own_rollouts(oracle):
    starts = start_states(oracle, 20)
    result = rollout(oracle.as_policy(), starts)
    # A win in k steps returns gamma^(k-1); the interpolated V estimates it (V jumps by a
    # factor gamma across the borders between step counts, where interpolation smears it).
    np.testing.assert_allclose(result.returns, GAMMA ** (result.steps - 1))
    error = np.abs(oracle.value(starts) - result.returns)
    assert np.median(error) < 0.02 and np.mean(error < 0.05) >= 0.8


def test_oracle_beats_random_and_always_right_from_the_starts(env, oracle):
    starts = start_states(oracle, 30)
    np.testing.assert_array_equal(starts, start_states(oracle, 30))  # fixed
    best = evaluate_car_policy(env, oracle.as_policy(), starts)
    assert best.returns.shape == (30,) and (best.returns > 0).all()
    rng = np.random.default_rng(0)
    random = evaluate_car_policy(env, lambda x, s: rng.integers(2, size=len(s)), starts)
    right = evaluate_car_policy(env, always(1), starts)
    assert best.mean > right.mean + 0.2 and best.mean > random.mean + 0.4


def test_evaluation_discounts_from_the_terminal_step(env):
    # (-0.9, -1) pushing right: the top after 12 steps (see the oracle's test above).
    result = evaluate_car_policy(env, always(1), np.array([[-0.9, -1.0], [0.9, 2.9]]))
    np.testing.assert_array_equal(result.steps, [12, 1])
    np.testing.assert_allclose(result.returns, [GAMMA**11, -1.0])
    with pytest.raises(ValueError, match=r"actions in 0\.\.1"):
        evaluate_car_policy(env, always(2), np.array([[0.0, 0.0]]))


def test_plots_are_written(env, oracle, tmp_path):
    grid = 12
    states = state_grid(grid)
    assert percepts_at(env, states).shape == (grid * grid, 96, 192, 3)
    actions = oracle.act(states).reshape(grid, grid)
    assert plot_car_policy({"oracle": actions, "nodes": oracle.policy}, tmp_path / "p.png").exists()
    assert plot_road(env, (0.1, -2.0), tmp_path / "r.png").exists()
    assert math.isclose(states[0, 0], -1 + 1 / grid) and math.isclose(
        states[grid, 1], -3 + 6 * 1.5 / grid
    )
