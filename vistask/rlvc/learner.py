"""RLVC: reinforcement learning of visual classes (paper sections 2.1-2.3).

The stage loop, top to bottom: map interactions to classes, solve Q on the estimated class MDP,
compute TD errors, find the significant split of every aliased class (with ``use_compounds``,
compound features for the most aliased classes where they split better, section 2.5.1), split,
repeat until no class splits or the stage cap. With ``compaction``, the classes are a BDD and
interchangeable classes merge when learning stops (section 2.5.2), and with ``compact_every``
also every so many stages, learning going on from the merged classes; ``regrow`` then grows
the merged classes again as one decision tree, for unseen percepts, or ``fuse`` fuses them
with class structures learned on bootstrap samples of the interactions into one such tree. The
policy acts on Q solved on the current classes (after ``fuse``, on the mean Q of the classes
that each structure puts a percept in, ``vistask.rlvc.committee``); after ``remember``, a
percept's class is that of the nearest percepts learned on (``vistask.rlvc.seen``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from vistask.checks import checked
from vistask.features import Compound
from vistask.memory import base_pages
from vistask.parallel import map_runs
from vistask.rlvc.bdd import ClassBDD
from vistask.rlvc.committee import Committee, history_only
from vistask.rlvc.compaction import (
    DROP_VALUE_TOLERANCE,
    acceptable,
    induced_splits,
    interchangeable,
    merge_groups,
)
from vistask.rlvc.compound_search import find_compound_splits
from vistask.rlvc.database import InteractionDatabase
from vistask.rlvc.presence import PackedPresence
from vistask.rlvc.seen import SeenPercepts, classify
from vistask.rlvc.solver import estimate_mdp, state_values, td_errors, value_iteration
from vistask.rlvc.split import Split, find_splits
from vistask.rlvc.tree import ClassTree
from vistask.saving import load_state, save_state


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


@checked
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
    compounds: int = 0  # compounds made so far (not this stage's)
    merged: int = 0  # classes that compaction merged away in this stage


@dataclass
class Timing:
    solve: float = 0.0
    split: float = 0.0
    compounds: float = 0.0  # part of ``split``: the compound search
    compaction: float = 0.0  # merging, dropping features, solving Q on the merged classes


@checked
@dataclass
class RLVC:
    """RLVC learner over an interaction database with feature presence.

    Example:
        >>> rlvc = RLVC(n_features=db.n_features, n_actions=4, gamma=0.9)
        >>> rlvc.learn(db, max_stages=100)
        >>> rlvc.greedy(presence)   # (N,) actions for (N, F) bool presence rows

    Args:
        n_features: number of features F that presence vectors hold (the vocabulary's words,
            then the compounds learned so far).
        n_actions: number of discrete actions.
        gamma: discount factor.
        alpha: significance level of the split t-tests.
        min_count: minimum interactions on each side of a split.
        use_compounds: at every stage, search compound features for the most aliased
            classes, which split on a compound where it reduces the TD errors' variance more
            than their split on a feature (the database must keep feature occurrences); each
            compound found becomes feature ``n_features``, which then grows.
        compound_tolerances: tolerances of candidate compounds, in units of keypoint scale.
        compaction: hold the classes in a BDD (``ClassBDD``) and merge interchangeable
            classes when learning stops, then drop the features whose absence leaves every
            percept a good action (``compaction.acceptable``; with compounds, only those
            whose absence keeps every percept among interchangeable classes), and split
            classes on features they already test where those do half as well as the best
            split (False: a ``ClassTree`` that only splits, on the best feature).
        compact_every: with ``compaction``, merge every this many stages as well (None:
            only when learning stops).
        compaction_tolerance: classes merge when their values, and the values of their
            greedy actions in each other, differ by at most this share of the range of the
            class values.
        min_effect: a split must show TD errors whose means differ by more than this share
            of the range of the class values (Welch's test against that margin), so that
            more data do not split classes ever finer on value differences too small to
            matter (0: any significant difference, the paper's test; in [0, 1)).
    """

    n_features: int
    n_actions: int
    gamma: float
    alpha: float = 0.05
    min_count: int = 10
    use_compounds: bool = False
    compound_tolerances: tuple[float, ...] = (1.0,)
    compaction: bool = False
    compact_every: int | None = None
    compaction_tolerance: float = 0.02
    min_effect: float = 0.0
    compounds: list[Compound] = field(default_factory=list, init=False)
    structure: ClassTree | ClassBDD = field(init=False)
    # With ``remember``, new percepts take the class of the nearest percepts learned on.
    seen: SeenPercepts | None = field(default=None, init=False)
    # After ``fuse``, the fused structures, whose mean Q the policy acts on.
    committee: Committee | None = field(default=None, init=False)
    history: list[StageRecord] = field(default_factory=list, init=False)
    timing: Timing = field(default_factory=Timing, init=False)
    _q: torch.Tensor | None = field(default=None, init=False, repr=False)
    # Classes whose compound search found nothing since their interactions last changed (a
    # split, a new database). Their candidates would be the same; only the TD errors they are
    # tested on drift as Q is solved again, and re-searching them every stage doubled the
    # search's time on the maze: a deliberate trade of a little power for time.
    _no_compound: set[int] = field(default_factory=set, init=False, repr=False)
    # The database and classes the next solve of ``q`` reads (after splits, until it runs).
    _pending: tuple[InteractionDatabase, torch.Tensor] | None = field(
        default=None, init=False, repr=False
    )
    # Compaction runs when classes split since the last one, at stages that are multiples of
    # ``compact_every`` and at the end of each ``learn`` call.
    _splits_since_compaction: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.n_features < 1 or self.n_actions < 1:
            raise ValueError(
                f"n_features and n_actions must be >= 1, got {self.n_features}, {self.n_actions}"
            )
        if not 0 <= self.gamma < 1:
            raise ValueError(f"gamma must be in [0, 1), got {self.gamma}")
        if not 0 < self.alpha < 1:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")
        self.compound_tolerances = tuple(float(t) for t in self.compound_tolerances)
        if not self.compound_tolerances or min(self.compound_tolerances) <= 0:
            raise ValueError(f"compound_tolerances must be > 0, got {self.compound_tolerances}")
        if self.min_count < 2:
            raise ValueError(
                f"min_count must be >= 2 (a variance needs two samples), got {self.min_count}"
            )
        if self.compact_every is not None and self.compact_every < 1:
            raise ValueError(f"compact_every must be >= 1 or None, got {self.compact_every}")
        if not 0 <= self.compaction_tolerance < 1:
            raise ValueError(
                f"compaction_tolerance must be in [0, 1), got {self.compaction_tolerance}"
            )
        if not 0 <= self.min_effect < 1:
            raise ValueError(f"min_effect must be in [0, 1), got {self.min_effect}")
        defaults = {f.name: f.default for f in fields(self)}
        for option, switch in (
            ("compact_every", "compaction"),
            ("compaction_tolerance", "compaction"),
            ("compound_tolerances", "use_compounds"),
        ):
            if not getattr(self, switch) and getattr(self, option) != defaults[option]:
                raise ValueError(f"{option} acts only with {switch}=True, which is off")
        self.structure = (ClassBDD if self.compaction else ClassTree)(self.n_features)
        self._q = torch.zeros(1, self.n_actions, dtype=torch.float64)

    @property
    def n_classes(self) -> int:
        """Number of classes."""
        return self.structure.n_classes

    @property
    def q(self) -> torch.Tensor:
        """(S, A) Q of the current classes, solved on the last database when classes changed."""
        if self._pending is not None:
            start = time.perf_counter()
            with single_thread():
                self._q = self.solve(*self._pending)
            self._pending = None
            self.timing.solve += time.perf_counter() - start
        return self._q

    def solve(self, db: InteractionDatabase, classes: torch.Tensor) -> torch.Tensor:
        """Q (S, A) of the current classes on ``db``; ``classes`` (M,) class of each percept."""
        if int(db.actions.max()) >= self.n_actions or int(db.actions.min()) < 0:
            raise ValueError(f"database holds action ids outside 0..{self.n_actions - 1}")
        mdp = estimate_mdp(
            classes[db.obs],
            db.actions,
            db.rewards,
            classes[db.next_obs],
            db.terminal,
            self.n_classes,
            self.n_actions,
        )
        return value_iteration(mdp, self.gamma)

    def learn(
        self,
        db: InteractionDatabase,
        max_stages: int = 300,
        progress: bool = True,
        on_stage: Callable[[StageRecord], bool | None] | None = None,
    ) -> RLVC:
        """Run stages on ``db`` until no class splits or ``max_stages``; continues from the
        current classes, so it can be called again with a larger database.

        Args:
            db: interaction database on this learner's vocabulary.
            max_stages: stage cap of this call.
            progress: show a progress bar.
            on_stage: called with each stage's record; returning False stops learning.
        """
        if db.n_features != self.n_features:
            raise ValueError(
                f"database has {db.n_features} features, the learner {self.n_features}"
            )
        if max_stages < 1:
            raise ValueError(f"max_stages must be >= 1, got {max_stages}")
        self.seen = self.committee = None  # the classes change
        threads = torch.get_num_threads()  # the compound search's, outside the block below
        with single_thread(), base_pages():
            return self._learn(db, max_stages, progress, on_stage, threads)

    def _learn(self, db, max_stages, progress, on_stage, threads) -> RLVC:
        self._no_compound.clear()
        pairs, rows, features = db.split_rows()
        classes = self.structure.classify(db.presence)
        bar = tqdm(range(max_stages), desc="RLVC stages", disable=not progress, leave=False)
        for _ in bar:
            start, compaction_before = time.perf_counter(), self.timing.compaction
            q = self.solve(db, classes)
            merged = 0
            if self._compaction_due():
                classes, q, merged = self._compact(db, classes, q)
            self._q, self._pending = q, None
            s, s_next = classes[db.obs], classes[db.next_obs]
            deltas = td_errors(q, s, db.actions, db.rewards, s_next, db.terminal, self.gamma)
            solved = time.perf_counter()
            margin = self.min_effect * value_range(q)
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
                # Compaction aims at few features: a feature the classes already test
                # splits a class when it does half as well as the class's best split.
                prefer=self._tested_mask() if self.compaction else None,
                pairs=pairs,
                margin=margin,
            )
            if self.use_compounds:
                compound_start = time.perf_counter()
                made = self._compound_splits(db, s, deltas, splits, threads, margin)
                if made:
                    won = {split.state for split in made}
                    splits = [split for split in splits if split.state not in won] + made
                    pairs, rows, features = db.split_rows()
                self.timing.compounds += time.perf_counter() - compound_start
            for split in splits:
                self._no_compound.discard(split.state)
                new_class = self.structure.split(split.state, split.feature)
                self._splits_since_compaction += 1
                # Incremental reclassification: only percepts of the split class can move,
                # and reading their presence only is 2.1-3.4 times faster than a whole column
                # (the car's 44,000 percepts, 150 classes).
                members = torch.nonzero(classes == split.state).flatten()
                classes[members[db.presence[members, split.feature]]] = new_class
            if splits:  # the acting Q is solved again when first needed
                self._pending = (db, classes.clone())
            done = time.perf_counter()
            self.timing.solve += solved - start - (self.timing.compaction - compaction_before)
            self.timing.split += done - solved
            record = StageRecord(
                stage=len(self.history),
                classes=self.n_classes,
                selected_features=len(self.structure.selected_features),
                mean_abs_td=float(deltas.abs().mean()),
                splits=len(splits),
                solve_seconds=solved - start,
                split_seconds=done - solved,
                compounds=len(self.compounds),
                merged=merged,
            )
            self.history.append(record)
            bar.set_postfix(classes=record.classes, td=f"{record.mean_abs_td:.2f}")
            if on_stage is not None and on_stage(record) is False:
                break
            if not splits:
                break
        if self.compaction and self._splits_since_compaction:
            # Learning stopped (no split, the stage cap or the callback): the classes end
            # compacted, and the last stage's record says so.
            _, self._q, merged = self._compact(db, classes, self.q)
            self._pending = None
            last = self.history[-1]
            last.merged += merged
            last.classes, last.selected_features = (
                self.n_classes,
                len(self.structure.selected_features),
            )
        return self

    def _tested_mask(self) -> torch.Tensor:
        """(F,) bool: the features that the classes test."""
        mask = torch.zeros(self.n_features, dtype=torch.bool)
        mask[self.structure.selected_features] = True
        return mask

    def _compaction_due(self) -> bool:
        stage = len(self.history)
        return (
            self.compaction
            and self.compact_every is not None
            and self._splits_since_compaction > 0
            and stage > 0
            and stage % self.compact_every == 0
        )

    def _compact(
        self, db: InteractionDatabase, classes: torch.Tensor, q: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, int]:
        """Merge interchangeable classes; returns the percepts' merged classes, their Q and
        the number of classes merged away."""
        start, before = time.perf_counter(), self.n_classes
        tolerance = self._merge_tolerance(q)
        groups = merge_groups(q, tolerance)
        self.structure.merge(groups)
        classes = groups[classes]
        # A feature is not needed either where its absence leaves the percepts it moves a
        # good action; with compounds, only where it moves them between interchangeable
        # classes (see the ``compaction`` module).
        merged_q = self.solve(db, classes)
        if self.use_compounds:
            allowed = interchangeable(merged_q, tolerance)
        else:
            allowed = acceptable(merged_q, tolerance, DROP_VALUE_TOLERANCE * tolerance)
        _, classes = self.structure.simplify(db.presence, allowed, db.counts)
        self._splits_since_compaction = 0
        self._no_compound.clear()  # class ids changed
        q = self.solve(db, classes)
        self.timing.compaction += time.perf_counter() - start
        return classes, q, before - self.n_classes

    def _merge_tolerance(self, q: torch.Tensor) -> float:
        """``compaction_tolerance`` as a value: its share of the range of the values of ``q``."""
        return self.compaction_tolerance * value_range(q)

    def regrow(self, db: InteractionDatabase) -> RLVC:
        """Grow the classes again as one decision tree over the features they test, every
        percept of ``db`` staying in its class (``compaction.induced_splits``), and solve Q
        on them; needs ``compaction``. ``RLVCAgent(compaction=Compaction(during_learning=True))``
        does this when it ends learning.

        The tests that made the classes were each chosen for one class's TD errors; the
        regrown tree's are chosen to tell the classes apart over all percepts, so unseen
        percepts land in the right class more often.
        """
        if not isinstance(self.structure, ClassBDD):
            raise ValueError("regrow needs compaction=True (the classes of a BDD)")
        start = time.perf_counter()
        # Classes that no percept of db is in go.
        _, classes = torch.unique(self.structure.classify(db.presence), return_inverse=True)
        splits, groups = induced_splits(
            db.presence, classes, self.structure.selected_features, counts=db.counts
        )
        # Classes that outgrew the BDD's memory budget regrow outside it: the tree has more
        # leaves than they had classes.
        self.structure = ClassBDD.from_splits(
            self.n_features, splits, groups, in_bdd=self.structure.in_bdd
        )
        with single_thread():
            self._took_new_classes(self.solve(db, classes))
        self.timing.compaction += time.perf_counter() - start
        return self

    def merge(self, db: InteractionDatabase, tolerance: float) -> RLVC:
        """Merge interchangeable classes once (``compaction.merge_groups``; ``tolerance`` is a
        share of the range of the class values, in [0, 1)) and solve Q on the merged classes
        of ``db``'s percepts. The classes keep their tests: a percept goes down the same
        splits as before, to the merged class of the class it reached (a ``ClassBDD`` held
        as its history). ``RLVCAgent(compaction=True)`` does this when it ends learning.

        Example:
            >>> rlvc = RLVC(db.n_features, 4, gamma=0.9).learn(db).merge(db, 0.02)
        """
        if not 0 <= tolerance < 1:
            raise ValueError(f"tolerance must be in [0, 1), got {tolerance}")
        start = time.perf_counter()
        classes = self.structure.classify(db.presence)
        q = self.solve(db, classes)
        groups = merge_groups(q, tolerance * value_range(q))
        if isinstance(self.structure, ClassTree):
            self.structure = ClassBDD.from_splits(
                self.n_features, self.structure.splits(), groups.tolist(), in_bdd=False
            )
        else:
            self.structure.merge(groups)
        with single_thread():
            self._took_new_classes(self.solve(db, groups[classes]))
        self.timing.compaction += time.perf_counter() - start
        return self

    def _took_new_classes(self, q: torch.Tensor) -> None:
        """``structure`` was replaced: hold ``q`` (S, A) as its classes' Q, and forget what
        was kept of the classes before."""
        self._q, self._pending = q, None
        self._no_compound.clear()
        if self.history:
            self.history[-1].classes = self.n_classes
            self.history[-1].selected_features = len(self.structure.selected_features)
        self.seen = self.committee = None

    def fuse(
        self, db: InteractionDatabase, structures: int, seed: int = 0, workers: int | None = None
    ) -> RLVC:
        """Learn ``structures - 1`` more class structures, each on a bootstrap sample of
        ``db``'s interactions over the features learned so far (no compound search), fuse
        them with the current classes into one partition, and act on the mean of their Q;
        needs ``compaction``. ``RLVCAgent(structures=...)`` does this instead of ``regrow``
        when it ends learning.

        The percepts of ``db`` that every structure puts in the same classes form a cell,
        whose Q is the mean of the structures' Q. Cells merge as compaction merges classes
        (``merge_groups`` on that mean Q, within ``compaction_tolerance``), and the merged
        classes grow as one decision tree over the features that any structure tests
        (``induced_splits``): these are the classes (``classify``), each with the mean Q of
        its percepts. The structures stay as a ``Committee``, and ``greedy`` acts on it: each
        structure classes a percept by its own tests, and the action is the best of the mean
        of their Q. One structure's classes depend on which of its splits happen to pass
        their tests first; its errors lie in other places than another's, and the mean Q
        outvotes them.

        Args:
            db: the interactions learned on, over this learner's features.
            structures: class structures fused, the current one included.
            seed: seeds the bootstrap samples.
            workers: processes that learn the structures side by side (``vistask.parallel``;
                default: torch's threads, one per core, or one in a worker process of
                ``vistask.parallel``, whose runs already fill the cores). The structures are
                the same whichever process learns them.
        """
        if not isinstance(self.structure, ClassBDD):
            raise ValueError("fuse needs compaction=True (the classes of a BDD)")
        if structures < 1:
            raise ValueError(f"structures must be >= 1, got {structures}")
        start = time.perf_counter()
        workers = torch.get_num_threads() if workers is None else workers
        generator = torch.Generator().manual_seed(seed)
        # Fresh classes over the same features; the percepts' occurrences stay here. The jobs
        # hold numpy arrays: the pool pickles them in a thread, and torch pickles a tensor by
        # moving its memory while this process may be reading it (a segfault, seen).
        config = {**self.config(), "use_compounds": False, "compact_every": None}
        del config["compound_tolerances"]  # an option of use_compounds
        percepts = replace(db, positions=None, occurrences=None).state_dict()
        percepts = {k: v.numpy() if torch.is_tensor(v) else v for k, v in percepts.items()}
        jobs = [
            (config, percepts, torch.randint(len(db), (len(db),), generator=generator).numpy())
            for _ in range(structures - 1)
        ]
        outcomes = {id(o.item): o for o in map_runs(_bootstrap_structure, jobs, workers)}
        failed = [o.error for o in outcomes.values() if not o.ok]
        if failed:
            raise RuntimeError(f"a bootstrap structure failed to learn:\n{failed[0]}")
        structure = self.structure, self.q, self.structure.selected_features
        learned = [structure, *(outcomes[id(job)].result for job in jobs)]
        with single_thread():
            # (M, A) mean Q of each percept's classes, (M,) its cell.
            committee = Committee.of([s for s, _, _ in learned], [q for _, q, _ in learned])
            classes = committee.classify(db.presence)
            mean_q = committee.mean_q(classes)
            cells, cell = torch.unique(classes, dim=0, return_inverse=True)
            cell_q = torch.zeros(len(cells), self.n_actions, dtype=torch.float64)
            cell_q[cell] = mean_q
            merged = merge_groups(cell_q, self._merge_tolerance(cell_q))[cell]
            tested = sorted(set().union(*(features for _, _, features in learned)))
            splits, leaf_groups = induced_splits(db.presence, merged, tested, counts=db.counts)
            self.structure = ClassBDD.from_splits(
                self.n_features, splits, leaf_groups, in_bdd=self.structure.in_bdd
            )
            # Each class's Q: the mean Q of its percepts.
            n = torch.bincount(merged, minlength=self.n_classes).clamp_min(1)
            q = torch.zeros(self.n_classes, self.n_actions, dtype=torch.float64)
            self._took_new_classes(q.index_add_(0, merged, mean_q) / n[:, None])
        self.committee = committee
        self.timing.compaction += time.perf_counter() - start
        return self

    def remember(self, db: InteractionDatabase) -> RLVC:
        """Keep the tested features of ``db``'s percepts, so that ``classify`` gives a percept
        the class of the nearest of them (``SeenPercepts``) until the classes change.
        ``RLVCAgent(nearest_seen=True)`` does this when it ends learning.

        A percept's class then does not hang on every test of one path.
        """
        self.seen = SeenPercepts.of(self.structure, db.presence, db.counts)
        return self

    def _compound_splits(
        self,
        db: InteractionDatabase,
        states: torch.Tensor,
        deltas: torch.Tensor,
        primitive: list[Split],
        threads: int,
        margin: float,
    ) -> list[Split]:
        """Significant compound splits of the most aliased classes, where they do better than
        the classes' ``primitive`` splits; their compounds join the features (of this learner,
        its tree and ``db``)."""
        found, searched = find_compound_splits(
            db,
            states,
            deltas,
            self.n_classes,
            self.n_actions,
            self.alpha,
            self.min_count,
            self.compound_tolerances,
            skip=self._no_compound,
            to_beat=primitive,
            threads=threads,
            margin=margin,
        )
        self._no_compound.update(set(searched) - {split.state for split, _ in found})
        new: dict[Compound, int] = {}  # two classes may pick the same compound
        for split, compound in found:
            split.feature = new.setdefault(compound, self.n_features + len(new))
        if new:
            db.add_compounds(list(new))
            self.compounds += list(new)
            self.n_features += len(new)
            self.structure.widen(self.n_features)
        return [split for split, _ in found]

    @property
    def n_words(self) -> int:
        """Features that are not compounds (the vocabulary's words): compound c is feature
        ``n_words + c``."""
        return self.n_features - len(self.compounds)

    @property
    def compound_features(self) -> list[int]:
        """Feature ids of the compounds that the classes test."""
        return [f for f in self.structure.selected_features if f >= self.n_words]

    def values(self) -> torch.Tensor:
        """(S,) V = max_a Q of every class."""
        return state_values(self.q)

    def classify(self, presence: torch.Tensor | PackedPresence) -> torch.Tensor:
        """(N, F) bool presence -> (N,) classes (by the structure, or after ``remember`` by
        the nearest percepts learned on)."""
        return classify(self.structure, self.seen, presence)

    def greedy(self, presence: torch.Tensor | PackedPresence) -> torch.Tensor:
        """(N, F) bool presence -> (N,) greedy actions: of the classes' Q, or after ``fuse``
        of the fused structures' mean Q (``Committee``)."""
        if self.committee is not None:
            return self.committee.greedy(presence)
        return self.q.argmax(dim=1)[self.classify(presence)]

    def config(self) -> dict:
        """The settings this learner was made with: ``RLVC(**rlvc.config())`` is a fresh one."""
        return {
            "n_features": self.n_features,
            "n_actions": self.n_actions,
            "gamma": self.gamma,
            "alpha": self.alpha,
            "min_count": self.min_count,
            "use_compounds": self.use_compounds,
            "compound_tolerances": list(self.compound_tolerances),
            "compaction": self.compaction,
            "compact_every": self.compact_every,
            "compaction_tolerance": self.compaction_tolerance,
            "min_effect": self.min_effect,
        }

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "config": self.config(),
            "compounds": [c.as_list() for c in self.compounds],
            "structure": self.structure.state_dict(),
            "splits_since_compaction": self._splits_since_compaction,
            "q": self.q,
            "history": [asdict(r) for r in self.history],
            "seen": None if self.seen is None else self.seen.state_dict(),
            "committee": None if self.committee is None else self.committee.state_dict(),
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> RLVC:
        """The object that ``state_dict`` described."""
        rlvc = cls(**state["config"])
        # Merged classes are held as a ClassBDD, whichever structure learned them.
        structure = ClassBDD if "history" in state["structure"] else ClassTree
        rlvc.structure = structure.from_state_dict(state["structure"])
        rlvc._splits_since_compaction = state["splits_since_compaction"]
        rlvc.compounds = [Compound.from_list(c) for c in state.get("compounds", [])]
        rlvc._q = state["q"]
        rlvc.history = [StageRecord(**r) for r in state["history"]]
        if state.get("seen") is not None:
            rlvc.seen = SeenPercepts.from_state_dict(state["seen"])
        if state.get("committee") is not None:
            rlvc.committee = Committee.from_state_dict(state["committee"])
        return rlvc

    def save(self, path: str | Path) -> None:
        """Write it to ``path``; ``load`` reads it back."""
        save_state(path, "RLVC", self.state_dict())

    @classmethod
    def load(cls, path: str | Path) -> RLVC:
        """Read what ``save`` wrote to ``path``."""
        return cls.from_state_dict(load_state(path, "RLVC"))


def value_range(q: torch.Tensor) -> float:
    """The range of the class values ``state_values(q)`` of (S, A) ``q``."""
    values = state_values(q)
    return float(values.max() - values.min())


def _bootstrap_structure(
    job: tuple[dict, dict, np.ndarray],
) -> tuple[ClassBDD, torch.Tensor, list[int]]:
    """One structure of ``RLVC.fuse``, in whichever process: a fresh ``RLVC(**config)`` learned
    on the interactions ``sample`` (N,) of the database whose ``state_dict`` (numpy arrays for
    its tensors) is ``arrays``; returns its classes as their history (a BDD does not pickle),
    their Q (S, A) and the features they test."""
    config, arrays, sample = job
    state = {k: torch.from_numpy(v) if isinstance(v, np.ndarray) else v for k, v in arrays.items()}
    db = InteractionDatabase.from_state_dict(state)
    rlvc = RLVC(**config).learn(db.take(torch.from_numpy(sample)), progress=False)
    return history_only(rlvc.structure), rlvc.q, rlvc.structure.selected_features


__all__ = ["RLVC", "Split", "StageRecord"]
