"""Place navigation: the place graph, jittered MuJoCo views and their cache, the oracle,
Gymnasium compliance, the vector env, pictures and errors."""

import cv2
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.envs import (
    Jitter,
    PlaceNavigationEnv,
    PlaceNavigationVectorEnv,
    PlaceOracle,
    PlaceWorld,
    draw_world,
    evaluation_starts,
    place_scene,
    view_sheet,
)
from vistask.envs.place_scene import PlaceScene
from vistask.envs.place_world import FORWARD, HEADING_STEPS, LEFT, RIGHT

VIEWS = 4  # a small bank keeps the tests fast (~2 s of rendering in all)


@pytest.fixture(scope="module", autouse=True)
def cache_dir(tmp_path_factory):
    """Every env of this module caches its views in a temporary folder, not in ~/.cache."""
    path = tmp_path_factory.mktemp("views")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("VISTASK_CACHE_DIR", str(path))
        yield path


@pytest.fixture(scope="module")
def env():
    return PlaceNavigationEnv(views_per_state=VIEWS)


@pytest.fixture(scope="module")
def oracle(env):
    return PlaceOracle(env)


def value_iteration(world: PlaceWorld, sweeps: int = 200) -> np.ndarray:
    """(places, 4) optimal values by brute-force value iteration over (place, heading)."""
    states = world.states_of(np.arange(world.n_states))
    off_goal = states[:, 0] != world.goal
    values = np.zeros(world.n_states)
    for _ in range(sweeps):
        q = np.zeros((world.n_states, 3))
        for a in range(3):
            new, reached = world.step(states, np.full(len(states), a))
            q[:, a] = np.where(reached, world.reward, world.gamma * values[world.index(new)])
        values = np.where(off_goal, q.max(axis=1), 0.0)
    return values.reshape(world.n_places, 4)


# -- the place graph -------------------------------------------------------------------------------
def test_streets_form_a_connected_seeded_maze():
    world = PlaceWorld()
    assert (world.n_places, world.n_states) == (25, 100)
    inner = 2 * 5 * 4  # streets between neighbouring places of a 5 x 5 grid
    assert world.open.sum() // 2 < inner  # some streets are closed
    np.testing.assert_array_equal(PlaceWorld(layout_seed=0).open, world.open)
    assert not np.array_equal(PlaceWorld(layout_seed=1).open, world.open)
    assert PlaceWorld(extra_open=0.0).open.sum() // 2 == world.n_places - 1  # a spanning tree
    assert PlaceWorld(extra_open=1.0).open.sum() // 2 == inner
    assert not world.open[:5, 0].any() and not world.open[::5, 3].any()  # the town's edge
    for seed in range(5):  # every state off the goal place (the last) reaches it
        assert (value_iteration(PlaceWorld(layout_seed=seed))[:-1] > 0).all()


def test_turns_and_forward_moves():
    world = PlaceWorld()
    for place, heading in [(0, 0), (7, 2), (12, 3)]:
        (left,), _ = world.step([[place, heading]], [LEFT])
        (right,), _ = world.step([[place, heading]], [RIGHT])
        assert tuple(left) == (place, (heading + 3) % 4)
        assert tuple(right) == (place, (heading + 1) % 4)
    for place in range(world.n_places):
        for heading in range(4):
            (new,), reached = world.step([[place, heading]], [FORWARD])
            row, col = divmod(place, world.cols)
            dr, dc = HEADING_STEPS[heading]
            expected = (row + dr) * world.cols + col + dc if world.open[place, heading] else place
            assert tuple(new) == (expected, heading)  # a closed street or the edge: stay
            assert reached[0] == (expected == world.goal != place)


