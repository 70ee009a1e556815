"""Navigation between the places of a small town seen through a jittered camera: the paper's
Fig. 8 outdoor task, simulated with MuJoCo.

The town is a rows x cols grid of places (street crossings). Buildings stand in the blocks
between the streets, walls close some streets (so that the graph of places is a little maze),
and a wall surrounds the town. Every facade and wall face shows its own crop of a photograph
bundled with an installed package (``vistask.envs.tapestry.PHOTOS``), so that SIFT finds
texture on it.

State: (place, heading); place = row * cols + column, row 0 on the north edge; heading 0..3 =
N, E, S, W (``HEADING_NAMES``). World coordinates (MuJoCo): x east, y north, z up, metres;
place (row, column) stands at (column * spacing, -row * spacing).

Percepts: the camera view from the place along the heading, jittered on every visit (camera
position within the place, heading, pitch, height, sun and ambient light: ``Jitter``), as two
photographs taken at one spot are never the same. Rendering dominates the cost, so every
state's views are rendered once into a bank from fixed jitter seeds, kept in memory and on
disk under ``$VISTASK_CACHE_DIR`` (default ``~/.cache/vistask``), keyed by a hash of the
scene, the jitter, the seeds and the renderer's version; a visit shows a view drawn from the
bank. Held-out views (``test_views``) come from other jitter seeds.

Rendering uses MUJOCO_GL (set to "egl" here when unset).
"""

from __future__ import annotations

import os
from typing import ClassVar

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from vistask.checks import checked
from vistask.envs.batched import BatchedCopies
from vistask.envs.place_scene import (
    TEST_SEED_OFFSET,
    TEST_VIEWS_PER_STATE,
    Jitter,
    PlaceScene,
    draw_town,
    view_bank,
)
from vistask.envs.place_world import PLACE_ACTION_NAMES, PlaceWorld, check_int


