"""RLJC: reinforcement learning of joint classes of percepts and continuous actions (paper 2.5.3).

The stage loop is RLVC's on the joint space: map every interaction (x_t, a_t) to its joint class,
solve Q over joint classes on the estimated model (the bootstrap of a next percept being the best
joint class compatible with it), compute TD errors, split every aliased joint class on its best
significant test, visual feature or action threshold, and repeat until no class splits or the
stage cap. The policy picks, among the classes compatible with a percept, the one of highest Q
and acts at the centre of its action box.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from vistask.checks import checked
from vistask.rlvc.database import InteractionDatabase
from vistask.rlvc.joint_tree import JointTree, cells_of
from vistask.rlvc.learner import StageRecord, Timing, single_thread
from vistask.rlvc.presence import PackedPresence
from vistask.rlvc.split import (
    Split,
    ThresholdSplit,
    find_splits,
    find_threshold_splits,
    first_in_group,
)
from vistask.saving import load_state, save_state


@checked
def joint_values(
    classes: torch.Tensor,
    rewards: torch.Tensor,
    next_cells: torch.Tensor,
    terminal: torch.Tensor,
    member_cell: torch.Tensor,
    member_class: torch.Tensor,
    n_classes: int,
    gamma: float,
    tol: float = 1e-8,
    max_iters: int = 10_000,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Q over joint classes by value iteration on the count-based model.

    Q(j) = R(j) + gamma * sum_c T(j, c) V(c), with V(c) = max of Q over the classes compatible
    with perceptual cell c (0 when none was visited) and T(j, c) the share of j's interactions
    whose next percept lies in cell c and did not end the episode.

    Args:
        classes: (N,) joint class of each interaction.
        rewards: (N,) rewards.
        terminal: (N,) bool, the interaction ended the episode.
        next_cells: (N,) cell of each next percept.
        member_cell, member_class: (K,) the cells' compatible classes as pairs.
        n_classes: number of joint classes J.
        gamma: discount factor.
        tol: stop when the cells' values V change by less than this.
        max_iters: iteration cap.

    Returns:
        Q (J,) float64, -inf for classes that no interaction visited; V (C,) of the cells.
    """
    if not 0 <= gamma < 1:
        raise ValueError(f"gamma must be in [0, 1), got {gamma}")
    n_cells = int(member_cell.max()) + 1
    counts = torch.bincount(classes, minlength=n_classes).double()
    safe = counts.clamp_min(1)
    r = torch.zeros(n_classes, dtype=torch.float64).index_add_(0, classes, rewards.double()) / safe
    live = ~terminal
    pairs, n_pairs = torch.unique(classes[live] * n_cells + next_cells[live], return_counts=True)
    origin, successor = pairs // n_cells, pairs % n_cells
    p = n_pairs.double() / safe[origin]
    visited = counts > 0
    v = torch.zeros(n_cells, dtype=torch.float64)
    for _ in range(max_iters):
        q = r + gamma * torch.zeros(n_classes, dtype=torch.float64).index_add_(
            0, origin, p * v[successor]
        )
        q = q.masked_fill(~visited, -torch.inf)
        best = torch.full((n_cells,), -torch.inf, dtype=torch.float64).scatter_reduce_(
            0, member_cell, q[member_class], "amax"
        )
        new_v = torch.where(torch.isfinite(best), best, 0.0)
        converged = (new_v - v).abs().max() < tol
        v = new_v
        if converged:
            break
    return q, v


