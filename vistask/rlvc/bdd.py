"""The class structure as a reduced ordered BDD (paper section 2.5.2).

Each visual class is a Boolean function of feature tests held in one shared BDD manager of
the ``dd`` package (CUDD through ``dd.cudd``; the pure-Python ``dd.autoref`` where the CUDD
extension is missing). A split conjoins a feature test to a class, as in the tree; a merge
makes a class the disjunction of several, which a tree cannot express. Variables are the
features, named ``f<i>`` and declared when first tested, in that order. A feature no class
depends on drops out of every class's support, and ``simplify`` drops the features that the
percepts seen so far do not need (the classes are free to differ on feature combinations never
seen: the cofactor "feature absent" replaces every class). Dynamic reordering is off: the
support of a class does not depend on the order, and sifting took minutes a stage on the maze.
In a fixed order, though, a disjunction of many classes can grow exponentially. The manager
works within a memory budget (``MAX_MEMORY``); where a split, a merge or a cofactor would
outgrow it, the classes leave the BDD with a warning and go on as their history alone (below),
which classifies every percept as the BDD would: merges and dropped features still apply, and
the selected features are then those that the history's splits test (sifting during a merge
kept the memory at 1.3 GB on place navigation but had not finished one merge after 3 minutes).

Classification replays the history of the partition on a batch of presence vectors: every
class starts as class 0, each group of splits (one stage's: distinct classes) moves the rows
of a split class whose feature is present to the new class, each merge relabels; a dropped
feature's splits are deleted from the history (with the feature absent they never move a row,
which is what the cofactor means). A batch costs one vectorized step per stage and merge.
Compiling the classes to one multi-terminal diagram instead grew exponentially with the merges
on the maze, and a decision tree with a leaf per region multiplied its leaves whenever a
merged class split again.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from vistask.checks import checked, warn
from vistask.rlvc.presence import PackedPresence, distinct_rows

try:
    from dd import cudd as _dd
except ImportError:  # pragma: no cover - wheels without the CUDD extension
    from dd import autoref as _dd


# CUDD's memory budget: classes that outgrow it leave the BDD (``ClassBDD.in_bdd``) instead of
# filling the machine's memory, which a merge on place navigation did (24 GB). The default maze
# peaks at 77 MiB; near the budget every split walks huge functions (the car with compaction:
# splits took 296 s of a 448 s run at 4 GiB, 87 s of 281 s at 1 GiB, with the same classes),
# and a merge that outgrows it fails only once it is full (place navigation, 200,000
# interactions: 23 s at 1 GiB, 3.4 s at 256 MiB, with the same classes; the mountain car's
# second merge: 9.3 s at 256 MiB, then 3.2 s of dropping features and 5 s of splits before a
# split outgrew it, against 5.3 s at 128 MiB, with the same classes).
MAX_MEMORY = 2**27
# Trials of dropping features that ``simplify`` replays together (one replay costs about as
# much for a few percepts as for thousands).
BATCH = 32


def _name(feature: int) -> str:
    return f"f{feature}"


@checked
class ClassBDD:
    """Visual classes as disjoint Boolean functions of feature presence, in a shared BDD.

    Example:
        >>> classes = ClassBDD(n_features=100)   # one class: everything aliased
        >>> classes.split(0, feature=7)          # class 0 -> {7 absent: 0, 7 present: 1}
        >>> classes.split(0, feature=3)          # {7, 3 absent: 0, 3 present: 2}
        >>> classes.merge(torch.tensor([0, 1, 1]))   # classes 1 and 2 become class 1
        >>> classes.classify(presence)           # presence (N, 100) bool -> (N,) long

    Args:
        n_features: number of visual features F a presence vector holds.
        max_memory: bytes the CUDD manager may take (the pure-Python fallback has no budget);
            classes that would outgrow it go on as their history (``in_bdd`` turns False).
    """

    def __init__(self, n_features: int, max_memory: int = MAX_MEMORY) -> None:
        if n_features < 1:
            raise ValueError(f"n_features must be >= 1, got {n_features}")
        self.n_features = int(n_features)
        self.max_memory = int(max_memory)
        self.bdd = _dd.BDD()
        self.bdd.configure(reordering=False)
        if _dd.__name__ == "dd.cudd":
            self.bdd.configure(max_memory=self.max_memory)
        # One function per class; None once the classes outgrew the memory budget.
        self.functions: list | None = [self.bdd.true]
        self._n_classes = 1
        # The history: {"splits": {class: (feature, new class)}} or {"merge": groups list}.
        self.history: list[dict] = []
        self._selected: set[int] = set()

    @property
    def n_classes(self) -> int:
        """Number of classes."""
        return self._n_classes

    @property
    def in_bdd(self) -> bool:
        """False once the classes outgrew the BDD's memory budget and went on as their
        history alone (same classification; selected features counted from the splits)."""
        return self.functions is not None

    @property
    def selected_features(self) -> list[int]:
        """Sorted distinct features that some class depends on."""
        return sorted(self._selected)

    def _tested_features(self) -> set[int]:
        """Features that some split of the history tests."""
        return {f for step in self.history for f, _ in step.get("splits", {}).values()}

    def _update_selected(self) -> None:
        if self.functions is None:
            self._selected = self._tested_features()
        else:
            self._selected = {int(name[1:]) for u in self.functions for name in self.bdd.support(u)}

    def _bdd_step(self, step: Callable[[], list]) -> None:
        """The classes' functions become ``step()``'s; where CUDD runs out of its memory
        budget, the classes leave the BDD (see the module)."""
        if self.functions is None:
            return
        try:
            self.functions = step()
        except (ValueError, RuntimeError) as error:
            # dd.cudd's words for "CUDD returned no node": a NULL pointer (operators), a failed
            # cofactor (``let``, which drops features).
            if "NULL" not in str(error) and "cofactor failed" not in str(error):
                raise
            warn(
                f"the visual classes outgrew the BDD's memory budget "
                f"({self.max_memory / 2**20:.0f} MiB) at {self.n_classes} classes: they go on "
                f"as their history of splits and merges, which classifies as the BDD did ({error})"
            )
            self._leave_bdd()

    def _leave_bdd(self) -> None:
        """The classes go on as their history alone (``in_bdd`` turns False)."""
        self.functions = None
        self.bdd = None  # frees CUDD's nodes

    def widen(self, n_features: int) -> None:
        """Presence vectors hold ``n_features`` features from now on (compounds were added)."""
        if n_features < self.n_features:
            raise ValueError(f"cannot narrow the classes from {self.n_features} to {n_features}")
        self.n_features = int(n_features)

    def _var(self, feature: int):
        name = _name(feature)
        if name not in self.bdd.vars:
            self.bdd.declare(name)
        return self.bdd.var(name)

    def split(self, class_id: int, feature: int) -> int:
        """Split a class on a feature; returns the id of the new ("present") class."""
        if not 0 <= class_id < self.n_classes:
            raise ValueError(f"no class {class_id} (there are {self.n_classes})")
        if not 0 <= feature < self.n_features:
            raise ValueError(f"feature {feature} outside 0..{self.n_features - 1}")

        def split_functions() -> list:
            test, function = self._var(feature), self.functions[class_id]
            absent, present = function & ~test, function & test
            self.functions[class_id] = absent
            self.functions.append(present)
            return self.functions

        self._bdd_step(split_functions)
        new_class = self._n_classes
        self._n_classes += 1
        group = self.history[-1].get("splits") if self.history else None
        # Splits of distinct classes, none made by the same group, are applied at once.
        if group is None or class_id in group or class_id in {n for _, n in group.values()}:
            group = {}
            self.history.append({"splits": group})
        group[class_id] = (feature, new_class)
        self._selected.add(feature)
        return new_class

    def merge(self, groups: torch.Tensor) -> None:
        """Class c becomes part of class ``groups[c]``; groups (S,) long numbered 0..G-1."""
        groups = torch.as_tensor(groups).long()
        if groups.shape != (self.n_classes,):
            raise ValueError(f"groups must be ({self.n_classes},), got {tuple(groups.shape)}")
        n_groups = int(groups.max()) + 1
        if set(groups.tolist()) != set(range(n_groups)):
            raise ValueError("groups must number the merged classes 0..G-1 without gaps")

        def merged_functions() -> list:
            merged = [self.bdd.false] * n_groups
            for function, g in zip(self.functions, groups.tolist(), strict=True):
                merged[g] = merged[g] | function
            return merged

        self._bdd_step(merged_functions)
        self._n_classes = n_groups
        self.history.append({"merge": groups.tolist()})
        self._update_selected()

    def simplify(
        self,
        presence: torch.Tensor | PackedPresence,
        allowed: torch.Tensor | None = None,
        counts: torch.Tensor | None = None,
    ) -> tuple[list[int], torch.Tensor]:
        """Drop every feature whose absence moves none of these percepts out of its class, or
        only into classes ``allowed`` for it.

        Features are tried from the rarest up; a dropped feature's test is replaced by its
        "absent" branch in every class, and classes left empty are removed (ids renumbered in
        order). Returns the dropped features and the percepts' (N,) long classes afterwards
        (what ``classify(presence)`` now gives, known without classifying again).

        Args:
            presence: (N, F) bool presence of the percepts that must stay where they are.
            allowed: (S, S) bool, True where a percept of class i may move to class j (None:
                nowhere else).
            counts: (N,) long, the times each percept was met, which order the features from
                the rarest (None: once each).
        """
        if not self._selected:
            return [], self.classify(presence)
        # The replay reads only the features that the history tests, and each distinct row of
        # them once (percepts equal on them move alike): column-major, for the trials that
        # read one column each.
        tested = sorted(self._tested_features())
        column = np.full(self.n_features, -1)
        column[tested] = np.arange(len(tested))
        packed, _, inverse, weight = distinct_rows(presence, tested, counts)
        bits = np.asfortranarray(np.unpackbits(packed, axis=1, count=len(tested)).view(bool))
        rows, columns = bits.nonzero()
        met = np.bincount(columns, weights=weight[rows], minlength=len(tested))
        order = sorted(self._selected, key=lambda f: (met[column[f]], f))
        allowed = np.eye(self.n_classes, dtype=bool) if allowed is None else allowed.numpy()
        dropped, classes = _droppable(bits, self._compiled(column), column[order], allowed)
        dropped = [tested[j] for j in dropped]
        classes = torch.as_tensor(classes[inverse], dtype=torch.long, device=presence.device)
        if not dropped:
            return dropped, classes
        absent = {_name(f): False for f in dropped}

        def cofactors() -> list:
            return [self.bdd.let(absent, u) for u in self.functions]

        self._bdd_step(cofactors)
        for step in self.history:
            if "splits" in step:
                for c in [c for c, (f, _) in step["splits"].items() if f in dropped]:
                    del step["splits"][c]
        kept = self._non_empty()
        if not kept.all():
            if self.functions is not None:
                self.functions = [u for u, k in zip(self.functions, kept, strict=True) if k]
            self._n_classes = int(kept.sum())
            renumbered = (kept.cumsum(0) - 1).clamp_min(0)
            self.history.append({"merge": renumbered.tolist()})
            classes = renumbered.to(classes.device)[classes]
        self._update_selected()
        return dropped, classes

    @classmethod
    def from_splits(
        cls,
        n_features: int,
        splits: list[tuple[int, int]],
        groups: list[int],
        max_memory: int = MAX_MEMORY,
        in_bdd: bool = True,
    ) -> ClassBDD:
        """Classes made by ``splits`` (class, feature) from one class, in order, then merged
        into ``groups`` (one per class the splits make, numbered 0..G-1), as
        ``compaction.induced_splits`` gives them; as their history alone unless ``in_bdd``
        (the merge of a large tree's leaves may fill the memory budget before it fails: 8 s
        on place navigation at 128 views a state)."""
        classes = cls(n_features, max_memory)
        if not in_bdd:
            classes._leave_bdd()
        for class_id, feature in splits:
            classes.split(class_id, feature)
        classes.merge(torch.as_tensor(groups))
        return classes

    def _non_empty(self) -> torch.Tensor:
        """(S,) bool: classes that some presence vector reaches. In the BDD: functions other
        than false; from the history: classes that class 0 reaches through its splits and
        merges (a split that tests a feature again on a path counts as reaching)."""
        if self.functions is not None:
            return torch.tensor([u != self.bdd.false for u in self.functions])
        alive = {0}
        for step in self.history:
            if "merge" in step:
                alive = {step["merge"][c] for c in alive}
            else:
                alive |= {n for c, (_, n) in step["splits"].items() if c in alive}
        return torch.tensor([c in alive for c in range(self.n_classes)])

    def classify(self, presence: torch.Tensor | PackedPresence) -> torch.Tensor:
        """(N, F) bool presence -> (N,) long class ids, all rows at once."""
        if presence.ndim != 2 or presence.shape[1] != self.n_features:
            raise ValueError(
                f"presence must be (N, {self.n_features}), got {tuple(presence.shape)}"
            )
        steps = self._compiled(np.arange(self.n_features))
        return torch.as_tensor(_replay(presence.cpu().numpy(), steps), device=presence.device)

    def _compiled(self, column: np.ndarray) -> list[tuple[np.ndarray | None, np.ndarray]]:
        """The history as arrays, feature f read in column ``column[f]`` of the presence:
        a group of splits is (column tested by each class or -1, class it moves to where the
        feature is present); a merge is (None, group of each class)."""
        steps, n_classes = [], 1
        for step in self.history:
            if "merge" in step:
                steps.append((None, np.asarray(step["merge"])))
                n_classes = max(step["merge"]) + 1
                continue
            splits = step["splits"]
            size = max([n_classes, *(n + 1 for _, n in splits.values()), *(c + 1 for c in splits)])
            tested, target = np.full(size, -1), np.arange(size)
            for c, (f, n) in splits.items():
                tested[c], target[c] = column[f], n
            steps.append((tested, target))
            n_classes = size
        return steps

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "n_features": self.n_features,
            "in_bdd": self.in_bdd,
            "history": [
                {"splits": [[c, f, n] for c, (f, n) in step["splits"].items()]}
                if "splits" in step
                else step
                for step in self.history
            ],
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> ClassBDD:
        """Rebuild the classes from their saved history, in the BDD unless they had left it."""
        classes = cls(state["n_features"])
        for step in state["history"]:
            if "merge" in step:
                classes.history.append({"merge": list(step["merge"])})
                classes._n_classes = max(step["merge"]) + 1
            else:
                classes.history.append({"splits": {c: (f, n) for c, f, n in step["splits"]}})
                classes._n_classes = max(
                    [classes._n_classes, *(n + 1 for _, _, n in step["splits"])]
                )
        if state.get("in_bdd", True):
            classes._bdd_step(classes._functions_of_history)
        else:
            classes._leave_bdd()
        classes._update_selected()
        return classes

    def _functions_of_history(self) -> list:
        """The classes' functions, built by replaying the history on the BDD."""
        bdd = self.bdd
        functions = {0: bdd.true}
        for step in self.history:
            if "merge" in step:
                merged: dict[int, object] = {}
                for c, g in enumerate(step["merge"]):
                    merged[g] = merged.get(g, bdd.false) | functions.get(c, bdd.false)
                functions = merged
                continue
            for c, (f, n) in step["splits"].items():
                test = self._var(f)
                function = functions.get(c, bdd.false)  # a dropped split's class is empty
                functions[c], functions[n] = function & ~test, function & test
        return [functions.get(c, bdd.false) for c in range(self.n_classes)]


