"""The place graph of place navigation: a rows x cols grid of places (street crossings) with
some streets closed by walls, and the moves between (place, heading) states.

State: (place, heading); place = row * cols + column, row 0 on the north edge; heading 0..3 =
N, E, S, W (``HEADING_NAMES``). World coordinates (MuJoCo): x east, y north, z up, metres;
place (row, column) stands at (column * spacing, -row * spacing).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vistask.checks import checked

PLACE_ACTION_NAMES: tuple[str, ...] = ("left", "right", "forward")
LEFT, RIGHT, FORWARD = range(3)
HEADING_NAMES: tuple[str, ...] = ("N", "E", "S", "W")
# (row, column) change of a move along each heading; row 0 is the north edge.
HEADING_STEPS = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]])
# Unit vector of each heading in world (x east, y north).
HEADING_VECTORS = np.array([[0.0, 1.0], [1.0, 0.0], [0.0, -1.0], [-1.0, 0.0]])


def check_int(name: str, value, low: int) -> int:
    """``value`` as an int; a ``ValueError`` naming ``name`` unless it is an integer >= ``low``."""
    if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


# -- the place graph ---------------------------------------------------------------------------
@checked
@dataclass(frozen=True)
class PlaceWorld:
    """The graph of places and its true dynamics, shared by the env, its vector env, the oracle
    and the pictures.

    Example:
        >>> world = PlaceWorld(rows=5, cols=5, layout_seed=0)
        >>> world.n_places, world.n_states
        (25, 100)
        >>> world.step(np.array([[0, 1]]), np.array([FORWARD]))  # from place 0 facing east

    Args:
        rows, cols: the grid of places (>= 2 each).
        layout_seed: draws the closed streets (and the scene: buildings, photo crops).
        goal: the goal place (default: the south-east corner, ``rows * cols - 1``).
        extra_open: fraction of the streets outside a random spanning tree of the grid that are
            open; the others are closed by walls (0: a perfect maze, 1: every street open).
        gamma: the task's discount factor.
        reward: reward for reaching the goal place.

    Attributes:
        open: (places, 4) bool: the street from the place along each heading is open (the
            town's edge counts as closed).
        next_state: (states, 3) successor state index of each state index and action.
    """

    rows: int = 5
    cols: int = 5
    layout_seed: int = 0
    goal: int | None = None
    extra_open: float = 0.3
    gamma: float = 0.9
    reward: float = 100.0
    open: np.ndarray = field(init=False, repr=False, compare=False)
    next_state: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        check_int("rows", self.rows, 2)
        check_int("cols", self.cols, 2)
        check_int("layout_seed", self.layout_seed, 0)
        if self.goal is None:
            object.__setattr__(self, "goal", self.rows * self.cols - 1)
        if not isinstance(self.goal, int | np.integer) or not 0 <= self.goal < self.n_places:
            raise ValueError(f"goal must be a place in 0..{self.n_places - 1}, got {self.goal!r}")
        object.__setattr__(self, "goal", int(self.goal))
        if not 0 <= self.extra_open <= 1:
            raise ValueError(f"extra_open must be in [0, 1], got {self.extra_open}")
        if not 0 <= self.gamma < 1:
            raise ValueError(f"gamma must be in [0, 1), got {self.gamma}")
        open_ = _draw_streets(self.rows, self.cols, self.layout_seed, self.extra_open)
        open_.setflags(write=False)
        object.__setattr__(self, "open", open_)
        places = np.arange(self.n_places)
        row, col = np.divmod(places, self.cols)
        table = np.empty((self.n_states, 3), dtype=np.int64)
        for h in range(4):
            s = places * 4 + h
            table[s, LEFT] = places * 4 + (h + 3) % 4
            table[s, RIGHT] = places * 4 + (h + 1) % 4
            ahead = (row + HEADING_STEPS[h, 0]) * self.cols + col + HEADING_STEPS[h, 1]
            table[s, FORWARD] = np.where(open_[:, h], ahead, places) * 4 + h
        table.setflags(write=False)
        object.__setattr__(self, "next_state", table)

    @property
    def n_places(self) -> int:
        """Number of places (rows x cols)."""
        return self.rows * self.cols

    @property
    def n_states(self) -> int:
        """Number of (place, heading) states."""
        return 4 * self.n_places

    @property
    def start_states(self) -> np.ndarray:
        """(n, 2) every (place, heading) off the goal place, in state-index order."""
        states = self.states_of(np.arange(self.n_states))
        return states[states[:, 0] != self.goal]

    def check_states(self, states, what: str = "states") -> np.ndarray:
        """``states`` as an (N, 2) int array of (place, heading), or a ValueError naming
        ``what``. A single (place, heading) pair becomes (1, 2)."""
        array = np.asarray(states)
        if array.ndim == 1:
            array = array[None]
        if (
            array.ndim != 2
            or array.shape[1] != 2
            or not (np.issubdtype(array.dtype, np.integer) or array.size == 0)
        ):
            raise ValueError(f"{what} must be (place, heading) integer pairs, got {states!r}")
        array = array.astype(np.int64)
        bad = (array[:, 0] < 0) | (array[:, 0] >= self.n_places)
        bad |= (array[:, 1] < 0) | (array[:, 1] > 3)
        if bad.any():
            raise ValueError(
                f"{what}: places must lie in 0..{self.n_places - 1} and headings in 0..3"
                f" ({', '.join(HEADING_NAMES)}), got {array[bad].tolist()}"
            )
        return array

    def index(self, states) -> np.ndarray:
        """(N,) state indices ``place * 4 + heading`` of (N, 2) states."""
        states = self.check_states(states)
        return states[:, 0] * 4 + states[:, 1]

    @staticmethod
    def states_of(indices) -> np.ndarray:
        """(N, 2) (place, heading) of (N,) state indices."""
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        return np.stack(np.divmod(indices, 4), axis=1)

    def place_xy(self, places, spacing: float) -> np.ndarray:
        """(N, 2) world (x east, y north) of places, with ``spacing`` metres between places."""
        row, col = np.divmod(np.asarray(places, dtype=np.int64).reshape(-1), self.cols)
        return np.stack([col * spacing, -row * spacing], axis=1).astype(np.float64)

    def step(self, states, actions) -> tuple[np.ndarray, np.ndarray]:
        """Apply the true dynamics to a batch.

        Args:
            states: (N, 2) (place, heading).
            actions: (N,) action ids in 0..2 (``PLACE_ACTION_NAMES``).

        Returns:
            new states (N, 2) and (N,) bool "the goal place was reached by this move".
        """
        states = self.check_states(states)
        actions = np.asarray(actions).reshape(-1)
        if (
            len(actions) != len(states)
            or not np.issubdtype(actions.dtype, np.integer)
            or (len(actions) and (actions.min() < 0 or actions.max() > 2))
        ):
            raise ValueError(f"expected {len(states)} integer actions in 0..2, got {actions!r}")
        new = self.states_of(self.next_state[states[:, 0] * 4 + states[:, 1], actions])
        reached = (new[:, 0] == self.goal) & (states[:, 0] != self.goal)
        return new, reached

    def sample_start(self, rng: np.random.Generator) -> np.ndarray:
        """(2,) a uniformly random state off the goal place."""
        starts = self.start_states
        return starts[rng.integers(len(starts))].copy()


def _draw_streets(rows: int, cols: int, seed: int, extra_open: float) -> np.ndarray:
    """(rows * cols, 4) open streets: a random spanning tree of the grid (every place reaches
    every other) plus ``extra_open`` of the remaining streets."""
    rng = np.random.default_rng(seed)
    edges = [(p, p + 1, 1) for p in range(rows * cols) if p % cols < cols - 1]
    edges += [(p, p + cols, 2) for p in range(rows * cols - cols)]
    parent = list(range(rows * cols))

    def root(p: int) -> int:
        while parent[p] != p:
            parent[p] = parent[parent[p]]
            p = parent[p]
        return p

    tree, rest = [], []
    for k in rng.permutation(len(edges)):  # Kruskal's algorithm on random edge weights
        a, b, _ = edges[k]
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[ra] = rb
            tree.append(edges[k])
        else:
            rest.append(edges[k])
    chosen = tree + rest[: round(extra_open * len(rest))]
    open_ = np.zeros((rows * cols, 4), dtype=bool)
    for a, b, heading in chosen:  # heading from a to b: E (1) or S (2)
        open_[a, heading] = open_[b, (heading + 2) % 4] = True
    return open_