def test_forward_into_a_wall_keeps_the_place(env):
    world = env.world
    closed = [(p, h) for p in range(world.n_places) for h in range(4) if not world.open[p, h]]
    rows, cols = np.divmod([p for p, _ in closed], world.cols)
    steps = HEADING_STEPS[[h for _, h in closed]]
    inside = (rows + steps[:, 0] >= 0) & (rows + steps[:, 0] < world.rows)
    inside &= (cols + steps[:, 1] >= 0) & (cols + steps[:, 1] < world.cols)
    assert inside.any() and not inside.all()  # walls inside the town, and its edge
    for state in (closed[np.argmax(inside)], closed[np.argmin(inside)]):
        env.reset(seed=0, options={"state": state})
        obs, reward, terminated, truncated, info = env.step(FORWARD)
        np.testing.assert_array_equal(info["state"], state)
        assert (reward, terminated, truncated) == (0.0, False, False)
        assert obs.shape == (80, 80, 3) and obs.dtype == np.uint8


def test_reaching_the_goal_terminates_with_reward_100(env):
    world = env.world
    place, heading = next(
        (p, h)
        for p in range(world.n_places)
        for h in range(4)
        if world.open[p, h] and world.step([[p, h]], [FORWARD])[0][0, 0] == world.goal
    )
    env.reset(seed=0, options={"state": (place, heading)})
    _, reward, terminated, truncated, info = env.step(FORWARD)
    assert (reward, terminated, truncated) == (100.0, True, False)
    assert info["state"][0] == world.goal and env.gamma == 0.9


def test_reset_starts_off_the_goal_or_at_the_given_state(env):
    seen = set()
    for seed in range(200):
        _, info = env.reset(seed=seed)
        assert info["state"][0] != env.world.goal
        seen.add(tuple(info["state"]))
    assert len(seen) > 60  # uniform over the 96 states off the goal place
    obs, info = env.reset(seed=1, options={"state": (7, 2)})
    np.testing.assert_array_equal(info["state"], [7, 2])
    np.testing.assert_array_equal(info["position"], [7, 2])  # what rlvc's collect records
    assert any((obs == view).all() for view in env.views[7 * 4 + 2])


# -- views -----------------------------------------------------------------------------------------
def test_views_change_with_the_jitter_seed_and_repeat_with_it(env):
    views = env.scene.render([[6, 1]], [0, 0, 1, 2])[0]
    np.testing.assert_array_equal(views[0], views[1])
    assert not np.array_equal(views[0], views[2]) and not np.array_equal(views[2], views[3])
    np.testing.assert_array_equal(views[0], env.views[6 * 4 + 1, 0])  # the bank's seed 0
    bank = env.views.reshape(env.world.n_states, VIEWS, -1)
    assert all(len({v.tobytes() for v in state}) == VIEWS for state in bank)
    assert not np.array_equal(env.views[0, 0], env.views[1, 0])  # turning changes the view


def test_without_jitter_every_view_of_a_state_is_the_same():
    scene = PlaceScene(PlaceWorld(rows=2, cols=2), image_size=32, jitter=Jitter.none())
    views = scene.render([[0, 1]], [0, 5, 9])[0]
    assert views.shape == (3, 32, 32, 3) and views.std() > 0
    np.testing.assert_array_equal(views[0], views[1])
    np.testing.assert_array_equal(views[0], views[2])


def test_every_face_has_its_own_textured_photo_crop(env):
    scene = env.scene
    assert len(scene.textures) == len(scene.facades) == 4 * 16 + 20 + 2 * len(scene.walls)
    assert len({t.tobytes() for t in scene.textures}) == len(scene.textures)
    sift = cv2.SIFT_create(contrastThreshold=0.02)
    keypoints = [len(sift.detect(view, None)) for view in env.views[:, 0]]
    assert np.median(keypoints) >= 15  # SIFT finds texture in the views


