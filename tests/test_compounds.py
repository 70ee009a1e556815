"""Compound features: presence against brute force, a split only a compound can make, saving."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from vistask.experiments.train_rlvc import feature_r2
from vistask.features import (
    Compound,
    Occurrences,
    VisualFeatureExtractor,
    add_compound_occurrences,
    propose,
)
from vistask.features.compounds import compound_occurrences, match, presence_of_candidates
from vistask.rlvc import RLVC, InteractionDatabase
from vistask.rlvc.compound_search import ReductionRank, find_compound_splits


def random_occurrences(rng, n_images=40, n_features=5, per_image=8) -> Occurrences:
    sizes = rng.integers(0, per_image + 1, n_images)
    n = int(sizes.sum())
    return Occurrences(
        np.repeat(np.arange(n_images), sizes),
        rng.integers(0, n_features, n),
        rng.uniform(0, 40, (n, 2)),
        rng.uniform(1, 4, n),
        n_images,
    )


def brute_force_presence(occ: Occurrences, c: Compound) -> np.ndarray:
    present = np.zeros(occ.n_images, bool)
    for i in range(len(occ)):
        for j in range(len(occ)):
            if i == j or occ.image[i] != occ.image[j]:
                continue
            if occ.feature[i] != c.first or occ.feature[j] != c.second:
                continue
            d = (occ.xy[j] - occ.xy[i]) / occ.scale[i] - np.asarray(c.offset)
            present[occ.image[i]] |= float((d * d).sum()) <= c.tolerance**2
    return present


def test_compound_presence_equals_brute_force_on_random_keypoints():
    rng = np.random.default_rng(0)
    for trial in range(20):
        occ = random_occurrences(rng)
        compounds = [
            Compound(int(a), int(b), tuple(rng.uniform(-8, 8, 2)), float(rng.uniform(1, 6)))
            for a, b in rng.integers(0, 5, (6, 2))
        ]
        got = presence_of_candidates(occ, compounds).numpy()
        for k, c in enumerate(compounds):
            assert np.array_equal(got[:, k], brute_force_presence(occ, c)), (trial, c)
        with_compounds = add_compound_occurrences(occ, compounds, first_id=5)
        assert np.array_equal(with_compounds.presence(11).numpy()[:, 5:], got)


def test_compounds_of_compounds_are_added_as_one_at_a_time_would_add_them():
    rng = np.random.default_rng(1)
    for trial in range(20):
        occ = random_occurrences(rng, per_image=12)
        compounds = [  # parts 0-4 are words, 5 on the compounds before
            Compound(int(a), int(b), tuple(rng.uniform(-6, 6, 2)), float(rng.uniform(2, 8)))
            for a, b in (rng.integers(0, 5 + c, 2) for c in range(8))
        ]
        one_at_a_time = occ
        for c, compound in enumerate(compounds):
            one_at_a_time = one_at_a_time.merge(
                compound_occurrences(one_at_a_time, compound, 5 + c)
            )
        got = add_compound_occurrences(occ, compounds, first_id=5)
        assert (got.feature >= 5).any(), trial
        for key in ("image", "feature", "xy", "scale", "part"):
            assert np.array_equal(getattr(got, key), getattr(one_at_a_time, key)), (trial, key)


def test_a_candidate_of_parts_the_images_do_not_show_is_absent():
    occ = Occurrences([0, 0], [0, 1], [[0, 0], [2, 0]], [2, 2], 2)
    candidates = [Compound(0, 1, (1.0, 0.0), 0.1), Compound(0, 7, (1.0, 0.0), 0.1)]
    assert presence_of_candidates(occ, candidates).tolist() == [[True, False], [False, False]]


def test_select_keeps_the_occurrences_of_the_chosen_images_renumbered():
    rng = np.random.default_rng(5)
    occ = random_occurrences(rng, n_images=30)
    images = np.sort(rng.choice(33, 12, replace=False))  # some beyond the table's images
    got = occ.select(images)
    keep = np.isin(occ.image, images)
    assert got.n_images == 12 and len(got) == keep.sum()
    assert got.image.tolist() == np.searchsorted(images, occ.image[keep]).tolist()
    for field in ("feature", "part", "xy", "scale"):
        assert np.array_equal(getattr(got, field), getattr(occ, field)[keep]), field


def test_propose_relates_no_pair_beyond_its_reach():
    def two_images(dx):
        return Occurrences([0, 0, 1, 1], [0, 1, 0, 1], [[0, 0], [dx, 0]] * 2, [1] * 4, 3)

    assert propose(two_images(300.0), min_count=1) == []  # 300 scales apart, MAX_REACH 256
    assert [(c.first, c.second, c.offset) for c in propose(two_images(30.0), min_count=1)] == [
        (0, 1, (30.0, 0.0)),
        (1, 0, (-30.0, 0.0)),
    ]
    assert propose(Occurrences([], [], [], [], 0)) == []


def test_a_compound_of_a_compound_occurs_at_its_parts_midpoint():
    occ = Occurrences([0, 0, 0], [0, 1, 2], [[0, 0], [4, 0], [2, 6]], [2, 2, 2], 1)
    pair = Compound(0, 1, (2.0, 0.0), 0.1)  # 1 two scales right of 0: at (2, 0)
    triple = Compound(3, 2, (0.0, 3.0), 0.1)  # 2 three scales below the pair
    both = add_compound_occurrences(occ, [pair, triple], first_id=3)
    assert both.presence(5)[0].tolist() == [True] * 5
    i, _ = match(both, triple)
    assert both.xy[i].tolist() == [[2.0, 0.0]]
    moved = add_compound_occurrences(
        Occurrences([0, 0, 0], [0, 1, 2], [[0, 0], [4, 0], [2, 9]], [2, 2, 2], 1),
        [pair, triple],
        first_id=3,
    )
    assert moved.presence(5)[0].tolist() == [True, True, True, True, False]


def relation_database(n=600, seed=0, word_agrees=None) -> InteractionDatabase:
    """One-step episodes whose reward is 1 when feature 1 lies 5 scales right of feature 0,
    and 0 when it lies anywhere else; every percept shows features 0-5 once. With
    ``word_agrees``, a word (feature 6) shows where the relation holds, in that share of the
    percepts, and where it does not, in the others."""
    rng = np.random.default_rng(seed)
    related = rng.random(n) < 0.5
    xy = rng.uniform(0, 100, (n, 6, 2))
    xy[related, 1] = xy[related, 0] + [10.0, 0.0]  # scale 2: 5 scales right
    near = ~related & (np.linalg.norm(xy[:, 1] - xy[:, 0] - [10.0, 0.0], axis=1) < 8)
    xy[near, 1] = xy[near, 0] - [30.0, 30.0]  # unrelated percepts: far from the relation
    image, feature = np.repeat(np.arange(n), 6), np.tile(np.arange(6), n)
    xy = xy.reshape(-1, 2)
    if word_agrees is not None:
        word = np.flatnonzero(related == (rng.random(n) < word_agrees))
        image, feature = np.r_[image, word], np.r_[feature, np.full(len(word), 6)]
        xy = np.r_[xy, rng.uniform(0, 100, (len(word), 2))]
        order = np.argsort(image, kind="stable")
        image, feature, xy = image[order], feature[order], xy[order]
    occ = Occurrences(image, feature, xy, np.full(len(image), 2.0), n + 1)  # n: the end
    return InteractionDatabase(
        presence=occ.presence(6 if word_agrees is None else 7),
        obs=torch.arange(n),
        actions=torch.zeros(n, dtype=torch.long),
        rewards=torch.from_numpy(related.astype(float)),
        next_obs=torch.full((n,), n),
        terminal=torch.ones(n, dtype=torch.bool),
        occurrences=occ,
    )


def test_only_a_compound_splits_a_reward_that_depends_on_a_relation():
    db = relation_database()
    plain = RLVC(db.n_features, 1, gamma=0.9).learn(db, progress=False)
    assert plain.n_classes == 1  # every feature is in every percept: nothing to split on
    rlvc = RLVC(db.n_features, 1, gamma=0.9, use_compounds=True).learn(db, progress=False)
    assert len(rlvc.compounds) >= 1 and rlvc.compound_features == [6]
    c = rlvc.compounds[0]
    assert {c.first, c.second} == {0, 1}
    assert np.allclose(np.abs(c.offset), [5.0, 0.0], atol=0.5)
    classes = rlvc.structure.classify(db.presence)[db.obs]
    values = rlvc.values()[classes].numpy()
    assert np.allclose(values, db.rewards.numpy(), atol=1e-9)  # each percept's true value


@pytest.mark.parametrize("word_agrees", [0.8, 1.0])
def test_a_compound_splits_a_class_that_a_word_splits_too_only_where_it_does_better(word_agrees):
    db = relation_database(word_agrees=word_agrees)  # the word: right in 80% or all percepts
    rlvc = RLVC(db.n_features, 1, gamma=0.9, use_compounds=True)
    rlvc.learn(db, max_stages=1, progress=False)
    assert rlvc.structure.selected_features == ([7] if word_agrees < 1 else [6])
    assert len(rlvc.compounds) == (1 if word_agrees < 1 else 0)


def brute_force_proposals(occ: Occurrences, tolerance: float, min_count: int) -> list:
    """(first, second, offset, images) of every bin seen in min_count to n_images - min_count
    images, by decreasing image count, then by (first, second, cell)."""
    images, displacements = {}, {}
    for i in range(len(occ)):
        for j in range(len(occ)):
            if i == j or occ.image[i] != occ.image[j]:
                continue
            d = (occ.xy[j] - occ.xy[i]) / occ.scale[i]
            cell = tuple(np.floor(d / tolerance + 0.5).astype(int))
            b = (int(occ.part[i]), int(occ.part[j]), cell)
            images.setdefault(b, set()).add(int(occ.image[i]))
            displacements.setdefault(b, []).append(d)
    bins = [b for b, ims in images.items() if min_count <= len(ims) <= occ.n_images - min_count]
    bins.sort(key=lambda b: (-len(images[b]), b))
    return [(b[0], b[1], np.mean(displacements[b], axis=0), images[b]) for b in bins]


def test_propose_counts_the_images_of_every_relation_as_brute_force_does():
    rng = np.random.default_rng(3)
    for _ in range(5):
        occ = random_occurrences(rng, n_images=30, n_features=3, per_image=6)
        for tolerance in (2.0, 4.0):
            got = propose(occ, tolerances=(tolerance,), min_count=2)
            expected = brute_force_proposals(occ, tolerance, min_count=2)
            assert got and [(c.first, c.second) for c in got] == [e[:2] for e in expected]
            assert np.allclose([c.offset for c in got], [e[2] for e in expected], atol=1e-4)


def test_td_ranked_proposals_order_relations_as_brute_force_does():
    """Relations ranked by the reduction of the TD errors' squared deviations that a split of
    the interactions of their bin's images makes, per action with min_count on both sides."""
    rng = np.random.default_rng(4)
    for _ in range(5):
        occ = random_occurrences(rng, n_images=30, n_features=3, per_image=6)
        percept = rng.integers(0, 30, 200)
        actions, deltas = rng.integers(0, 2, 200), rng.normal(size=200)
        rank = ReductionRank.of(
            percept, 30, torch.from_numpy(actions), torch.from_numpy(deltas), 2, 4
        )
        got = propose(occ, tolerances=(4.0,), min_count=2, max_candidates=10**6, rank=rank)

        def sse(x):
            return float(((x - x.mean()) ** 2).sum()) if len(x) else 0.0

        expected = []
        for first, second, offset, images in brute_force_proposals(occ, 4.0, 2):
            inside = np.isin(percept, sorted(images))
            score = max(
                (
                    sse(deltas[a]) - sse(deltas[a & inside]) - sse(deltas[a & ~inside])
                    for a in (actions == 0, actions == 1)
                    if (a & inside).sum() >= 4 and (a & ~inside).sum() >= 4
                ),
                default=-np.inf,
            )
            expected.append((score, first, second, offset))
        assert rank.ranked == len(expected)
        expected = [e for e in expected if e[0] > -np.inf]
        assert got and len(got) == len(expected)
        scores = []
        for c in got:  # the brute-force bin of each proposal, then its score
            (score,) = [
                e[0]
                for e in expected
                if (e[1], e[2]) == (c.first, c.second) and np.allclose(e[3], c.offset, atol=1e-4)
            ]
            scores.append(score)
        assert np.all(np.diff(scores) <= 1e-9)  # best first