@checked
@dataclass
class RLJC:
    """RLJC learner over an interaction database with continuous actions.

    Example:
        >>> rljc = RLJC(n_features=db.n_features, low=[-np.pi], high=[np.pi], gamma=0.9)
        >>> rljc.learn(db, max_stages=300)
        >>> rljc.greedy(presence)   # (N, m) actions for (N, F) bool presence rows

    Args:
        n_features: number of visual features F that presence vectors hold.
        low, high: (m,) bounds of the action space.
        gamma: discount factor.
        alpha: significance level of the split t-tests.
        min_count: minimum interactions on each side of a split.
    """

    n_features: int
    low: list[float]
    high: list[float]
    gamma: float
    alpha: float = 0.05
    min_count: int = 10
    structure: JointTree = field(init=False)
    history: list[StageRecord] = field(default_factory=list, init=False)
    timing: Timing = field(default_factory=Timing, init=False)
    _q: torch.Tensor = field(init=False, repr=False)
    _pending: InteractionDatabase | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if not 0 <= self.gamma < 1:
            raise ValueError(f"gamma must be in [0, 1), got {self.gamma}")
        if not 0 < self.alpha < 1:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")
        if self.min_count < 2:
            raise ValueError(
                f"min_count must be >= 2 (a variance needs two samples), got {self.min_count}"
            )
        self.low = [float(x) for x in np.atleast_1d(self.low)]
        self.high = [float(x) for x in np.atleast_1d(self.high)]
        self.structure = JointTree(self.n_features, self.low, self.high)
        self._q = torch.zeros(1, dtype=torch.float64)

    @property
    def n_classes(self) -> int:
        """Number of classes."""
        return self.structure.n_classes

    @property
    def compounds(self) -> list:
        """RLJC tests the vocabulary's words only: no compound features."""
        return []

    @property
    def q(self) -> torch.Tensor:
        """(J,) Q of the current joint classes, solved on the last database when they changed."""
        if self._pending is not None:
            start = time.perf_counter()
            with single_thread():
                self._q = self.solve(self._pending)[0]
            self._pending = None
            self.timing.solve += time.perf_counter() - start
        return self._q

    def solve(self, db: InteractionDatabase) -> tuple[torch.Tensor, torch.Tensor]:
        """Q (J,) of the current joint classes on ``db`` and the TD error (N,) of every
        interaction."""
        self._check_database(db)
        classes = self.structure.classify(db.presence, db.actions, db.obs)
        return self._solve(db, classes, *self.structure.compatible(db.presence))

    def _solve(
        self,
        db: InteractionDatabase,
        classes: torch.Tensor,
        pair_rows: torch.Tensor,
        pair_classes: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``solve`` given the interactions' joint classes (N,) and the percepts' compatible
        classes as pairs (K,)."""
        cell, member_cell, member_class = cells_of(
            pair_rows, pair_classes, len(db.presence), self.n_classes
        )
        q, v = joint_values(
            classes,
            db.rewards,
            cell[db.next_obs],
            db.terminal,
            member_cell,
            member_class,
            self.n_classes,
            self.gamma,
        )
        bootstrap = torch.where(db.terminal, 0.0, v[cell[db.next_obs]])
        return q, db.rewards + self.gamma * bootstrap - q[classes]

    def _check_database(self, db: InteractionDatabase) -> None:
        if db.n_features != self.n_features:
            raise ValueError(
                f"database has {db.n_features} features, the learner {self.n_features}"
            )
        if db.actions.ndim != 2 or db.actions.shape[1] != len(self.low):
            raise ValueError(
                f"RLJC needs (N, {len(self.low)}) continuous actions, the database holds "
                f"{tuple(db.actions.shape)} {db.actions.dtype}"
            )

    def learn(
        self,
        db: InteractionDatabase,
        max_stages: int = 300,
        progress: bool = True,
        on_stage: Callable[[StageRecord], bool | None] | None = None,
    ) -> RLJC:
        """Run stages on ``db`` until no joint class splits or ``max_stages``; continues from
        the current classes, so it can be called again with a larger database.

        Args:
            db: interaction database on this learner's vocabulary, with continuous actions.
            max_stages: stage cap of this call.
            progress: show a progress bar.
            on_stage: called with each stage's record; returning False stops learning.
        """
        self._check_database(db)
        if max_stages < 1:
            raise ValueError(f"max_stages must be >= 1, got {max_stages}")
        with single_thread():
            rows, features = db.interaction_features()
            # The interactions' joint classes and the percepts' compatible classes, moved
            # along with every split rather than found again from the root.
            classes = self.structure.classify(db.presence, db.actions, db.obs)
            pair_rows, pair_classes = self.structure.compatible(db.presence)
            bar = tqdm(range(max_stages), desc="RLJC stages", disable=not progress, leave=False)
            for _ in bar:
                start = time.perf_counter()
                q, deltas = self._solve(db, classes, pair_rows, pair_classes)
                self._q, self._pending = q, None
                solved = time.perf_counter()
                splits = self._best_splits(rows, features, classes, db.actions, deltas)
                classes, pair_rows, pair_classes = self._apply(
                    splits, db, classes, pair_rows, pair_classes
                )
                n_splits = len(splits)
                if n_splits:  # the acting Q is solved again when first needed
                    self._pending = db
                done = time.perf_counter()
                self.timing.solve += solved - start
                self.timing.split += done - solved
                record = StageRecord(
                    stage=len(self.history),
                    classes=self.n_classes,
                    selected_features=len(self.structure.selected_features),
                    mean_abs_td=float(deltas.abs().mean()),
                    splits=n_splits,
                    solve_seconds=solved - start,
                    split_seconds=done - solved,
                )
                self.history.append(record)
                bar.set_postfix(classes=record.classes, td=f"{record.mean_abs_td:.2f}")
                if on_stage is not None and on_stage(record) is False:
                    break
                if not n_splits:
                    break
        return self

    def _best_splits(
        self, rows, features, classes, actions, deltas
    ) -> dict[int, Split | ThresholdSplit]:
        """The best significant test of every joint class that has one: a visual feature or
        an action threshold, whichever reduces the TD errors' variance more."""
        n = self.n_classes
        no_action = torch.zeros_like(classes)
        best: dict[int, Split | ThresholdSplit] = {}
        for split in find_splits(
            rows, features, classes, no_action, deltas, n, 1, self.n_features,
            self.alpha, self.min_count,
        ):  # fmt: skip
            best[split.state] = split
        for split in find_threshold_splits(classes, actions, deltas, n, self.alpha, self.min_count):
            if split.state not in best or split.reduction > best[split.state].reduction:
                best[split.state] = split
        return best

    def _apply(
        self,
        splits: dict[int, Split | ThresholdSplit],
        db: InteractionDatabase,
        classes: torch.Tensor,
        pair_rows: torch.Tensor,
        pair_classes: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Split the classes, then move the interactions that pass their class's new test to
        the new class, and give the percepts compatible with a class split on an action the
        new class as well. Returns the new ``classes``, ``pair_rows``, ``pair_classes``."""
        n = self.n_classes
        kind = torch.zeros(n, dtype=torch.long)  # 1: split on a feature, 2: on an action
        feature, dim = torch.zeros(n, dtype=torch.long), torch.zeros(n, dtype=torch.long)
        threshold, new = torch.zeros(n, dtype=torch.float64), torch.arange(n)
        for state, split in splits.items():
            if isinstance(split, ThresholdSplit):
                new[state] = self.structure.split_action(state, split.dim, split.threshold)
                kind[state], dim[state], threshold[state] = 2, split.dim, split.threshold
            else:
                new[state] = self.structure.split_feature(state, split.feature)
                kind[state], feature[state] = 1, split.feature
        k = kind[classes]
        seen = db.presence[db.obs, feature[classes]]
        above = db.actions[torch.arange(len(classes)), dim[classes]] >= threshold[classes]
        classes = torch.where(((k == 1) & seen) | ((k == 2) & above), new[classes], classes)
        k = kind[pair_classes]
        both = k == 2  # the percept stays compatible with the lower and the upper class
        extra_rows, extra_classes = pair_rows[both], new[pair_classes[both]]
        seen = (k == 1) & db.presence[pair_rows, feature[pair_classes]]
        pair_classes = torch.where(seen, new[pair_classes], pair_classes)
        return (
            classes,
            torch.cat([pair_rows, extra_rows]),
            torch.cat([pair_classes, extra_classes]),
        )

    # -- acting -----------------------------------------------------------------------------
    def best_classes(
        self,
        presence: torch.Tensor | PackedPresence,
        pairs: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """(N, F) presence -> (N,) the compatible joint class of highest Q of each percept
        (``pairs``: the percepts' ``structure.compatible`` if already known)."""
        rows, classes = pairs if pairs is not None else self.structure.compatible(presence)
        q = self.q[classes]
        top = torch.full((len(presence),), -torch.inf, dtype=torch.float64)
        top.scatter_reduce_(0, rows, q, "amax")
        # Among ties (and where no compatible class was visited), the first class in order.
        is_top = (q == top[rows]) | torch.isinf(top[rows])
        tops = torch.nonzero(is_top).flatten()
        return classes[tops[first_in_group(rows[tops], len(presence))]]

    def greedy(self, presence: torch.Tensor | PackedPresence) -> np.ndarray:
        """(N, F) bool presence -> (N, m) greedy actions: the centres of the best boxes."""
        best = self.best_classes(presence).numpy()
        return (self.structure.box_low[best] + self.structure.box_high[best]) / 2

    def explore(
        self, presence: torch.Tensor | PackedPresence, epsilon: float, rng: np.random.Generator
    ) -> np.ndarray:
        """(N, m) actions drawn uniformly inside a box chosen epsilon-greedily among the
        classes compatible with each percept (the best one, or with probability ``epsilon``
        any one)."""
        pairs = self.structure.compatible(presence)
        best = self.best_classes(presence, pairs).numpy()
        rows, classes = (t.numpy() for t in pairs)
        counts = np.bincount(rows, minlength=len(best))
        starts = np.cumsum(counts) - counts
        anyone = classes[starts + (rng.random(len(best)) * counts).astype(int)]
        chosen = np.where(rng.random(len(best)) < epsilon, anyone, best)
        low, high = self.structure.box_low[chosen], self.structure.box_high[chosen]
        return rng.uniform(low, high)

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "config": {
                "n_features": self.n_features,
                "low": self.low,
                "high": self.high,
                "gamma": self.gamma,
                "alpha": self.alpha,
                "min_count": self.min_count,
            },
            "structure": self.structure.state_dict(),
            "q": self.q,
            "history": [asdict(r) for r in self.history],
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> RLJC:
        """The object that ``state_dict`` described."""
        rljc = cls(**state["config"])
        rljc.structure = JointTree.from_state_dict(state["structure"])
        rljc._q = state["q"]
        rljc.history = [StageRecord(**r) for r in state["history"]]
        return rljc

    def save(self, path: str | Path) -> None:
        """Write it to ``path``; ``load`` reads it back."""
        save_state(path, "RLJC", self.state_dict())

    @classmethod
    def load(cls, path: str | Path) -> RLJC:
        """Read what ``save`` wrote to ``path``."""
        return cls.from_state_dict(load_state(path, "RLJC"))