def test_test_views_are_held_out(env):
    images, states = env.test_views(per_state=2)
    assert images.shape == (env.world.n_states * 2, 80, 80, 3) and images.dtype == np.uint8
    np.testing.assert_array_equal(states[:4], [[0, 0], [0, 0], [0, 1], [0, 1]])
    np.testing.assert_array_equal(states[-1], [env.world.n_places - 1, 3])
    training = {v.tobytes() for v in env.views.reshape(-1, 80, 80, 3)}
    assert not any(image.tobytes() in training for image in images)
    np.testing.assert_array_equal(images, env.test_views(per_state=2)[0])


def test_training_views_are_the_bank_and_the_task_marks_their_optimal_actions(env, oracle):
    from vistask.experiments.tasks import PlaceTask

    images, states = env.training_views()
    assert images.shape == (env.world.n_states * VIEWS, 80, 80, 3)
    index = 6 * VIEWS + 3  # state 6: place 1, heading 2
    np.testing.assert_array_equal(images[index], env.views[6, 3])
    np.testing.assert_array_equal(states[index], [1, 2])
    percepts, optimal = PlaceTask(env).train_set()
    np.testing.assert_array_equal(percepts, images)
    np.testing.assert_array_equal(optimal[index], oracle.optimal_actions([1, 2]))


def test_the_disk_cache_round_trips(tmp_path, monkeypatch):
    kwargs = {"rows": 2, "cols": 2, "image_size": 32, "views_per_state": 2, "cache_dir": tmp_path}
    first = PlaceNavigationEnv(**kwargs).views
    files = list((tmp_path / "place_navigation").iterdir())
    assert len(files) == 1 and files[0].suffix == ".npy"  # no temporary file left behind
    place_scene.clear_memory_cache()

    def no_rendering(*args, **kwargs):
        raise AssertionError("the views should come from the disk cache")

    monkeypatch.setattr(PlaceScene, "render", no_rendering)
    np.testing.assert_array_equal(PlaceNavigationEnv(**kwargs).views, first)
    with pytest.raises(AssertionError, match="disk cache"):  # another world, another file
        PlaceNavigationEnv(**{**kwargs, "layout_seed": 1}).views  # noqa: B018
    monkeypatch.undo()
    files[0].write_bytes(b"damaged")
    place_scene.clear_memory_cache()
    np.testing.assert_array_equal(PlaceNavigationEnv(**kwargs).views, first)  # rendered again


# -- oracle ----------------------------------------------------------------------------------------
def test_oracle_values_equal_value_iteration(oracle):
    np.testing.assert_allclose(oracle.values, value_iteration(oracle.world), rtol=1e-12)
    assert oracle.steps.max() < 50 and (oracle.steps[:-1] > 0).all()


def test_optimal_actions_include_ties():
    open_town = PlaceOracle(PlaceNavigationEnv(extra_open=1.0))  # goal: place 24 (SE)
    # Place 4 (north-east corner) facing north: turning twice either way, then 4 steps south.
    np.testing.assert_array_equal(open_town.optimal_actions((4, 0)), [True, True, False])
    assert open_town.steps[4, 0] == 6
    # Place 0 facing east: 4 steps east, a right turn, 4 steps south; turning first costs one
    # more turn.
    np.testing.assert_array_equal(open_town.optimal_actions((0, 1)), [False, False, True])
    np.testing.assert_array_equal(open_town.optimal_actions((0, 0)), [False, True, False])
    assert open_town.optimal_actions([[0, 1], [0, 0]]).shape == (2, 3)
    assert open_town.values[0, 1] == pytest.approx(100 * 0.9**8)  # 9 actions


def test_following_the_oracle_earns_the_return_it_predicts(oracle):
    env = gym.make("vistask/PlaceNavigation-v0", views_per_state=VIEWS)
    for start in evaluation_starts(env, 20, seed=0):
        _, info = env.reset(seed=0, options={"state": start})
        ret, t, terminated, truncated = 0.0, 0, False, False
        while not (terminated or truncated):
            assert oracle.optimal_actions(info["state"])[oracle.act(info["state"][None])[0]]
            _, reward, terminated, truncated, info = env.step(
                int(oracle.act(info["state"][None])[0])
            )
            ret += 0.9**t * reward
            t += 1
        assert terminated and ret == pytest.approx(oracle.value(start)[0])
        assert t == oracle.steps[tuple(start)]