def test_td_ranking_keeps_a_rare_relation_that_the_frequency_cap_drops():
    """Part 1 lies 5 scales right of part 0 in 20 of 200 images, whose TD errors are high;
    parts 2 and 3 lie in one relation in 150 images, unrelated to the TD errors."""
    rng = np.random.default_rng(0)
    rare, common = np.arange(200) < 20, rng.random(200) < 0.75
    xy = rng.uniform(0, 100, (200, 4, 2))
    xy[rare, 1] = xy[rare, 0] + [10.0, 0.0]
    xy[common, 3] = xy[common, 2] + [0.0, 10.0]
    occ = Occurrences(
        np.repeat(np.arange(200), 4),
        np.tile(np.arange(4), 200),
        xy.reshape(-1, 2),
        np.full(800, 2.0),
        200,
    )
    deltas = torch.from_numpy(np.where(rare, 1.0, 0.0) + rng.normal(0, 0.1, 200))
    rank = ReductionRank.of(np.arange(200), 200, torch.zeros(200, dtype=torch.long), deltas, 1, 10)
    (by_count,) = propose(occ, min_count=10, max_candidates=1)
    (by_td,) = propose(occ, min_count=10, max_candidates=1, rank=rank)
    assert (by_count.first, by_count.second) in {(2, 3), (3, 2)}
    assert (by_td.first, by_td.second) in {(0, 1), (1, 0)}
    assert rank.ranked > 1  # the family of its Bonferroni correction: every relation ranked


