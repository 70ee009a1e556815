"""BDD classes and compaction: merging, classification against the tree and dd, persistence."""

import numpy as np
import pytest
import torch

from vistask.rlvc import (
    RLVC,
    ClassBDD,
    ClassTree,
    Committee,
    InteractionDatabase,
    acceptable,
    compaction,
    interchangeable,
    merge_groups,
)
from vistask.rlvc.compaction import induced_splits
from vistask.rlvc.presence import PackedPresence
from vistask.rlvc.solver import state_values


def random_q(n_states: int, n_actions: int, seed: int) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    q = rng.normal(0, 1, (n_states, n_actions)).round(1)  # ties, as value iteration gives
    q[rng.random((n_states, n_actions)) < 0.1] = -np.inf  # actions a class never tried
    return torch.from_numpy(q)


def pair_by_pair(q: torch.Tensor, holds) -> torch.Tensor:
    """(S, S) bool: i == j, or both classes tried an action and ``holds(i, j, v, greedy)``."""
    v, greedy = state_values(q), q.argmax(dim=1)
    tried = torch.isfinite(q).any(dim=1)
    n = len(q)
    expected = torch.zeros(n, n, dtype=torch.bool)
    for i in range(n):
        for j in range(n):
            expected[i, j] = i == j or bool(tried[i] and tried[j] and holds(i, j, v, greedy))
    return expected


def test_interchangeable_equals_its_definition_pair_by_pair():
    q, t = random_q(40, 3, seed=0), 0.3
    expected = pair_by_pair(
        q,
        lambda i, j, v, greedy: (
            abs(v[i] - v[j]) <= t and q[j, greedy[i]] >= v[j] - t and q[i, greedy[j]] >= v[i] - t
        ),
    )
    assert torch.equal(interchangeable(q, t), expected)


def test_acceptable_equals_its_definition_pair_by_pair():
    q, t, value_t = random_q(40, 3, seed=1), 0.3, 1.2
    expected = pair_by_pair(
        q, lambda i, j, v, greedy: abs(v[i] - v[j]) <= value_t and q[i, greedy[j]] >= v[i] - t
    )
    result = acceptable(q, t, value_t)
    assert torch.equal(result, expected)
    assert not torch.equal(result, result.T)  # one way only
    with pytest.raises(ValueError, match="tolerances must be >= 0"):
        acceptable(q, 0.1, -1.0)


@pytest.mark.parametrize("seed", range(3))
def test_merging_keeps_every_greedy_action_within_the_tolerance(seed):
    q, tolerance = random_q(60, 4, seed), 0.5
    groups = merge_groups(q, tolerance)
    assert sorted(set(groups.tolist())) == list(range(int(groups.max()) + 1))
    assert int(groups.max()) + 1 < 60  # something merged
    v, greedy = state_values(q), q.argmax(dim=1)
    for c in range(60):
        for m in (groups == groups[c]).nonzero().flatten().tolist():
            # Acting in class c with any member's greedy action loses at most the tolerance.
            assert q[c, greedy[m]] >= v[c] - tolerance
            assert abs(v[c] - v[m]) <= tolerance
    # A zero tolerance merges only classes with equal values and the same greedy action.
    exact = merge_groups(q, 0.0)
    for c, m in torch.combinations(torch.arange(60)).tolist():
        if exact[c] == exact[m]:
            assert v[c] == v[m]


def random_splits(n_features: int, n_splits: int, seed: int) -> tuple[ClassTree, ClassBDD]:
    rng = np.random.default_rng(seed)
    tree, bdd = ClassTree(n_features), ClassBDD(n_features)
    for _ in range(n_splits):
        c, f = int(rng.integers(tree.n_classes)), int(rng.integers(n_features))
        assert tree.split(c, f) == bdd.split(c, f)
    return tree, bdd