def test_evaluate_scores_the_oracle_at_one_and_random_far_below(oracle):
    result = oracle.evaluate(oracle.as_policy(), views="train")
    starts = evaluation_starts(oracle.env)
    assert len(result.returns) == len(starts) == 96
    np.testing.assert_allclose(result.returns, oracle.value(starts))
    assert oracle.return_ratio(result) == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    randomly = oracle.return_ratio(
        lambda percepts, states: rng.integers(3, size=len(percepts)), per_state=2
    )
    assert randomly < 0.3
    seen = []
    oracle.evaluate(lambda p, s: seen.append(p) or oracle.act(s), starts[:3], per_state=2)
    assert all(p.shape[1:] == (80, 80, 3) for p in seen)


def test_evaluate_with_training_views_replays_the_env(env, oracle):
    start = np.array([[3, 2]])
    shown = []
    oracle.evaluate(lambda p, s: shown.append(p[0]) or oracle.act(s), start, seed=5, views="train")
    obs, info = env.reset(seed=5, options={"state": start[0]})
    for view in shown:
        np.testing.assert_array_equal(view, obs)
        obs, *_, info = env.step(int(oracle.act(info["state"][None])[0]))


# -- gymnasium -------------------------------------------------------------------------------------
def test_gymnasium_env_checker_passes():
    made = gym.make("vistask/PlaceNavigation-v0", views_per_state=VIEWS)
    check_env(made.unwrapped, skip_render_check=False)


def test_registration(env):
    made = gym.make("vistask/PlaceNavigation-v0", views_per_state=VIEWS)
    assert made.spec.max_episode_steps == 50 and made.unwrapped.gamma == 0.9
    assert made.action_space.n == 3 and made.observation_space.shape == (80, 80, 3)
    again = gym.make("vistask/PlaceNavigation-v0", views_per_state=VIEWS)
    assert made.unwrapped.views is again.unwrapped.views  # one bank in memory for equal worlds
    np.testing.assert_array_equal(made.unwrapped.views, env.views)


def test_vector_env_gives_the_episodes_of_separate_seeded_envs():
    n, kwargs = 5, {"views_per_state": VIEWS, "max_episode_steps": 6}
    batch = gym.make_vec(
        "vistask/PlaceNavigation-v0", num_envs=n, vectorization_mode="vector_entry_point", **kwargs
    )
    assert isinstance(batch.unwrapped, PlaceNavigationVectorEnv)
    single = gym.vector.SyncVectorEnv(
        [lambda: gym.make("vistask/PlaceNavigation-v0", **kwargs)] * n,
        autoreset_mode=gym.vector.AutoresetMode.DISABLED,
    )
    rng = np.random.default_rng(0)
    views, info = batch.reset(seed=3)
    expected, expected_info = single.reset(seed=3)
    np.testing.assert_array_equal(info["state"], expected_info["state"])
    ended = 0
    for _ in range(40):
        np.testing.assert_array_equal(views, expected)
        actions = rng.integers(3, size=n)
        views, rewards, terminated, truncated, info = batch.step(actions)
        expected, *outcome, expected_info = single.step(actions)
        for got, want in zip((rewards, terminated, truncated), outcome, strict=True):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(info["state"], expected_info["state"])
        done = terminated | truncated
        if done.any():  # only the ended copies restart, each from its own generator
            ended += done.sum()
            views, info = batch.reset(options={"reset_mask": done})
            expected, expected_info = single.reset(options={"reset_mask": done})
            np.testing.assert_array_equal(info["_state"], done)
            np.testing.assert_array_equal(info["state"][done], expected_info["state"][done])
    assert ended > n


