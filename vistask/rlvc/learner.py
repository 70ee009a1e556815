"""RLVC: reinforcement learning of visual classes (paper sections 2.1-2.3).

The stage loop, top to bottom: map interactions to classes, solve Q on the estimated class MDP,
compute TD errors, find the significant split of every aliased class, split, repeat until no
class splits or the stage cap. The policy acts on Q solved on the final classes (optionally
with blocked moves as dead ends, ``blocked_is_stuck``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from tqdm.auto import tqdm

from vistask.rlvc.database import InteractionDatabase
from vistask.rlvc.solver import estimate_mdp, state_values, td_errors, value_iteration
from vistask.rlvc.split import Split, find_splits
from vistask.rlvc.tree import ClassTree


@contextmanager
def single_thread() -> Iterator[None]:
    """Run torch on one thread inside the block.

    The stage loop is many small tensor operations: intra-op threads do not speed them up,
    and on a machine whose other core is busy they stall (measured: Q solving 0.4 s -> 50 s).
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


@dataclass
class StageRecord:
    """What one stage saw and did."""

    stage: int
    classes: int
    selected_features: int
    mean_abs_td: float
    splits: int
    solve_seconds: float
    split_seconds: float
    greedy_return: float | None = None


@dataclass
class Timing:
    solve: float = 0.0
    split: float = 0.0
    evaluate: float = 0.0