def test_bdd_classification_equals_the_trees_before_any_compaction():
    tree, bdd = random_splits(30, 60, seed=0)
    presence = torch.from_numpy(np.random.default_rng(1).random((3000, 30)) < 0.3)
    assert torch.equal(bdd.classify(presence), tree.classify(presence))
    assert set(bdd.selected_features) <= set(tree.selected_features)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_tree_gives_back_the_splits_that_made_it(seed):
    tree, _ = random_splits(20, 50, seed)
    rebuilt = ClassBDD.from_splits(20, tree.splits(), list(range(tree.n_classes)), in_bdd=False)
    presence = torch.from_numpy(np.random.default_rng(seed).random((2000, 20)) < 0.3)
    assert torch.equal(rebuilt.classify(presence), tree.classify(presence))
    assert ClassTree.from_state_dict(tree.state_dict()).splits() == tree.splits()


@pytest.mark.parametrize("simplified", [False, True])
def test_vectorized_bdd_classification_equals_dds_own_evaluation(simplified):
    _, bdd = random_splits(16, 40, seed=2)
    groups = torch.unique(torch.randint(0, 9, (bdd.n_classes,)), return_inverse=True)[1]
    bdd.merge(groups)  # disjunctions
    if simplified:  # cofactors in the BDD, deleted splits in the replayed history
        seen = torch.from_numpy(np.random.default_rng(8).random((40, 16)) < 0.2)
        assert bdd.simplify(seen)[0]
    presence = torch.from_numpy(np.random.default_rng(3).random((300, 16)) < 0.5)
    classes = bdd.classify(presence)
    declared = set(bdd.bdd.vars)
    for row, c in zip(presence.tolist(), classes.tolist(), strict=True):
        values = {f"f{i}": bit for i, bit in enumerate(row) if f"f{i}" in declared}
        holds = [bdd.bdd.let(values, u) == bdd.bdd.true for u in bdd.functions]
        assert holds.index(True) == c and sum(holds) == 1  # the classes partition


def test_merge_maps_classes_to_their_groups_and_drops_features_no_class_needs():
    _, bdd = random_splits(20, 30, seed=4)
    presence = torch.from_numpy(np.random.default_rng(5).random((2000, 20)) < 0.4)
    before = bdd.classify(presence)
    groups = torch.unique(torch.randint(0, 5, (bdd.n_classes,)), return_inverse=True)[1]
    bdd.merge(groups)
    assert bdd.n_classes == int(groups.max()) + 1
    assert torch.equal(bdd.classify(presence), groups[before])
    siblings = ClassBDD(20)
    siblings.split(0, 7)
    siblings.split(1, 3)
    siblings.merge(torch.tensor([0, 0, 1]))  # {7 absent or 7 present and 3 absent}, {7 and 3}
    assert siblings.selected_features == [3, 7]
    siblings.merge(torch.tensor([0, 0]))
    assert siblings.selected_features == [] and siblings.n_classes == 1
    with pytest.raises(ValueError, match="without gaps"):
        bdd.merge(torch.zeros(bdd.n_classes, dtype=torch.long) + 1)


def test_simplify_keeps_the_class_of_every_given_percept_and_drops_features():
    _, bdd = random_splits(20, 40, seed=9)
    bdd.merge(torch.unique(torch.randint(0, 6, (bdd.n_classes,)), return_inverse=True)[1])
    seen = torch.from_numpy(np.random.default_rng(10).random((60, 20)) < 0.2)
    before, features = bdd.classify(seen), bdd.selected_features
    dropped, after = bdd.simplify(seen)
    assert torch.equal(after, bdd.classify(seen))
    # The same partition of the seen percepts (empty classes are removed, ids renumbered).
    pairs = set(zip(before.tolist(), after.tolist(), strict=True))
    assert dropped and len(pairs) == len(set(before.tolist())) == len(set(after.tolist()))
    assert bdd.selected_features == sorted(set(features) - set(dropped))