def test_propose_keeps_only_relations_that_could_split():
    db = relation_database(n=200)
    candidates = propose(db.occurrences, tolerances=(1.0,), min_count=10)
    assert candidates, "the planted relation recurs in about 100 percepts"
    assert any({c.first, c.second} == {0, 1} for c in candidates)
    with pytest.raises(ValueError, match="tolerances"):
        propose(db.occurrences, tolerances=(0.0,))


def test_added_compounds_extend_the_interaction_pairs_as_a_fresh_database_finds_them():
    """The split search sums each feature's pairs in their order: the cached pairs, extended
    by the compounds' pairs, hold every feature's pairs in the order that a database built
    with the compounds already in it has them; so do the percept-action pairs."""
    db = relation_database(n=200, word_agrees=0.8)
    db = db.take(torch.from_numpy(np.random.default_rng(1).integers(0, 200, 300)))
    db.interaction_features()  # cached before the compounds come
    db.percept_action_features()
    compounds = [Compound(0, 1, (5.0, 0.0), 1.0), Compound(2, 7, (0.0, 3.0), 40.0)]
    db.add_compounds(compounds[:1])
    db.add_compounds(compounds[1:])  # a compound of a compound
    fresh = replace(db, _coo=None, _pairs=None)
    rows, features = db.interaction_features()
    fresh_rows, fresh_features = fresh.interaction_features()
    pairs, pair_rows, pair_features = db.percept_action_features()
    fresh_pairs, fresh_pair_rows, fresh_pair_features = fresh.percept_action_features()
    assert torch.equal(pairs, fresh_pairs)
    assert set(features[features >= 7].tolist()) == {7, 8}
    for f in range(db.n_features):
        assert torch.equal(rows[features == f], fresh_rows[fresh_features == f]), f
        assert torch.equal(
            pair_rows[pair_features == f], fresh_pair_rows[fresh_pair_features == f]
        ), f