# -- environments --------------------------------------------------------------------------------
@checked
class PlaceNavigationEnv(gym.Env):
    """Walk through a small town to the goal place, seeing only a jittered camera view.

    Observation: (image_size, image_size, 3) uint8 RGB view from the place along the heading,
    drawn on every visit from the state's bank of ``views_per_state`` jittered views.
    Actions: ``Discrete(3)``: turn left, turn right (quarter turns), forward (to the next place
    along the heading if the street is open, else stay) (``PLACE_ACTION_NAMES``). Reward 100
    when the goal place is reached (terminated), 0 otherwise; ``gamma`` = 0.9. Starts are
    uniform over the states off the goal place, or ``options={"state": (place, heading)}``.
    ``info["state"]`` holds the true (place, heading), also as ``info["position"]``, the name
    under which ``vistask.rlvc.collect`` records true states (oracles and plots only; agents
    must not use it).

    The first use of the views renders the bank (4 ms a view with EGL on two CPU cores: 14 s
    for the default 100 states x 32 views, 61 MB) and caches it on disk; an env in another
    process loads it in 0.1 s.

    Example:
        >>> import gymnasium as gym, vistask.envs
        >>> env = gym.make("vistask/PlaceNavigation-v0")
        >>> obs, info = env.reset(seed=0, options={"state": (0, 1)})  # place 0, facing east
        >>> obs.shape, info["state"]
        ((80, 80, 3), array([0, 1]))
        >>> obs, reward, terminated, truncated, info = env.step(2)  # forward

    Args:
        rows, cols, layout_seed, goal, extra_open, gamma: see ``PlaceWorld``.
        image_size: side of the square views in pixels.
        views_per_state: jittered views rendered per state (the bank).
        spacing, fovy: see ``PlaceScene``.
        jitter: ranges of the per-view jitter (default ``Jitter()``).
        cache_dir: folder of the disk cache (default ``default_cache_dir()``).
        disk_cache: read and write the disk cache (else render in every new process).
        render_mode: ``None`` or ``"rgb_array"`` (a top-down map, ``draw_town``).
    """

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        rows: int = 5,
        cols: int = 5,
        layout_seed: int = 0,
        goal: int | None = None,
        extra_open: float = 0.3,
        gamma: float = 0.9,
        image_size: int = 80,
        views_per_state: int = 32,
        spacing: float = 6.0,
        fovy: float = 75.0,
        jitter: Jitter | None = None,
        cache_dir: str | os.PathLike | None = None,
        disk_cache: bool = True,
        render_mode: str | None = None,
    ) -> None:
        self.world = PlaceWorld(rows, cols, layout_seed, goal, extra_open, gamma)
        self.scene = PlaceScene(self.world, image_size, spacing, fovy, jitter)
        self.views_per_state = check_int("views_per_state", views_per_state, 1)
        if self.views_per_state > TEST_SEED_OFFSET:
            raise ValueError(f"views_per_state must be <= {TEST_SEED_OFFSET}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.gamma = self.world.gamma
        if cache_dir is not None and not disk_cache:
            raise ValueError("cache_dir acts only with disk_cache=True, which is off")
        self.cache_dir, self.disk_cache = cache_dir, bool(disk_cache)
        self.render_mode = render_mode
        self.observation_space = spaces.Box(0, 255, (image_size, image_size, 3), np.uint8)
        self.action_space = spaces.Discrete(len(PLACE_ACTION_NAMES))
        self.state = self.world.start_states[0].copy()
        self._views: np.ndarray | None = None

    @property
    def views(self) -> np.ndarray:
        """(states, views_per_state, H, W, 3) uint8 bank of training views (jitter seeds
        0..views_per_state-1), loaded or rendered on first use; index ``place * 4 + heading``.
        """
        if self._views is None:
            seeds = range(self.views_per_state)
            self._views = view_bank(self.scene, seeds, self.cache_dir, self.disk_cache)
        return self._views

    def test_bank(self, per_state: int = TEST_VIEWS_PER_STATE) -> np.ndarray:
        """(states, per_state, H, W, 3) uint8 held-out views: jitter seeds from
        ``TEST_SEED_OFFSET`` on, never in a training bank (cached like it)."""
        per_state = check_int("per_state", per_state, 1)
        seeds = range(TEST_SEED_OFFSET, TEST_SEED_OFFSET + per_state)
        return view_bank(self.scene, seeds, self.cache_dir, self.disk_cache)

    def test_views(self, per_state: int = TEST_VIEWS_PER_STATE) -> tuple[np.ndarray, np.ndarray]:
        """Held-out views of every state (see ``test_bank``).

        Returns:
            images (N, H, W, 3) uint8 and their states (N, 2) (place, heading), N = states *
            per_state, state-major.
        """
        return self._flat(self.test_bank(per_state))

    def training_views(self) -> tuple[np.ndarray, np.ndarray]:
        """The training bank (``views``) as images (N, H, W, 3) uint8 and their states (N, 2),
        N = states * views_per_state, state-major."""
        return self._flat(self.views)

    def _flat(self, bank: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        states = self.world.states_of(np.arange(self.world.n_states))
        return bank.reshape(-1, *bank.shape[2:]), np.repeat(states, bank.shape[1], axis=0)

    def percept(self, state, view: int) -> np.ndarray:
        """View ``view`` of the bank of ``state`` (place, heading) (a fresh array)."""
        index = self.world.index(state)[0]
        if not 0 <= view < self.views_per_state:
            raise ValueError(f"view must be in 0..{self.views_per_state - 1}, got {view}")
        return self.views[index, view].copy()

    def _observe(self) -> np.ndarray:
        return self.percept(self.state, int(self.np_random.integers(self.views_per_state)))

    def _info(self) -> dict:
        return {"state": self.state.copy(), "position": self.state.copy()}

    # -- gymnasium API -----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode: (observation, info), ``info["position"]`` the true state."""
        super().reset(seed=seed)
        options = options or {}
        if "state" in options:
            state = self.world.check_states(options["state"], "start state")
            if len(state) != 1:
                raise ValueError(f"start state must be one (place, heading), got {state.tolist()}")
            if state[0, 0] == self.world.goal:
                raise ValueError(f"start state {state[0].tolist()} is on the goal place")
            self.state = state[0].copy()
        else:
            self.state = self.world.sample_start(self.np_random)
        return self._observe(), self._info()

    def step(self, action):
        """Take ``action``: (observation, reward, terminated, truncated, info)."""
        if not self.action_space.contains(action):
            raise ValueError(
                f"invalid action {action!r}: expected an int in 0..2"
                f" ({', '.join(PLACE_ACTION_NAMES)})"
            )
        new, reached = self.world.step(self.state[None], np.array([int(action)]))
        self.state = new[0]
        terminated = bool(reached[0])
        reward = self.world.reward if terminated else 0.0
        return self._observe(), reward, terminated, False, self._info()

    def render(self) -> np.ndarray | None:
        """The picture of ``render_mode="rgb_array"`` (None without a render mode)."""
        if self.render_mode != "rgb_array":
            return None
        return draw_town(self.world, self.scene, self.state)

    def vector_copies(
        self, num_envs: int, max_episode_steps: int | None = None
    ) -> PlaceNavigationVectorEnv:
        """``num_envs`` copies of this env (same world and view bank) stepped as one batch."""
        return PlaceNavigationVectorEnv.like(self, num_envs, max_episode_steps)


@checked
class PlaceNavigationVectorEnv(BatchedCopies):
    """``num_envs`` place-navigation envs stepped as one batch: one table look-up for all.

    Each copy draws its start and its views from its own generator, exactly as a
    ``PlaceNavigationEnv`` reset with the same seed would, so the batch gives the same episodes
    as ``num_envs`` separate envs. Autoreset is off: reset ended copies with
    ``reset(options={"reset_mask": mask})``; ``options={"states": (num_envs, 2)}`` starts the
    reset copies at given states. ``infos["state"]`` (and ``infos["position"]``) hold the true
    states.

    Example:
        >>> envs = gym.make_vec("vistask/PlaceNavigation-v0", num_envs=16,
        ...                     vectorization_mode="vector_entry_point")
        >>> obs, infos = envs.reset(seed=0)       # obs (16, 80, 80, 3); copy i seeded 0 + i
        >>> obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())

    Args:
        num_envs: number of copies.
        max_episode_steps: truncate episodes after this many steps (None: never).
        **kwargs: ``PlaceNavigationEnv`` arguments.
    """

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = None, **kwargs) -> None:
        self._attach(PlaceNavigationEnv(**kwargs), num_envs, max_episode_steps)

    @classmethod
    def like(
        cls, env: PlaceNavigationEnv, num_envs: int, max_episode_steps: int | None = None
    ) -> PlaceNavigationVectorEnv:
        """Copies of an existing env, sharing its (read-only) view bank."""
        envs = cls.__new__(cls)
        envs._attach(env, num_envs, max_episode_steps)
        return envs

    def _attach(
        self, env: PlaceNavigationEnv, num_envs: int, max_episode_steps: int | None
    ) -> None:
        super()._attach(env, num_envs, max_episode_steps)
        self.env = env
        self.states = np.tile(env.world.start_states[0], (num_envs, 1))
        self.shown = np.zeros(num_envs, dtype=np.int64)  # bank index of each copy's view

    @property
    def gamma(self) -> float:
        """The env's discount."""
        return self.env.gamma

    def _draw_views(self, mask: np.ndarray) -> np.ndarray:
        """New views for the copies in ``mask`` (each from its own generator); (num_envs, H, W,
        3) the views of all copies."""
        for i in np.flatnonzero(mask):
            self.shown[i] = self.rngs[i].integers(self.env.views_per_state)
        return self.env.views[self.env.world.index(self.states), self.shown]

    def _infos(self, mask: np.ndarray) -> dict:
        return {
            "state": self.states.copy(),
            "_state": mask.copy(),
            "position": self.states.copy(),
            "_position": mask.copy(),
        }

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Reset the copies (those of ``options["reset_mask"]`` only, if given): (observations,
        infos)."""
        options = options or {}
        world, starts = self.env.world, None
        if "states" in options:
            starts = world.check_states(options["states"], "start states")
            if len(starts) != self.num_envs or (starts[:, 0] == world.goal).any():
                raise ValueError(
                    f"options['states'] must be {self.num_envs} (place, heading) off the goal"
                    f" place {world.goal}, got {starts.tolist()}"
                )
        mask = self._reset_copies(seed, options)
        for i in np.flatnonzero(mask):
            self.states[i] = world.sample_start(self.rngs[i]) if starts is None else starts[i]
        return self._draw_views(mask), self._infos(mask)

    def step(self, actions):
        """Step every copy with ``actions`` (N,): (observations, rewards, terminated, truncated,
        infos)."""
        actions = self._check_actions(actions)
        self.states, terminated = self.env.world.step(self.states, actions)
        truncated = self._count_step()
        rewards = np.where(terminated, self.env.world.reward, 0.0)
        every = np.ones(self.num_envs, dtype=bool)
        return self._draw_views(every), rewards, terminated, truncated, self._infos(every)


def navigation_env(env: gym.Env, user: str) -> PlaceNavigationEnv:
    """The ``PlaceNavigationEnv`` inside ``env``; ``user`` names the caller in the error."""
    nav = env.unwrapped
    if not isinstance(nav, PlaceNavigationEnv):
        raise TypeError(f"{user} needs a PlaceNavigationEnv, got {type(nav).__name__}")
    return nav