# One batch of trials; several batches, where a drop early in a batch changes the class of
# a later trial's percepts (seed 10) or the bits of the percepts it replays (seed 15); percepts
# seen many times, held as bits (simplify replays each distinct one once).
@pytest.mark.parametrize(
    "n_features, seed, repeated",
    [(20, 12, False), (100, 12, False), (100, 10, False), (100, 15, False), (60, 16, True)],
)
def test_simplify_drops_what_reclassifying_every_percept_one_feature_at_a_time_drops(
    n_features, seed, repeated
):
    rng = np.random.default_rng(seed)
    _, bdd = random_splits(n_features, 2 * n_features, seed=seed)
    bdd.merge(
        torch.from_numpy(np.unique(rng.integers(0, 8, bdd.n_classes), return_inverse=True)[1])
    )
    for c, f in [(0, 4), (3, 11), (1, 4), (5, 17)]:  # splits after the merge
        bdd.split(c, f)
    seen = torch.from_numpy(rng.random((4 * n_features, n_features)) < 0.25)
    if repeated:
        seen = seen[torch.from_numpy(rng.zipf(1.5, 20 * n_features) % len(seen))]
    allowed = torch.from_numpy(rng.random((bdd.n_classes,) * 2) < 0.3)
    allowed |= torch.eye(bdd.n_classes, dtype=torch.bool)
    # Brute force: rarest feature first, drop it when classifying every seen percept with it
    # zeroed (and those dropped before) moves none outside its allowed classes.
    before, kept, expected = bdd.classify(seen), seen.clone(), []
    counts = seen.sum(0)
    for f in sorted(bdd.selected_features, key=lambda f: (int(counts[f]), f)):
        trial = kept.clone()
        trial[:, f] = False
        if allowed[before, bdd.classify(trial)].all():
            kept, expected = trial, [*expected, f]
    dropped, classes = bdd.simplify(PackedPresence.from_dense(seen) if repeated else seen, allowed)
    assert expected and dropped == expected
    assert torch.equal(classes, bdd.classify(seen))
    # A dropped feature moves a percept before a later step tests the next feature there:
    # {0 absent: 0, 0 present: {1 absent: 1, 1 present: 2}}, class 2 may become class 0 only.
    chain = ClassBDD(2)
    chain.split(chain.split(0, 0), 1)
    seen = torch.tensor([[True, True], [False, True], [False, True]])
    allowed = torch.eye(3, dtype=torch.bool)
    allowed[2, 0] = True
    dropped, classes = chain.simplify(seen, allowed)
    assert dropped == [0, 1] and chain.n_classes == 1 and classes.tolist() == [0, 0, 0]


def test_bdd_state_dict_round_trip():
    _, bdd = random_splits(25, 50, seed=6)
    bdd.merge(torch.unique(torch.randint(0, 12, (bdd.n_classes,)), return_inverse=True)[1])
    bdd.simplify(torch.from_numpy(np.random.default_rng(11).random((50, 25)) < 0.2))
    bdd.split(0, 3)  # a split after the compaction
    loaded = ClassBDD.from_state_dict(bdd.state_dict())
    presence = torch.from_numpy(np.random.default_rng(7).random((2000, 25)) < 0.5)
    assert torch.equal(loaded.classify(presence), bdd.classify(presence))
    assert loaded.selected_features == bdd.selected_features


def two_faced_chain(n_states: int = 5, n: int = 4000, seed: int = 0) -> InteractionDatabase:
    """A chain where each state shows one of two features of its own: the tree needs a class
    per feature, compaction can merge the two faces of a state into one class."""
    rng = np.random.default_rng(seed)
    states = rng.integers(0, n_states, n)
    actions = rng.integers(0, 2, n)  # 0: left, 1: right
    nxt = np.clip(states + np.where(actions == 1, 1, -1), 0, n_states - 1)
    terminal = nxt == n_states - 1
    presence = np.zeros((2 * n, 2 * n_states), bool)
    presence[np.arange(n), 2 * states + rng.integers(0, 2, n)] = True
    presence[n + np.arange(n), 2 * nxt + rng.integers(0, 2, n)] = True
    return InteractionDatabase(
        torch.from_numpy(presence),
        torch.arange(n),
        torch.from_numpy(actions),
        torch.from_numpy(np.where(terminal, 10.0, 0.0)),
        torch.arange(n, 2 * n),
        torch.from_numpy(terminal),
    )