@dataclass
class RLVC:
    """RLVC learner over an interaction database with feature presence.

    Example:
        >>> rlvc = RLVC(n_features=db.n_features, n_actions=4, gamma=0.9)
        >>> rlvc.learn(db, max_stages=100)
        >>> rlvc.greedy(presence)   # (N,) actions for (N, F) bool presence rows

    Args:
        n_features: vocabulary size F.
        n_actions: number of discrete actions.
        gamma: discount factor.
        alpha: family-wise significance level of the split t-tests.
        min_count: minimum interactions on each side of a split.
        bonferroni: correct alpha for the number of candidate splits (see ``find_splits``).
        max_splits_per_stage: split at most this many classes per stage, best first (None: all
            aliased classes, as in the paper).
        blocked_is_stuck: solve the Q the policy acts on (``q``, ``greedy``) with blocked
            interactions, whose next percept is the very same image, bootstrapping nothing:
            a reactive, deterministic policy that takes a blocked action on an image takes it
            on the same image again, forever. The split search keeps the paper's TD errors.
    """

    n_features: int
    n_actions: int
    gamma: float
    alpha: float = 0.05
    min_count: int = 10
    bonferroni: bool = True
    max_splits_per_stage: int | None = None
    blocked_is_stuck: bool = False
    tree: ClassTree = field(init=False)
    q: torch.Tensor = field(init=False)
    history: list[StageRecord] = field(default_factory=list, init=False)
    timing: Timing = field(default_factory=Timing, init=False)

    def __post_init__(self) -> None:
        if self.n_actions < 1:
            raise ValueError(f"n_actions must be >= 1, got {self.n_actions}")
        self.tree = ClassTree(self.n_features)
        self.q = torch.zeros(1, self.n_actions, dtype=torch.float64)

    @property
    def n_classes(self) -> int:
        return self.tree.n_classes

    def solve(
        self, db: InteractionDatabase, classes: torch.Tensor, blocked_is_stuck: bool = False
    ) -> torch.Tensor:
        """Q (S, A) of the current classes on ``db``; ``classes`` (M,) class of each percept.
        With ``blocked_is_stuck``, blocked interactions (x_{t+1} the same image as x_t)
        bootstrap nothing, like terminal ones."""
        if int(db.actions.max()) >= self.n_actions or int(db.actions.min()) < 0:
            raise ValueError(f"database holds action ids outside 0..{self.n_actions - 1}")
        no_bootstrap = db.terminal | (db.obs == db.next_obs) if blocked_is_stuck else db.terminal
        mdp = estimate_mdp(
            classes[db.obs],
            db.actions,
            db.rewards,
            classes[db.next_obs],
            no_bootstrap,
            self.n_classes,
            self.n_actions,
        )
        return value_iteration(mdp, self.gamma)

    def _solve_policy(self, db: InteractionDatabase, classes: torch.Tensor) -> None:
        start = time.perf_counter()
        self.q = self.solve(db, classes, self.blocked_is_stuck)
        self.timing.solve += time.perf_counter() - start

    def learn(
        self,
        db: InteractionDatabase,
        max_stages: int = 200,
        evaluate: Callable[[RLVC], float] | None = None,
        eval_every: int = 5,
        progress: bool = True,
        on_stage: Callable[[StageRecord], None] | None = None,
    ) -> RLVC:
        """Run stages on ``db`` until no class splits or ``max_stages``; continues from the
        current tree, so it can be called again with a fresh database.

        Args:
            db: interaction database on this learner's vocabulary.
            max_stages: stage cap of this call.
            evaluate: optional ``evaluate(self) -> greedy-policy return``, run every
                ``eval_every`` stages and after the last one.
            progress: show a progress bar.
            on_stage: called with each stage's record (logging).
        """
        if db.n_features != self.n_features:
            raise ValueError(
                f"database has {db.n_features} features, the learner {self.n_features}"
            )
        if max_stages < 1:
            raise ValueError(f"max_stages must be >= 1, got {max_stages}")
        with single_thread():
            return self._learn(db, max_stages, evaluate, eval_every, progress, on_stage)

    def _learn(self, db, max_stages, evaluate, eval_every, progress, on_stage) -> RLVC:
        rows, features = db.interaction_features()
        classes = self.tree.classify(db.presence)
        bar = tqdm(range(max_stages), desc="RLVC stages", disable=not progress, leave=False)
        for i in bar:
            start = time.perf_counter()
            q = self.solve(db, classes)  # the paper's Q, whose TD errors reveal aliasing
            s, s_next = classes[db.obs], classes[db.next_obs]
            deltas = td_errors(q, s, db.actions, db.rewards, s_next, db.terminal, self.gamma)
            solved = time.perf_counter()
            splits = find_splits(
                rows,
                features,
                s,
                db.actions,
                deltas,
                self.n_classes,
                self.n_actions,
                self.n_features,
                self.alpha,
                self.min_count,
                self.bonferroni,
            )[: self.max_splits_per_stage]
            for split in splits:
                new_class = self.tree.split(split.state, split.feature)
                # Incremental reclassification: only percepts of the split class can move.
                moved = (classes == split.state) & db.presence[:, split.feature]
                classes[moved] = new_class
            done = time.perf_counter()
            self.timing.solve += solved - start
            self.timing.split += done - solved
            record = StageRecord(
                stage=len(self.history),
                classes=self.n_classes,
                selected_features=len(self.tree.selected_features),
                mean_abs_td=float(deltas.abs().mean()),
                splits=len(splits),
                solve_seconds=solved - start,
                split_seconds=done - solved,
            )
            # The cap counts this call's stages; evaluations follow the stage count of all calls.
            last = not splits or i + 1 == max_stages
            evaluating = evaluate is not None and (last or (record.stage + 1) % eval_every == 0)
            if last or evaluating:
                self._solve_policy(db, classes)
            if evaluating:
                t = time.perf_counter()
                record.greedy_return = float(evaluate(self))
                self.timing.evaluate += time.perf_counter() - t
            self.history.append(record)
            bar.set_postfix(classes=record.classes, td=f"{record.mean_abs_td:.2f}")
            if on_stage is not None:
                on_stage(record)
            if not splits:
                break
        return self

    def values(self) -> torch.Tensor:
        """(S,) V = max_a Q of every class."""
        return state_values(self.q)

    def greedy(self, presence: torch.Tensor) -> torch.Tensor:
        """(N, F) bool presence -> (N,) greedy actions."""
        return self.q.argmax(dim=1)[self.tree.classify(presence)]

    def state_dict(self) -> dict:
        return {
            "config": {
                "n_features": self.n_features,
                "n_actions": self.n_actions,
                "gamma": self.gamma,
                "alpha": self.alpha,
                "min_count": self.min_count,
                "bonferroni": self.bonferroni,
                "max_splits_per_stage": self.max_splits_per_stage,
                "blocked_is_stuck": self.blocked_is_stuck,
            },
            "tree": self.tree.state_dict(),
            "q": self.q,
            "history": [asdict(r) for r in self.history],
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> RLVC:
        rlvc = cls(**state["config"])
        rlvc.tree = ClassTree.from_state_dict(state["tree"])
        rlvc.q = state["q"]
        rlvc.history = [StageRecord(**r) for r in state["history"]]
        return rlvc

    def save(self, path: str | Path) -> None:
        torch.save(self.state_dict(), path)

    @classmethod
    def load(cls, path: str | Path) -> RLVC:
        return cls.from_state_dict(torch.load(path, weights_only=True))


__all__ = ["RLVC", "Split", "StageRecord"]