def test_vector_env_starts_at_given_states_and_rejects_bad_input(env):
    batch = env.vector_copies(2, max_episode_steps=10)
    with pytest.raises(RuntimeError, match="reset"):
        batch.step(np.array([0, 1]))
    _, info = batch.reset(seed=0, options={"states": [[1, 2], [3, 0]]})
    np.testing.assert_array_equal(info["position"], [[1, 2], [3, 0]])
    with pytest.raises(ValueError, match="off the goal"):
        batch.reset(options={"states": [[1, 2], [24, 0]]})
    with pytest.raises(ValueError, match="2 integer actions"):
        batch.step(np.array([0, 3]))


# -- pictures --------------------------------------------------------------------------------------
def test_pictures(env):
    world = draw_world(env, (3, 1))
    assert world.ndim == 3 and world.dtype == np.uint8 and world.shape[0] == world.shape[1]
    rendering = PlaceNavigationEnv(views_per_state=VIEWS, render_mode="rgb_array")
    rendering.reset(seed=0, options={"state": (3, 1)})
    np.testing.assert_array_equal(rendering.render(), world)
    sheet = view_sheet(env, (6, 1), n=3)
    assert sheet.shape == (80, 3 * 80 + 2 * 2, 3)
    np.testing.assert_array_equal(sheet[:, :80], env.views[6 * 4 + 1, 0])
    assert view_sheet(env, (6, 1), n=VIEWS + 1).shape[1] == (VIEWS + 1) * 82 - 2


# -- errors ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rows": 1}, "rows"),
        ({"cols": 2.5}, "cols"),
        ({"goal": 25}, "goal"),
        ({"extra_open": 1.5}, "extra_open"),
        ({"gamma": 1.0}, "gamma"),
        ({"image_size": 8}, "image_size"),
        ({"views_per_state": 0}, "views_per_state"),
        ({"spacing": 2.0}, "spacing"),
        ({"fovy": 170.0}, "fovy"),
        ({"jitter": Jitter(offset=5.0)}, "narrowest street"),
        ({"render_mode": "human"}, "render_mode"),
    ],
)
def test_bad_kwargs_raise_clear_errors(kwargs, match):
    with pytest.raises((TypeError, ValueError), match=match):
        PlaceNavigationEnv(**kwargs)


def test_bad_jitter_ranges_are_refused():
    with pytest.raises(ValueError, match="pitch"):
        Jitter(pitch=(5.0, -5.0))
    with pytest.raises(ValueError, match="offset"):
        Jitter(offset=-1.0)


@pytest.mark.parametrize(
    ("state", "match"),
    [((24, 0), "goal place"), ((3, 4), "headings"), ((-1, 0), "places"), ((1.5, 0), "integer")],
)
def test_bad_start_states_are_refused(env, state, match):
    with pytest.raises(ValueError, match=match):
        env.reset(options={"state": state})


@pytest.mark.parametrize("action", [3, -1, 1.5, "forward"])
def test_invalid_actions_are_rejected(env, action):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="invalid action"):
        env.step(action)


def test_oracle_and_evaluation_refuse_bad_input(env, oracle):
    with pytest.raises(TypeError, match="PlaceNavigationEnv"):
        PlaceOracle(gym.make("vistask/VisualMaze-v0"))
    with pytest.raises(ValueError, match="views"):
        oracle.evaluate(oracle.as_policy(), views="validation")
    with pytest.raises(ValueError, match="goal place"):
        oracle.evaluate(oracle.as_policy(), [[24, 1]])
    with pytest.raises(ValueError, match=r"actions in 0\.\.2"):
        oracle.evaluate(lambda p, s: np.full(len(p), 3), [[0, 0]], views="train")
    with pytest.raises(ValueError, match="headings"):
        oracle.optimal_actions((0, 7))
    with pytest.raises(ValueError, match="one state"):
        view_sheet(env, [[0, 0], [1, 1]])