def test_compaction_merges_the_faces_of_each_state_and_keeps_the_policy(tmp_path):
    db = two_faced_chain()
    tree = RLVC(db.n_features, 2, gamma=0.9).learn(db, progress=False)
    bdd = RLVC(
        db.n_features, 2, gamma=0.9, compaction=True, compact_every=5, compaction_tolerance=0.01
    )
    bdd.learn(db, progress=False)
    assert isinstance(bdd.structure, ClassBDD)
    assert sum(r.merged for r in bdd.history) > 0
    assert bdd.n_classes < tree.n_classes
    faces = torch.eye(db.n_features, dtype=torch.bool)[:8]  # both faces of states 0..3
    assert bdd.greedy(faces).tolist() == tree.greedy(faces).tolist() == [1] * 8
    classes = bdd.structure.classify(db.presence)
    torch.testing.assert_close(bdd.q, bdd.solve(db, classes))  # Q of the final classes
    bdd.save(tmp_path / "rlvc.pt")
    loaded = RLVC.load(tmp_path / "rlvc.pt")
    assert isinstance(loaded.structure, ClassBDD)
    assert torch.equal(loaded.structure.classify(db.presence), classes)
    assert loaded.history == bdd.history


def test_a_tree_merged_once_keeps_the_policy_with_fewer_classes_and_round_trips(tmp_path):
    db = two_faced_chain()
    tree = RLVC(db.n_features, 2, gamma=0.9).learn(db, progress=False)
    before, greedy = tree.n_classes, tree.greedy(db.presence)
    merged = RLVC.from_state_dict(tree.state_dict()).merge(db, 0.01)
    assert isinstance(merged.structure, ClassBDD) and merged.n_classes < before
    # The faces of one state merge; every percept keeps its greedy action.
    assert merged.n_classes <= 5
    assert torch.equal(merged.greedy(db.presence), greedy)
    classes = merged.structure.classify(db.presence)
    torch.testing.assert_close(merged.q, merged.solve(db, classes))
    merged.save(tmp_path / "rlvc.pt")
    loaded = RLVC.load(tmp_path / "rlvc.pt")
    assert isinstance(loaded.structure, ClassBDD)
    assert torch.equal(loaded.structure.classify(db.presence), classes)
    # Learning goes on from the merged classes, and a zero tolerance merges only equals.
    assert loaded.learn(db, progress=False).n_classes >= merged.n_classes
    assert RLVC.from_state_dict(tree.state_dict()).merge(db, 0.0).n_classes <= before
    with pytest.raises(ValueError, match=r"tolerance must be in \[0, 1\)"):
        tree.merge(db, 1.5)


def test_compaction_settings_are_checked():
    with pytest.raises(ValueError, match="compact_every"):
        RLVC(10, 2, 0.9, compact_every=0)
    with pytest.raises(ValueError, match="compaction_tolerance"):
        RLVC(10, 2, 0.9, compaction=True, compaction_tolerance=1.5)


def equality_classes(k: int, max_memory: int) -> tuple[ClassTree, ClassBDD, list[int]]:
    """The same splits in a tree and a BDD: a full tree over features 0..k-1 (x), each leaf b
    then split along k..2k-1 (y) down to the cell where y = b. The cells together are x = y:
    2^k nodes in the order x then y."""
    tree, classes = ClassTree(2 * k), ClassBDD(2 * k, max_memory=max_memory)

    def split(c: int, f: int) -> int:
        new = tree.split(c, f)
        assert classes.split(c, f) == new
        return new

    leaves = [0]
    for i in range(k):
        leaves = [c for leaf in leaves for c in (leaf, split(leaf, i))]
    cells = []
    for b, leaf in enumerate(leaves):  # leaf b: feature i present where bit k-1-i of b is
        for i in range(k):
            present = split(leaf, k + i)
            leaf = present if (b >> (k - 1 - i)) & 1 else leaf
        cells.append(leaf)
    return tree, classes, cells


