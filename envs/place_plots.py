"""Pictures of place navigation: the town from above and the views of one state."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from vistask.checks import checked
from vistask.envs.place_navigation import navigation_env
from vistask.envs.place_scene import draw_town
from vistask.envs.place_world import check_int


@checked
def draw_world(env: gym.Env, state=None, pixels_per_metre: float = 12.0) -> np.ndarray:
    """Top-down map of the town of a place-navigation env (``draw_town``), with the agent at
    ``state`` if given.

    Returns:
        (H, W, 3) uint8 RGB image, north up.
    """
    nav = navigation_env(env, "draw_world")
    return draw_town(nav.world, nav.scene, state, pixels_per_metre)


@checked
def view_sheet(env: gym.Env, state, n: int = 8, gap: int = 2) -> np.ndarray:
    """A row of ``n`` jittered views of one state (place, heading): its bank's first views,
    rendered afresh (jitter seeds 0..n-1) beyond the bank's size.

    Returns:
        (H, n * W + (n - 1) * gap, 3) uint8 RGB image, white between the views.
    """
    nav = navigation_env(env, "view_sheet")
    n = check_int("n", n, 1)
    gap = check_int("gap", gap, 0)
    states = nav.world.check_states(state, "state")
    if len(states) != 1:
        raise ValueError(f"view_sheet shows one state, got {states.tolist()}")
    if n <= nav.views_per_state:
        views = nav.views[nav.world.index(states)[0], :n]
    else:
        views = nav.scene.render(states, range(n))[0]
    size = nav.scene.image_size
    sheet = np.full((size, n * size + (n - 1) * gap, 3), 255, np.uint8)
    for k, view in enumerate(views):
        sheet[:, k * (size + gap) : k * (size + gap) + size] = view
    return sheet
