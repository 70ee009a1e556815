"""Compound splits (paper section 2.5.1): new features where they split an aliased class best.

At every stage, the most aliased classes (largest TD-error variance first) are searched with
candidate compounds made from their own percepts: pairs of parts (coarse groups of words, or
compounds) that recur in a stable relative position (``vistask.features.propose``), the 128
whose percepts' TD errors they would split best (``ReductionRank``). The candidates are
scored as primitive features are (``find_splits``: variance reduction and Welch's t-test), at
the significance level divided by the number of relations ranked (Bonferroni): thousands of
relations are ranked for each class by the very TD errors they are tested on, and without the
correction chance relations pass (measured on the maze: lower returns with uncorrected
compounds). The best significant candidate of a class becomes a new feature where
it reduces the variance more than the class's primitive split, if it has one: a class that a
word splits is searched too, so that a relation that reads the state (a gauge's needle) is
not put off until words have cut the class into pieces too small to show it.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch

from vistask.features import Compound
from vistask.features.compounds import concatenated_ranges, presence_of_candidates, propose
from vistask.rlvc.database import InteractionDatabase
from vistask.rlvc.split import Split, find_splits, group_moments, sse


def aliased_classes(
    states: torch.Tensor,
    actions: torch.Tensor,
    deltas: torch.Tensor,
    n_states: int,
    n_actions: int,
    min_count: int,
) -> torch.Tensor:
    """Classes by decreasing sum of squared TD-error deviations within their (class, action)
    groups that could split (``2 * min_count`` interactions or more); classes with none left
    out."""
    n, s1, s2 = group_moments(states * n_actions + actions, deltas, n_states * n_actions)
    spread = torch.where(n >= 2 * min_count, sse(n, s1, s2), 0.0)
    per_class = spread.view(n_states, n_actions).sum(1)
    order = torch.argsort(per_class, descending=True, stable=True)
    return order[per_class[order] > 0]


@dataclass
class ReductionRank:
    """Ranks the candidate relations of one class by how much they would reduce the squared
    deviations of its TD errors (the test that ``find_splits`` then makes), and counts the
    relations it ranks: they are all tested, in effect, so they are the family of the
    search's Bonferroni correction.

    A relation is scored from the interactions of the images its bin of ``propose`` holds,
    for each action with ``min_count`` interactions on both sides, the best action's
    reduction (-inf where no action has them).

    Args:
        stats: (P, A, 3) float64 count, sum and sum of squares of the TD errors of each
            percept's interactions under each action.
        min_count: minimum interactions on each side of a split.
        ranked: relations ranked so far (by the calls of ``propose``).
    """

    stats: torch.Tensor
    min_count: int
    ranked: int = 0

    @classmethod
    def of(
        cls,
        percept: np.ndarray,
        n_percepts: int,
        actions: torch.Tensor,
        deltas: torch.Tensor,
        n_actions: int,
        min_count: int,
    ) -> ReductionRank:
        """From the interactions: ``percept`` (N,) index of each one's percept (of
        ``n_percepts``, the images ``propose`` bins), ``actions``, ``deltas`` (N,)."""
        group = torch.as_tensor(percept, dtype=torch.long) * n_actions + actions
        moments = group_moments(group, deltas, n_percepts * n_actions)
        return cls(torch.stack(moments, 1).view(n_percepts, n_actions, 3), min_count)

    def __call__(self, images: np.ndarray, start: np.ndarray) -> np.ndarray:
        """Reduction scores of the relations found in ``images`` (their first occurrences at
        ``start``)."""
        self.ranked += len(start)
        if not len(start):
            return np.zeros(0)
        total = self.stats.sum(0)  # (A, 3)
        # Column by column: a bin's images are a few of the class's percepts, and gathering
        # single columns of them is twice as fast as gathering (A, 3) rows.
        columns = self.stats.view(len(self.stats), -1).T.contiguous().numpy()
        inside = np.stack([np.add.reduceat(c[images], start) for c in columns], 1)
        inside = torch.from_numpy(inside).view(len(start), *total.shape)
        outside = total - inside  # (B, A, 3)
        reduction = sse(*total.unbind(1)) - sse(*inside.unbind(2)) - sse(*outside.unbind(2))
        testable = (inside[..., 0] >= self.min_count) & (outside[..., 0] >= self.min_count)
        return reduction.where(testable, -torch.inf).amax(1).numpy()


def find_compound_splits(
    db: InteractionDatabase,
    states: torch.Tensor,
    deltas: torch.Tensor,
    n_states: int,
    n_actions: int,
    alpha: float = 0.05,
    min_count: int = 10,
    tolerances: Sequence[float] = (1.0,),
    max_classes: int = 8,
    max_candidates: int = 128,
    skip: set[int] | frozenset = frozenset(),
    to_beat: Sequence[Split] = (),
    threads: int = 1,
    margin: float = 0.0,
) -> tuple[list[tuple[Split, Compound]], list[int]]:
    """The best significant compound split of each of the ``max_classes`` most aliased classes
    that are not in ``skip`` (classes that the learner searched in vain since they last
    changed), where it reduces the variance more than the class's split in ``to_beat``.

    Args:
        db: database with feature occurrences (``db.occurrences``).
        states, deltas: (N,) class of x_t and TD error of each interaction.
        n_states, n_actions: sizes S, A.
        alpha: significance level of the whole search of one class (each of its candidates
            is tested at alpha / K, K the relations ranked).
        min_count: as in ``find_splits``.
        tolerances: tolerances of the candidates, in units of their first part's keypoint
            scale: a compound covers a band of relations as wide as its tolerance.
        max_classes: classes searched, by decreasing TD-error variance.
        skip: classes not to search (searched in vain since they last changed).
        max_candidates: candidate compounds scored per class and tolerance, those whose
            bins' percepts split the TD errors best (``ReductionRank``).
        to_beat: primitive splits of some classes (``find_splits``), the reductions that
            their compound splits must exceed.
        threads: classes searched side by side in threads (>= 1, default 1).
        margin: as in ``find_splits``.

    Returns:
        (split, compound) pairs (``split.feature`` is -1 until the compound gets a feature
        id), and the classes searched.
    """
    if db.occurrences is None:
        raise ValueError("compound splits need a database that keeps feature occurrences")
    primitive = {split.state: split.reduction for split in to_beat}
    ranked = aliased_classes(states, db.actions, deltas, n_states, n_actions, min_count)
    searched = [state for state in ranked.tolist() if state not in skip][:max_classes]

    def search(state: int) -> tuple[Split, Compound] | None:
        rows = torch.nonzero(states == state).flatten()
        percepts, local = np.unique(db.obs[rows].numpy(), return_inverse=True)
        occurrences = db.occurrences.select(percepts)
        rank = ReductionRank.of(
            local, len(percepts), db.actions[rows], deltas[rows], n_actions, min_count
        )
        candidates = propose(occurrences, tolerances, min_count, max_candidates, rank)
        if not candidates:
            return None
        # (interaction, candidate) presence pairs in the order of a nonzero of the (rows, K)
        # matrix, made from the smaller (percepts, K) one: each percept's candidates repeated
        # for each of its interactions.
        percept, of_percept = presence_of_candidates(occurrences, candidates).nonzero(as_tuple=True)
        count = np.bincount(percept.numpy(), minlength=len(percepts))
        start = np.cumsum(count) - count
        which = torch.from_numpy(np.repeat(np.arange(len(rows)), count[local]))
        feature = of_percept[torch.from_numpy(concatenated_ranges(start[local], count[local]))]
        splits = find_splits(
            which,
            feature,
            torch.zeros(len(rows), dtype=torch.long),
            db.actions[rows],
            deltas[rows],
            1,
            n_actions,
            len(candidates),
            alpha / rank.ranked,  # the candidates are among the relations ranked
            min_count,
            margin=margin,
        )
        if not splits or splits[0].reduction <= primitive.get(state, 0.0):
            return None
        top = splits[0]
        return Split(state, -1, top.action, top.reduction, top.p_value), candidates[top.feature]

    if threads > 1 and len(searched) > 1:
        with ThreadPoolExecutor(min(threads, len(searched))) as pool:
            outcomes = list(pool.map(search, searched))
    else:
        outcomes = [search(state) for state in searched]
    return [found for found in outcomes if found is not None], searched