def test_classes_that_outgrow_the_bdd_go_on_as_their_history():
    with pytest.warns(UserWarning, match="outgrew the BDD's memory budget"):
        tree, classes, cells = equality_classes(10, max_memory=16 * 2**20)
        groups = torch.zeros(classes.n_classes, dtype=torch.long)
        groups[cells] = 1
        classes.merge(groups)
    assert not classes.in_bdd and classes.n_classes == 2
    presence = torch.from_numpy(np.random.default_rng(0).random((3000, 20)) < 0.5)
    presence[:1000, 10:] = presence[:1000, :10]
    equal = (presence[:, :10] == presence[:, 10:]).all(dim=1)
    assert torch.equal(classes.classify(presence), equal.long())
    assert torch.equal(classes.classify(presence), groups[tree.classify(presence)])
    assert classes.split(1, 0) == 2  # learning goes on: splits, dropped features, saving
    assert torch.equal(classes.classify(presence), equal * (1 + presence[:, 0]))
    assert classes.selected_features == list(range(20))
    seen = presence[~presence[:, 19]]
    assert classes.simplify(seen)[0] == [19] and classes.selected_features == list(range(19))
    assert torch.equal(classes.classify(seen), equal[~presence[:, 19]] * (1 + seen[:, 0]))
    loaded = ClassBDD.from_state_dict(classes.state_dict())
    assert not loaded.in_bdd and loaded.history == classes.history
    assert torch.equal(loaded.classify(presence), classes.classify(presence))
    assert loaded.selected_features == classes.selected_features


def test_features_drop_when_their_cofactors_outgrow_the_bdd(monkeypatch):
    bdd_step = ClassBDD._bdd_step

    def out_of_memory_at_cofactors(self, step):
        def no_node():
            raise RuntimeError("cofactor failed")  # what dd.cudd's ``let`` raises

        bdd_step(self, no_node if step.__name__ == "cofactors" else step)

    monkeypatch.setattr(ClassBDD, "_bdd_step", out_of_memory_at_cofactors)
    classes = ClassBDD(3)
    classes.split(classes.split(0, 0), 1)  # {0 absent: 0, 0 present: {1 absent: 1, present: 2}}
    seen = torch.tensor([[False, False, True], [True, False, False]])  # feature 1 never present
    with pytest.warns(UserWarning, match="outgrew the BDD's memory budget"):
        assert classes.simplify(seen)[0] == [1]
    assert not classes.in_bdd and classes.selected_features == [0]
    assert classes.classify(torch.tensor([[True, True, False]])).tolist() == [1]


def test_rlvc_merges_on_when_its_classes_outgrow_the_bdd(monkeypatch):
    bdd_step = ClassBDD._bdd_step

    def out_of_memory_at_merges(self, step):
        def no_node():
            raise ValueError("`DdNode *node` is `NULL` pointer.")  # what dd.cudd raises

        bdd_step(self, no_node if step.__name__ == "merged_functions" else step)

    monkeypatch.setattr(ClassBDD, "_bdd_step", out_of_memory_at_merges)
    db = two_faced_chain()
    tree = RLVC(db.n_features, 2, gamma=0.9).learn(db, progress=False)
    bdd = RLVC(
        db.n_features, 2, gamma=0.9, compaction=True, compact_every=5, compaction_tolerance=0.01
    )
    with pytest.warns(UserWarning, match="outgrew the BDD's memory budget"):
        bdd.learn(db, progress=False)
    assert not bdd.structure.in_bdd
    assert sum(r.merged for r in bdd.history) > 0 and bdd.n_classes < tree.n_classes
    faces = torch.eye(db.n_features, dtype=torch.bool)[:8]  # both faces of states 0..3
    assert bdd.greedy(faces).tolist() == [1] * 8