def _droppable(
    bits: np.ndarray,
    steps: list[tuple[np.ndarray | None, np.ndarray]],
    candidates: np.ndarray,
    allowed: np.ndarray,
) -> tuple[list[int], np.ndarray]:
    """The columns of ``candidates``, tried in that order, whose absence moves no row of
    ``bits`` (N, T) out of its class under ``steps`` (see ``ClassBDD._compiled``), or only
    into classes ``allowed`` (S, S) for it, the columns dropped before being absent too; and
    the (N,) classes of the rows with those columns absent. ``bits`` is changed: the dropped
    columns are zeroed."""
    # trail[i]: every row's class before step i. Dropping a column moves only the rows that
    # reach a step testing it, and only from there on.
    n_classes = max(len(target) for _, target in steps) if steps else 1
    trail_type = np.int16 if n_classes <= np.iinfo(np.int16).max else np.int32
    trail = np.empty((len(steps) + 1, len(bits)), dtype=trail_type)
    classes = _replay(bits, steps, trail=trail)
    tests = [[] for _ in range(bits.shape[1])]  # steps that test each column
    for i, (columns, _) in enumerate(steps):
        if columns is not None:  # a group of splits
            for j in np.unique(columns[columns >= 0]):
                tests[j].append(i)

    def trial(j: int) -> tuple[np.ndarray, np.ndarray, int]:
        """The rows showing column j and, of them, those that reach a step testing it, with
        the first such step."""
        present = bits[:, j].nonzero()[0]
        reach, start = np.zeros(len(present), dtype=bool), len(steps)
        for i in tests[j]:
            here = steps[i][0][trail[i, present]] == j
            if here.any():
                reach |= here
                start = min(start, i)
        return present, present[reach], start

    def replay(rows: np.ndarray, zeroed: np.ndarray, start: int) -> np.ndarray:
        """The trail of ``rows`` from step ``start`` on, with column ``zeroed[r]`` absent from
        row r (classifying with a column zeroed is classifying with the cofactor)."""
        new_trail = np.empty((len(steps) + 1 - start, len(rows)), dtype=trail.dtype)
        _replay(bits, steps, start, trail[start, rows], new_trail, rows, zeroed)
        return new_trail

    dropped = []
    # BATCH trials share one replay, each as if the columns before it in the batch stayed. A
    # column dropped before trial j in the batch cleared the bits of the rows showing it
    # ("cleared") and changed the trail of some of them ("moved"); j's shared replay still
    # holds unless a row it replays was cleared, or a row showing j moved (it may now reach
    # j's tests, or reach them elsewhere): then j runs again alone.
    for batch in (candidates[k : k + BATCH] for k in range(0, len(candidates), BATCH)):
        trials = [trial(j) for j in batch]
        start = min(first for _, _, first in trials)
        sizes = [len(rows) for _, rows, _ in trials]
        batch_rows = np.concatenate([rows for _, rows, _ in trials])
        batch_trail = replay(batch_rows, np.repeat(batch, sizes), start)
        cleared, moved = np.zeros(len(bits), dtype=bool), np.zeros(len(bits), dtype=bool)
        for j, (present, rows, first), end in zip(batch, trials, np.cumsum(sizes), strict=True):
            if cleared[rows].any() or moved[present].any():
                present, rows, first = trial(j)
                new_trail = replay(rows, np.full(len(rows), j), first)
            else:
                new_trail = batch_trail[first - start :, end - len(rows) : end]
            if allowed[classes[rows], new_trail[-1]].all():
                bits[present, j] = False
                moved[rows[(new_trail != trail[first:, rows]).any(axis=0)]] = True
                trail[first:, rows] = new_trail
                cleared[present] = True
                dropped.append(int(j))
    return dropped, trail[-1]


