"""New percepts classed by the nearest percepts seen while learning (``vistask.rlvc.seen``)."""

import numpy as np
import pytest
import torch
from test_rlvc_core import synthetic_chain

from vistask.rlvc import RLVC, ClassTree
from vistask.rlvc import seen as seen_module
from vistask.rlvc.seen import SeenPercepts, classify


def random_tree(n_features: int, splits: int, rng: np.random.Generator) -> ClassTree:
    tree = ClassTree(n_features)
    for _ in range(splits):
        tree.split(int(rng.integers(tree.n_classes)), int(rng.integers(n_features)))
    return tree


def brute_force(tree: ClassTree, seen: torch.Tensor, new: torch.Tensor) -> list[int]:
    """For each new row: the class most of the seen rows at the least Hamming distance over the
    tree's tested features are in (ties: the lowest class)."""
    tested = tree.selected_features
    classes = tree.classify(seen).tolist()
    out = []
    for row in new:
        distance = [int((row[tested] != other[tested]).sum()) for other in seen]
        nearest = [classes[k] for k, d in enumerate(distance) if d == min(distance)]
        out.append(min(set(nearest), key=lambda c: (-nearest.count(c), c)))
    return out


def test_nearest_seen_classes_equal_a_brute_force_vote(monkeypatch):
    monkeypatch.setattr(seen_module, "MAX_DISTANCES", 100 * 250)  # chunks of 100 new rows
    rng = np.random.default_rng(0)
    for _ in range(4):
        tree = random_tree(40, 25, rng)
        seen = torch.from_numpy(rng.random((300, 40)) < 0.3)
        seen[:50] = seen[50:100]  # repeated patterns: they count once per percept
        new = torch.from_numpy(rng.random((220, 40)) < 0.3)
        remembered = SeenPercepts.of(tree, seen)
        assert 200 < remembered.patterns.shape[0] <= 250  # chunks of 100 or more
        assert classify(tree, remembered, new).tolist() == brute_force(tree, seen, new)
        # A seen percept keeps the tree's class.
        assert torch.equal(classify(tree, remembered, seen), tree.classify(seen))


def test_one_feature_shown_by_chance_no_longer_moves_a_percept_to_another_class():
    tree = ClassTree(8)
    present = tree.split(0, 0)  # feature 0 present -> class 1, then more tests below it
    for feature in (1, 2, 3):
        present = tree.split(present, feature)
    # Seen: features 0-3 together (the deepest class), or none of them (class 0).
    seen = torch.zeros(20, 8, dtype=torch.bool)
    seen[:10, :4] = True
    remembered = SeenPercepts.of(tree, seen)
    new = torch.zeros(2, 8, dtype=torch.bool)
    new[0, 1:4] = True  # feature 0 missed: the tree puts it in class 0
    new[1, 0] = True  # only feature 0: nearest to the percepts without any
    assert tree.classify(new).tolist() == [0, 1]
    assert classify(tree, remembered, new).tolist() == [present, 0]


def test_seen_percepts_round_trip_and_reject_untested_dependence(tmp_path):
    rng = np.random.default_rng(1)
    tree = random_tree(30, 12, rng)
    seen = torch.from_numpy(rng.random((200, 30)) < 0.4)
    new = torch.from_numpy(rng.random((50, 30)) < 0.4)
    remembered = SeenPercepts.of(tree, seen)
    torch.save(remembered.state_dict(), tmp_path / "seen.pt")
    loaded = SeenPercepts.from_state_dict(torch.load(tmp_path / "seen.pt"))
    assert torch.equal(loaded.nearest(new), remembered.nearest(new))

    class Liar(ClassTree):  # lists fewer features than it tests
        @property
        def selected_features(self):
            return super().selected_features[1:]

    liar = Liar(30)
    liar.split(0, 3)
    liar.split(0, 7)
    with pytest.raises(ValueError, match="does not list"):
        SeenPercepts.of(liar, seen)


def test_rlvc_remembers_until_its_classes_change_and_saves_what_it_remembers(tmp_path):
    db = synthetic_chain(n=1000)
    rlvc = RLVC(db.n_features, 2, gamma=0.9).learn(db, max_stages=2, progress=False)
    assert rlvc.seen is None
    rlvc.remember(db)
    unseen = torch.zeros(3, db.n_features, dtype=torch.bool)
    unseen[:, 6:] = True  # distractors only, or one chain feature beside them
    unseen[1, 2] = unseen[2, 4] = True
    expected = classify(rlvc.structure, rlvc.seen, unseen)
    assert torch.equal(rlvc.classify(unseen), expected)
    assert torch.equal(rlvc.greedy(unseen), rlvc.q.argmax(1)[expected])
    rlvc.save(tmp_path / "rlvc.pt")
    loaded = RLVC.load(tmp_path / "rlvc.pt")
    assert torch.equal(loaded.classify(unseen), expected)
    rlvc.learn(db, progress=False)
    assert rlvc.seen is None