def test_induced_splits_keep_every_percept_in_its_class_and_test_only_the_features_given():
    rng = np.random.default_rng(20)
    _, labelling = random_splits(12, 25, seed=20)
    groups = torch.from_numpy(rng.integers(0, 6, labelling.n_classes))
    labelling.merge(torch.unique(groups, return_inverse=True)[1])
    presence = torch.from_numpy(rng.random((500, 30)) < 0.3)  # features 12..29 are noise
    classes = labelling.classify(presence[:, :12])
    classes = torch.unique(classes, return_inverse=True)[1]
    features = sorted(labelling.selected_features)
    splits, groups = induced_splits(presence, classes, features)
    assert {f for _, f in splits} <= set(features)
    induced = ClassBDD.from_splits(30, splits, groups)
    assert torch.equal(induced.classify(presence), classes)
    assert induced.n_classes == int(classes.max()) + 1


def test_induced_splits_grow_the_same_tree_from_a_sparse_matrix(monkeypatch):
    rng = np.random.default_rng(23)
    presence = torch.from_numpy(rng.random((600, 40)) < 0.2)
    classes = torch.unique(presence[:, :5].sum(dim=1) + 2 * presence[:, 7], return_inverse=True)[1]
    dense = induced_splits(presence, classes, list(range(40)))
    monkeypatch.setattr(compaction, "DENSE_TREE_BYTES", 0)
    assert induced_splits(presence, classes, list(range(40))) == dense


def test_induced_splits_test_the_feature_that_tells_the_classes_apart():
    # Percepts are in class 1 where feature 0 shows; 20 noise features also tell the training
    # percepts apart, but the one test that holds for all of them is feature 0.
    rng = np.random.default_rng(21)
    presence = torch.from_numpy(rng.random((400, 21)) < 0.5)
    splits, groups = induced_splits(presence, presence[:, 0].long(), list(range(21)))
    assert splits == [(0, 0)] and groups == [0, 1]
    unseen = torch.from_numpy(rng.random((1000, 21)) < 0.5)
    induced = ClassBDD.from_splits(21, splits, groups)
    assert torch.equal(induced.classify(unseen), unseen[:, 0].long())


def test_induced_splits_reproduce_with_their_seed_and_regrow_outside_the_bdd_alike():
    rng = np.random.default_rng(22)
    presence = torch.from_numpy(rng.random((300, 15)) < 0.3)
    classes = torch.unique(presence[:, :4].sum(dim=1), return_inverse=True)[1]
    splits, groups = induced_splits(presence, classes, list(range(15)), seed=3)
    assert induced_splits(presence, classes, list(range(15)), seed=3) == (splits, groups)
    in_bdd = ClassBDD.from_splits(15, splits, groups)
    history = ClassBDD.from_splits(15, splits, groups, in_bdd=False)
    assert in_bdd.in_bdd and not history.in_bdd
    unseen = torch.from_numpy(rng.random((1000, 15)) < 0.3)
    assert torch.equal(history.classify(unseen), in_bdd.classify(unseen))
    assert torch.equal(history.classify(presence), classes)