def _replay(
    bits: np.ndarray,
    steps: list[tuple[np.ndarray | None, np.ndarray]],
    start: int = 0,
    classes: np.ndarray | None = None,
    trail: np.ndarray | None = None,
    rows: np.ndarray | None = None,
    zeroed: int | np.ndarray = -1,
) -> np.ndarray:
    """(N, T) bool presence -> (n,) class ids of ``rows``, by replaying compiled ``steps`` (see
    ``ClassBDD._compiled``) from step ``start``, the rows being in ``classes`` there (default:
    step 0, every row in class 0).

    Args:
        bits: (N, T) bool presence of the tested features.
        steps: the compiled steps.
        start: the step to replay from.
        classes: (n,) classes of the rows at ``start``.
        trail: (len(steps) + 1 - start, n) array whose row i receives the classes before
            step start + i, and whose last row the result.
        rows: replay only these n rows of ``bits`` (default: all N).
        zeroed: a column read as absent in every row, or (n,) one column for each row.
    """
    rows = np.arange(len(bits)) if rows is None else rows
    classes = np.zeros(len(rows), dtype=np.int64) if classes is None else classes.copy()
    zeroed = np.broadcast_to(zeroed, len(rows))
    for i, (tested, target) in enumerate(steps[start:]):
        if trail is not None:
            trail[i] = classes
        if tested is None:
            classes = target[classes]
            continue
        # A group of splits reads only the rows of the classes it splits.
        at = np.flatnonzero(tested[classes] >= 0)
        column = tested[classes[at]]
        at = at[(column != zeroed[at]) & bits[rows[at], column]]
        classes[at] = target[classes[at]]
    if trail is not None:
        trail[-1] = classes
    return classes


__all__ = ["ClassBDD"]