def test_databases_sharing_presence_add_compounds_without_touching_each_other():
    """A database taken from another shares its presence: compounds added to one must not
    show in the other."""
    db = relation_database(n=200)
    a, b, c = (
        Compound(0, 1, (5.0, 0.0), 1.0),
        Compound(2, 3, (0.0, 0.0), 60.0),
        Compound(4, 4, (0.0, 0.0), 1.0),
    )
    db.add_compounds([a])
    other = db.take(torch.arange(100))  # shares db's presence
    db.add_compounds([b])
    other.add_compounds([c])
    for database in (db, other):
        assert torch.equal(database.presence.dense(), database.occurrences.presence(8))
    assert not torch.equal(db.presence[:, 7], other.presence[:, 7])


def test_classes_searched_side_by_side_find_what_one_thread_finds():
    db = relation_database(n=800, word_agrees=0.5)
    states = db.presence[db.obs, 6].long() + 2 * (db.obs % 2)  # four aliased classes
    deltas = db.rewards - db.rewards.mean()
    found = [find_compound_splits(db, states, deltas, 4, 1, threads=threads) for threads in (1, 2)]
    assert len(found[0][0]) == 4 and found[0] == found[1]


def test_rlvc_with_compounds_round_trips(tmp_path):
    db = relation_database()
    rlvc = RLVC(db.n_features, 1, gamma=0.9, use_compounds=True).learn(db, progress=False)
    rlvc.save(tmp_path / "rlvc.pt")
    loaded = RLVC.load(tmp_path / "rlvc.pt")
    assert loaded.compounds == rlvc.compounds
    assert torch.equal(loaded.structure.classify(db.presence), rlvc.structure.classify(db.presence))
    assert torch.equal(loaded.q, rlvc.q)


def test_feature_r2_is_the_squared_correlation_of_presence_and_values():
    rng = np.random.default_rng(3)
    values = rng.normal(size=500)
    presence = torch.from_numpy(rng.random((500, 7)) < 0.3)
    presence[:, 6] = torch.from_numpy(values > 0.5)  # reads the values well
    got = feature_r2(presence, values).numpy()
    brute = [np.corrcoef(presence[:, f].numpy(), values)[0, 1] ** 2 for f in range(7)]
    assert np.allclose(got, brute)
    assert got.argmax() == 6


def test_a_words_compound_part_is_its_coarse_group(tmp_path):
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, (64, 64, 3), dtype=np.uint8) for _ in range(30)]
    extractor = VisualFeatureExtractor.fit(images, n_words=64, groups=4)
    occ = extractor.occurrences(images)
    assert len(occ) > 0
    assert np.array_equal(occ.part, extractor.groups.group_of.numpy()[occ.feature])
    flat = VisualFeatureExtractor.fit(images, n_words=64, groups=0).occurrences(images)
    assert np.array_equal(flat.part, flat.feature)