def test_leaves_only_copies_reach_take_the_class_of_the_percepts_around_them():
    from sklearn.tree import DecisionTreeClassifier

    from vistask.rlvc.compaction import _node_classes

    rng = np.random.default_rng(23)
    x = (rng.random((200, 16)) < 0.4).astype(np.float32)  # 50 percepts, then 150 copies
    labels = rng.integers(0, 3, 200)
    labels[50:] = np.tile(labels[:50], 3)
    x[50:] = np.tile(x[:50], (3, 1)) * (rng.random((150, 16)) >= 0.3)
    fitted = DecisionTreeClassifier(random_state=0).fit(x, labels)
    tree = fitted.tree_
    leaf_of = fitted.apply(x[:50])
    assert len(np.unique(x[:50], axis=0)) == 50
    node_class = _node_classes(tree, leaf_of, labels[:50], np.ones(50, dtype=np.int64), 3)
    parent = {int(c): p for p in range(tree.node_count) for c in tree.children_left[p : p + 1]}
    parent |= {int(c): p for p in range(tree.node_count) for c in tree.children_right[p : p + 1]}

    def below(node):  # the percepts' labels under a node, by brute force
        return [
            label
            for leaf, label in zip(leaf_of, labels[:50], strict=True)
            if node == leaf or node in ancestors(leaf)
        ]

    def ancestors(node):
        out = []
        while node in parent and node != 0:
            node = parent[node]
            out.append(node)
        return out

    def leaf_class(leaf):
        for node in [leaf, *ancestors(leaf)]:
            if below(node):
                return int(np.bincount(below(node), minlength=3).argmax())

    for node in range(tree.node_count):
        leaves = [
            n
            for n in range(tree.node_count)
            if tree.children_left[n] < 0 and (n == node or node in ancestors(n))
        ]
        kinds = {leaf_class(leaf) for leaf in leaves}
        assert node_class[node] == (kinds.pop() if len(kinds) == 1 else -1)


def test_induced_splits_refuse_equal_percepts_in_different_classes():
    presence = torch.tensor([[1, 0], [1, 0], [0, 1]]).bool()
    with pytest.raises(ValueError, match="different classes"):
        induced_splits(presence, torch.tensor([0, 1, 1]), [0, 1])
    assert induced_splits(presence, torch.tensor([2, 2, 2]), [0, 1]) == ([], [2])


def test_regrow_keeps_every_percept_in_its_class_and_q_solved_on_them():
    db = two_faced_chain(seed=1)
    rlvc = RLVC(db.n_features, 2, gamma=0.9, compaction=True, compaction_tolerance=0.01)
    rlvc.learn(db, progress=False)
    before, q = rlvc.structure.classify(db.presence), rlvc.q.clone()
    rlvc.regrow(db)
    after = rlvc.structure.classify(db.presence)
    assert len(set(zip(before.tolist(), after.tolist(), strict=True))) == len(set(before.tolist()))
    torch.testing.assert_close(rlvc.q, rlvc.solve(db, after))
    torch.testing.assert_close(rlvc.q[after], q[before])  # the same classes, renumbered at most
    assert rlvc.history[-1].classes == rlvc.n_classes
    with pytest.raises(ValueError, match="compaction=True"):
        RLVC(db.n_features, 2, gamma=0.9).learn(db, progress=False).regrow(db)


@pytest.mark.parametrize("workers", [1, 2])
def test_fuse_classes_hold_the_mean_q_of_their_percepts_and_greedy_acts_on_the_structures(workers):
    # Rewards that three features set through noise: bootstrap samples split them differently.
    rng = np.random.default_rng(5)
    n = 1500
    presence = torch.from_numpy(rng.random((2 * n, 12)) < 0.5)
    actions = torch.from_numpy(rng.integers(0, 2, n))
    x = presence[:n].double()
    rewards = (2 * actions - 1) * (x[:, 0] + 0.5 * x[:, 1] - x[:, 2]) + torch.from_numpy(
        rng.normal(size=n)
    )
    terminal = torch.from_numpy(rng.random(n) < 0.2)
    db = InteractionDatabase(
        presence, torch.arange(n), actions, rewards, n + torch.arange(n), terminal
    )
    rlvc = RLVC(db.n_features, 2, gamma=0.9, compaction=True, compaction_tolerance=0.01)
    rlvc.learn(db, progress=False)
    # The structures that fuse learns, made again by brute force: the same bootstrap samples.
    generator = torch.Generator().manual_seed(7)
    learned = [(rlvc.structure, rlvc.q.clone())]
    for _ in range(2):
        sample = torch.randint(len(db), (len(db),), generator=generator)
        other = RLVC(db.n_features, 2, gamma=0.9, compaction=True, compaction_tolerance=0.01)
        other.learn(db.take(sample), progress=False)
        learned.append((other.structure, other.q))
    structures = [(structure.classify(db.presence), q) for structure, q in learned]
    new_percepts = torch.from_numpy(rng.random((500, 12)) < 0.5)
    votes = [[q[int(c)] for c in structure.classify(new_percepts)] for structure, q in learned]
    committee_greedy = [int(torch.argmax(sum(v))) for v in zip(*votes, strict=True)]
    mean_q = [
        sum(q[int(classes[i])] for classes, q in structures) / 3 for i in range(len(db.presence))
    ]
    cells = [tuple(int(classes[i]) for classes, _ in structures) for i in range(len(db.presence))]
    assert len(set(cells)) > len(set(cells[i][0] for i in range(len(cells))))  # they differ

    rlvc.fuse(db, 3, seed=7, workers=workers)
    fused = rlvc.structure.classify(db.presence)
    assert rlvc.history[-1].classes == rlvc.n_classes == len(set(fused.tolist()))
    assert rlvc.n_classes < len(set(cells))  # interchangeable cells merged
    for cell in set(cells):  # a cell stays in one class
        assert len({int(fused[i]) for i in range(len(cells)) if cells[i] == cell}) == 1
    for c in range(rlvc.n_classes):
        members = [mean_q[i] for i in range(len(cells)) if fused[i] == c]
        torch.testing.assert_close(rlvc.q[c], sum(members) / len(members))
    # The policy is the structures': on new percepts, the action of the best mean Q of the
    # classes each puts them in.
    assert rlvc.greedy(new_percepts).tolist() == committee_greedy
    loaded = RLVC.from_state_dict(rlvc.state_dict())
    assert torch.equal(loaded.greedy(new_percepts), rlvc.greedy(new_percepts))
    rlvc.learn(db, progress=False)  # the classes change: the committee goes
    assert rlvc.committee is None
    with pytest.raises(ValueError, match="compaction=True"):
        RLVC(db.n_features, 2, gamma=0.9).learn(db, progress=False).fuse(db, 3)


def test_a_committee_acts_on_the_mean_q_of_the_class_each_structure_gives():
    # Structure a reads feature 0, b feature 1; their Q disagree where both are present.
    a, b = ClassBDD(3), ClassBDD(3)
    a.split(0, 0)
    b.split(0, 1)
    q_a = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    q_b = torch.tensor([[0.0, 0.5], [3.0, 0.0]])
    committee = Committee.of([a, b], [q_a, q_b])
    presence = torch.tensor([[0, 0, 1], [1, 0, 0], [0, 1, 0], [1, 1, 1]], dtype=torch.bool)
    expected = torch.stack([q_a[[0, 1, 0, 1]], q_b[[0, 0, 1, 1]]]).mean(0)
    assert committee.classify(presence).tolist() == [[0, 0], [1, 0], [0, 1], [1, 1]]
    torch.testing.assert_close(committee.mean_q(committee.classify(presence)), expected.double())
    assert committee.greedy(presence).tolist() == [0, 1, 0, 0]
    assert all(not s.in_bdd for s in committee.structures)  # kept as their history
    loaded = Committee.from_state_dict(committee.state_dict())
    assert torch.equal(loaded.classify(presence), committee.classify(presence))
    assert all(torch.equal(x, y) for x, y in zip(loaded.q, committee.q, strict=True))
    # An RLVC with a committee acts on it, not on its classes' Q.
    rlvc = RLVC(3, 2, gamma=0.9, compaction=True)
    rlvc.committee = committee
    assert rlvc.greedy(presence).tolist() == [0, 1, 0, 0]
    assert rlvc.q.argmax(1)[rlvc.classify(presence)].tolist() == [0, 0, 0, 0]
    with pytest.raises(ValueError, match=r"Q must be \(classes, actions\) = \(2, A\)"):
        Committee.of([a], [torch.zeros(3, 2)])
    with pytest.raises(ValueError, match="one Q per structure"):
        Committee.of([a, b], [q_a])
