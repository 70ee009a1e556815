"""RLVC's parts on synthetic data: split search, t-test, Q solver, class tree, database."""

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
import torch

import vistask.envs  # noqa: F401  (registers the maze)
from vistask.envs import VisualMazeEnv, VisualMazeVectorEnv
from vistask.features import Occurrences
from vistask.memory import _set_madvise_hugepage
from vistask.rlvc import (
    RLVC,
    ClassTree,
    InteractionDatabase,
    collect,
    collect_chunks,
    estimate_mdp,
    find_splits,
    td_errors,
    value_iteration,
    vector_copies,
)
from vistask.rlvc import split as split_module


def sparse(presence: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return presence.nonzero(as_tuple=True)


def test_split_search_finds_the_planted_feature():
    rng = np.random.default_rng(0)
    n, f = 2000, 300
    presence = torch.from_numpy(rng.random((n, f)) < 0.3)
    actions = torch.from_numpy(rng.integers(0, 4, n))
    # TD errors depend on feature 123 under action 2 only.
    deltas = torch.from_numpy(rng.normal(0, 1, n))
    deltas += 3.0 * (presence[:, 123] & (actions == 2))
    rows, features = sparse(presence)
    splits = find_splits(
        rows,
        features,
        torch.zeros(n, dtype=torch.long),
        actions,
        deltas,
        1,
        4,
        f,
        alpha=0.05,
        min_count=10,
    )
    assert [(s.state, s.feature, s.action) for s in splits] == [(0, 123, 2)]
    assert splits[0].p_value < 1e-6


def test_the_t_test_refuses_splits_on_pure_noise():
    rng = np.random.default_rng(1)
    n, f = 2000, 5
    presence = torch.from_numpy(rng.random((n, f)) < 0.3)
    rows, features = sparse(presence)
    states = torch.zeros(n, dtype=torch.long)
    actions = torch.zeros(n, dtype=torch.long)
    noise = torch.from_numpy(rng.standard_t(3, n))  # heavy tails, as TD errors have
    kwargs = dict(n_states=1, n_actions=1, n_features=f, min_count=10)
    assert find_splits(rows, features, states, actions, noise, alpha=0.01, **kwargs) == []
    # The same features, once the TD errors depend on one of them, split on it.
    shifted = noise + 2.0 * presence[:, 3]
    assert [s.feature for s in find_splits(rows, features, states, actions, shifted, **kwargs)] == [
        3
    ]


def test_a_margin_refuses_splits_whose_means_differ_by_less():
    rng = np.random.default_rng(2)
    n, f = 4000, 5
    presence = torch.from_numpy(rng.random((n, f)) < 0.5)
    rows, features = sparse(presence)
    zeros = torch.zeros(n, dtype=torch.long)
    # Feature 3 shifts the TD errors by 0.3: significant with thousands of interactions.
    deltas = torch.from_numpy(rng.normal(0, 1, n)) + 0.3 * presence[:, 3]
    args = (rows, features, zeros, zeros, deltas, 1, 1, f)
    plain, margined = find_splits(*args), find_splits(*args, margin=0.1)
    assert [s.feature for s in plain] == [s.feature for s in margined] == [3]
    assert find_splits(*args, margin=0.3) == []
    # A split that the margin lets through keeps its reduction; its p-value grows.
    assert margined[0].reduction == plain[0].reduction
    assert margined[0].p_value > plain[0].p_value


def test_min_count_bounds_each_side_of_a_split():
    n = 100
    presence = torch.zeros(n, 2, dtype=torch.bool)
    presence[:5, 0] = True  # perfect but tiny split
    deltas = torch.zeros(n, dtype=torch.float64)
    deltas[:5] = 10.0
    rows, features = sparse(presence)
    zeros = torch.zeros(n, dtype=torch.long)
    assert find_splits(rows, features, zeros, zeros, deltas, 1, 1, 2, min_count=6) == []
    (split,) = find_splits(rows, features, zeros, zeros, deltas, 1, 1, 2, min_count=5)
    assert split.feature == 0 and split.p_value == 0.0


def brute_force_splits(
    presence, states, actions, deltas, n_states, n_actions, alpha, min_count, prefer=(), share=0.5
):
    """Eq. (7) and Welch's t-test (scipy), class by class, action by action, feature by feature;
    the best significant split on a feature in ``prefer`` instead, if it does ``share`` as well."""
    from scipy import stats

    best = {}
    for s in range(n_states):
        candidates = []
        for a in range(n_actions):
            group = (states == s) & (actions == a)
            d = deltas[group].numpy()
            for f in range(presence.shape[1]):
                has = presence[group, f].numpy()
                if has.sum() < min_count or (~has).sum() < min_count:
                    continue
                sse = ((d - d.mean()) ** 2).sum()
                split = sum(((x - x.mean()) ** 2).sum() for x in (d[has], d[~has]))
                if sse - split > 0:
                    p = stats.ttest_ind(d[has], d[~has], equal_var=False).pvalue
                    candidates.append((sse - split, a, f, p))
        significant = [c for c in candidates if c[3] < alpha]
        if significant:
            best[s] = max(significant, key=lambda c: c[0])  # the first among equals
            preferred = [c for c in significant if c[2] in prefer and c[0] >= share * best[s][0]]
            if preferred:
                best[s] = max(preferred, key=lambda c: c[0])
    return best


def test_split_search_equals_a_per_class_brute_force():
    rng = np.random.default_rng(3)
    n, f, n_states, n_actions = 1500, 40, 5, 3
    presence = torch.from_numpy(rng.random((n, f)) < 0.4)
    presence[:, 30:] = presence[:, 20:30]  # twin features: equal splits, ties to break alike
    states = torch.from_numpy(rng.integers(0, n_states, n))
    actions = torch.from_numpy(rng.integers(0, n_actions, n))
    deltas = torch.from_numpy(rng.normal(0, 1, n))
    for s in range(n_states - 1):  # a planted feature per class, under one action
        deltas += (1.0 + s) * (presence[:, 7 * s + 3] & (states == s) & (actions == s % 3))
    deltas += 3.0 * (presence[:, 25] & (states == 4))  # a twin feature, under every action
    rows, features = sparse(presence)
    data = (states, actions, deltas, n_states, n_actions)
    # Class 3's best split is on twin features 24 and 34, the first taken (as 25 of 25 and 35
    # in class 4); class 2's feature 8 does 0.10 as well as its best (17), class 4's 20 0.10.
    for prefer, share, chosen in [
        ((), 0.5, {0: 3, 1: 10, 2: 17, 3: 24, 4: 25}),
        ((34, 8, 20), 0.3, {0: 3, 1: 10, 2: 17, 3: 34, 4: 25}),
        ((34, 8, 20), 0.1, {0: 3, 1: 10, 2: 8, 3: 34, 4: 20}),
    ]:
        mask = torch.zeros(f, dtype=torch.bool)
        mask[list(prefer)] = True
        splits = find_splits(rows, features, *data, f, 0.05, 8, prefer=mask, prefer_share=share)
        expected = brute_force_splits(presence, *data, 0.05, 8, prefer=prefer, share=share)
        assert {s: e[2] for s, e in expected.items()} == chosen
        assert {s.state for s in splits} == set(expected)
        for split in splits:
            reduction, action, feature, p_value = expected[split.state]
            assert (split.action, split.feature) == (action, feature)
            assert split.reduction == pytest.approx(reduction, rel=1e-9)
            assert split.p_value == pytest.approx(p_value, rel=1e-6)
        assert [s.reduction for s in splits] == sorted((s.reduction for s in splits), reverse=True)
    # A class too small to split (class 5: 12 interactions over 3 actions) takes no part,
    # whatever its TD errors, and the others split as brute force says.
    small, loud = states.clone(), deltas.clone()
    small[:12], loud[:12] = 5, loud[:12] + 50.0 * presence[:12, 0]
    splits = find_splits(rows, features, small, actions, loud, 6, n_actions, f, 0.05, 8)
    expected = brute_force_splits(presence, small, actions, loud, 6, n_actions, 0.05, 8)
    assert 5 not in expected and len(expected) >= 4
    assert {(s.state, s.action, s.feature) for s in splits} == {
        (state, e[1], e[2]) for state, e in expected.items()
    }


def test_split_search_gives_the_same_splits_when_its_cells_outgrow_their_first_room(
    monkeypatch,
):
    db = synthetic_chain(n_states=6, n=4000)
    rows, features = db.interaction_features()
    rng = np.random.default_rng(0)
    states = torch.from_numpy(rng.integers(0, 40, len(db)))
    deltas = torch.from_numpy(rng.normal(0, 1, len(db))) + 2.0 * db.presence[db.obs, 1]
    args = (rows, features, states, db.actions, deltas, 40, 2, db.n_features)
    whole = find_splits(*args)
    monkeypatch.setattr(split_module, "FIRST_CELLS", 1)  # doubled again and again
    assert whole and find_splits(*args) == whole


def test_split_search_over_percept_action_pairs_finds_the_splits_of_every_interaction():
    rng = np.random.default_rng(1)
    n, m = 3000, 50
    presence = torch.from_numpy(rng.random((m, 12)) < 0.4)
    obs, actions = torch.from_numpy(rng.integers(0, m, n)), torch.from_numpy(rng.integers(0, 3, n))
    zeros = torch.zeros(n)
    db = InteractionDatabase(presence, obs, actions, zeros.double(), obs.roll(1), zeros.bool())
    states = torch.from_numpy(rng.integers(0, 4, m))[obs]  # a class is a set of percepts
    deltas = torch.from_numpy(rng.normal(0, 1, n)) + 2.0 * (presence[obs, 3] & (actions == 1))
    pairs, rows, features = db.percept_action_features()
    assert len(torch.unique(pairs)) <= 3 * m
    for i in rng.integers(0, n, 20):  # each interaction's pair shows its percept's features
        assert torch.equal(features[rows == pairs[i]], torch.nonzero(presence[obs[i]]).flatten())
    # Features 12 and 13 copy feature 3 and its complement: splits equal but for rounding,
    # which the first in feature order wins as over interactions.
    presence = torch.cat([presence, presence[:, 3:4], ~presence[:, 3:4]], 1)
    db = replace(db, presence=presence, _pairs=None)
    pairs, rows, features = db.percept_action_features()
    args = (states, actions, deltas, 4, 3, 14)
    each = find_splits(*db.interaction_features(), *args)
    once = find_splits(rows, features, *args, pairs=pairs)
    assert len(each) >= 3 and any(s.feature == 3 for s in each)
    assert once == each  # the same splits, reductions and p-values to the last bit
    # The search reads pairs where interactions repeat them, else the interactions.
    assert torch.equal(db.split_rows()[0], pairs)
    chain = synthetic_chain()
    no_pairs, rows, features = chain.split_rows()
    assert no_pairs is None and (rows, features) == chain.interaction_features()  # the cached


def test_value_iteration_matches_a_hand_solved_mdp():
    # Two states; in s0, action 1 moves to s1 (reward 0); in s1, action 0 ends with reward 10.
    # Other actions stay put with reward 0. Q*(s1, 0) = 10, Q*(s0, 1) = 0.5 * 10 = 5 (gamma 0.5).
    s = torch.tensor([0, 0, 1, 1])
    a = torch.tensor([0, 1, 0, 1])
    r = torch.tensor([0.0, 0.0, 10.0, 0.0], dtype=torch.float64)
    s2 = torch.tensor([0, 1, 1, 1])
    done = torch.tensor([False, False, True, False])
    q = value_iteration(estimate_mdp(s, a, r, s2, done, 2, 2), gamma=0.5)
    expected = torch.tensor([[2.5, 5.0], [10.0, 5.0]], dtype=torch.float64)
    torch.testing.assert_close(q, expected)
    torch.testing.assert_close(
        td_errors(q, s, a, r, s2, done, 0.5), torch.zeros(4, dtype=torch.float64)
    )


def test_estimated_transitions_are_the_counted_frequencies():
    rng = np.random.default_rng(3)
    n, n_states, n_actions = 400, 6, 3
    s, a, s2 = (torch.from_numpy(rng.integers(k, size=n)) for k in (n_states, n_actions, n_states))
    done = torch.from_numpy(rng.random(n) < 0.2)
    mdp = estimate_mdp(s, a, torch.zeros(n, dtype=torch.float64), s2, done, n_states, n_actions)
    counts = np.zeros((n_states, n_actions, n_states))
    np.add.at(counts, (s[~done].numpy(), a[~done].numpy(), s2[~done].numpy()), 1)
    visits = np.bincount((s * n_actions + a).numpy(), minlength=n_states * n_actions)
    expected = counts / np.maximum(visits.reshape(n_states, n_actions, 1), 1)
    np.testing.assert_allclose(mdp.transitions.to_dense().numpy(), expected)


def test_unvisited_actions_are_never_greedy():
    s, a = torch.tensor([0]), torch.tensor([1])
    r, done = torch.tensor([-1.0], dtype=torch.float64), torch.tensor([True])
    q = value_iteration(estimate_mdp(s, a, r, s, done, 1, 3), gamma=0.9)
    assert q.argmax(1).item() == 1 and torch.isinf(q[0, [0, 2]]).all()


def test_estimate_mdp_rejects_unknown_action_ids():
    one = torch.tensor([0])
    with pytest.raises(ValueError, match="action ids"):
        estimate_mdp(one, torch.tensor([5]), one.double(), one, torch.tensor([False]), 1, 4)


def test_batch_classification_equals_per_sample_classification():
    rng = np.random.default_rng(2)
    tree = ClassTree(50)
    for _ in range(30):
        tree.split(int(rng.integers(tree.n_classes)), int(rng.integers(50)))
    presence = torch.from_numpy(rng.random((500, 50)) < 0.5)
    batch = tree.classify(presence)
    single = torch.cat([tree.classify(row[None]) for row in presence])
    assert torch.equal(batch, single)
    assert set(batch.tolist()) <= set(range(tree.n_classes))
    restored = ClassTree.from_state_dict(tree.state_dict())
    assert torch.equal(restored.classify(presence), batch)
    # A walk down the tree, row by row, from its node lists.
    walked = []
    for row in presence.tolist():
        node = 0
        while tree.feature[node] >= 0:
            node = tree.present[node] if row[tree.feature[node]] else tree.absent[node]
        walked.append(tree.leaf_class[node])
    assert batch.tolist() == walked


def test_split_keeps_class_ids_stable():
    tree = ClassTree(4)
    assert tree.split(0, 2) == 1
    assert tree.split(0, 3) == 2
    presence = torch.tensor([[0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 0, 1, 1]]).bool()
    assert tree.classify(presence).tolist() == [0, 1, 2, 1]
    assert tree.selected_features == [2, 3] and tree.depth == 2
    with pytest.raises(ValueError, match="no class"):
        tree.split(7, 0)


def test_empty_database_is_rejected():
    empty = torch.zeros(0, dtype=torch.long)
    with pytest.raises(ValueError, match="empty"):
        InteractionDatabase(
            torch.zeros(1, 3, dtype=torch.bool), empty, empty, empty.double(), empty, empty.bool()
        )


def test_collect_links_interactions_and_stores_a_blocked_view_once():
    env = gym.make("vistask/VisualMaze-v0")
    t = collect(env, 400, seed=3)
    assert len(t) == 400 and len(t.percepts) == len(t.positions)
    blocked = t.obs == t.next_obs
    assert 0 < blocked.sum() < len(t) / 2  # walls block some moves and keep the view
    np.testing.assert_array_equal(t.positions[t.obs[blocked]], t.positions[t.next_obs[blocked]])
    # Within an episode x_{t+1} is the next x_t; no two stored views in a row are equal.
    inside = t.next_obs[:-1] == t.obs[1:]
    assert inside.mean() > 0.9
    for i, j in zip(t.obs[1:][~blocked[1:]], t.next_obs[1:][~blocked[1:]], strict=True):
        assert not np.array_equal(t.percepts[i], t.percepts[j])


def test_collect_cuts_episodes_stuck_against_a_wall():
    env = gym.make("vistask/VisualMaze-v0")
    push_left = lambda views, rng: np.full(len(views), 3)  # noqa: E731 - walls stop it
    t = collect(env, 300, push_left, seed=0, max_blocked=2)
    blocked = t.obs == t.next_obs
    new_episode = np.r_[True, t.next_obs[:-1] != t.obs[1:]]
    run, longest = 0, 0
    for is_blocked, starts in zip(blocked, new_episode, strict=True):
        run = (0 if starts else run) + 1 if is_blocked else 0
        longest = max(longest, run)
    assert longest == 2  # an episode never makes a third blocked move in a row
    uncut = collect(env, 300, push_left, seed=0)
    assert (uncut.obs == uncut.next_obs).mean() > 0.8 > 0.6 > blocked.mean()


def test_collecting_and_learning_run_on_base_pages_and_restore_numpys_setting():
    env = gym.make("vistask/VisualMaze-v0")
    inside = []

    def record(*_) -> None:  # numpy's huge-page setting inside collect and learn
        inside.append(_set_madvise_hugepage(False))
        _set_madvise_hugepage(inside[-1])

    def policy(views, rng):
        record()
        return rng.integers(0, 4, len(views))

    db = synthetic_chain(n=300, seed=0)
    original = _set_madvise_hugepage(True)
    try:
        for setting in (True, False):
            _set_madvise_hugepage(setting)
            collect(env, 20, policy, seed=0)
            assert _set_madvise_hugepage(setting) is setting  # as it was before
            RLVC(db.n_features, 2, gamma=0.9).learn(
                db, max_stages=2, progress=False, on_stage=record
            )
            assert _set_madvise_hugepage(original) is setting
            assert len(inside) > 1 and not any(inside)
            inside.clear()
    finally:
        _set_madvise_hugepage(original)


def test_chunks_hold_the_interactions_of_one_collection():
    env = gym.make("vistask/VisualMaze-v0")
    whole = collect(env, 1500, seed=3, n_envs=8, max_blocked=2)
    parts = list(collect_chunks(env, 1500, seed=3, n_envs=8, max_blocked=2, chunk_percepts=400))
    assert len(parts) > 2 and all(len(p.percepts) <= 400 + 8 for p in parts)

    def interactions(t):
        views = np.stack(t.percepts)
        return views[t.obs], t.actions, t.rewards, views[t.next_obs], t.terminal, t.positions[t.obs]

    for a, b in zip(interactions(whole), zip(*map(interactions, parts), strict=True), strict=True):
        assert np.array_equal(a, np.concatenate(b))
    assert np.array_equal(whole.episode_returns, np.concatenate([p.episode_returns for p in parts]))
    with pytest.raises(ValueError, match="chunk_percepts"):
        next(collect_chunks(env, 100, n_envs=8, chunk_percepts=4))


def test_side_by_side_episodes_are_seeded_and_stay_linked():
    env = gym.make("vistask/VisualMaze-v0")
    t = collect(env, 600, seed=5, n_envs=4)
    assert len(t) == 600
    starts = [gym.make("vistask/VisualMaze-v0").reset(seed=5 + i)[1]["position"] for i in range(4)]
    np.testing.assert_array_equal(t.positions[:4], np.stack(starts))
    moved = np.linalg.norm(t.positions[t.next_obs] - t.positions[t.obs], axis=1)
    assert moved.max() < 0.25  # every x_{t+1} is one noisy step of 0.1 from its own x_t
    # Each episode continues from its own last view: all but the episodes' ends recur as x_t.
    ends = t.terminal | ~np.isin(t.next_obs, t.obs)
    assert ends.sum() <= 600 // 30 + 4 + t.terminal.sum()


def test_collect_steps_the_maze_as_one_batch_unless_other_wrappers_surround_it():
    plain = gym.make("vistask/VisualMaze-v0")
    wrapped = gym.wrappers.RecordEpisodeStatistics(gym.make("vistask/VisualMaze-v0"))
    assert isinstance(vector_copies(plain, 3), VisualMazeVectorEnv)
    assert vector_copies(plain, 3).max_episode_steps == plain.spec.max_episode_steps
    assert isinstance(vector_copies(wrapped, 3), gym.vector.SyncVectorEnv)

    class Windy(VisualMazeEnv):  # changes the dynamics: its copies must step its own way
        def step(self, action):
            return super().step(1)

    assert isinstance(vector_copies(Windy(), 3), gym.vector.SyncVectorEnv)
    # Both give the same interactions: the batch reproduces separate seeded envs.
    batched, one_by_one = (
        collect(env, 500, seed=2, max_blocked=2, n_envs=5) for env in (plain, wrapped)
    )
    for key in ("obs", "actions", "rewards", "next_obs", "terminal", "positions"):
        np.testing.assert_array_equal(getattr(batched, key), getattr(one_by_one, key))
    np.testing.assert_array_equal(np.stack(batched.percepts), np.stack(one_by_one.percepts))


def test_concatenated_databases_keep_each_interaction_linked_to_its_percepts():
    first, second = synthetic_chain(n=300, seed=1), synthetic_chain(n=200, seed=2)
    joined = InteractionDatabase.concat(first, second)
    assert len(joined) == 500 and len(joined.presence) == 1000
    for part, rows in ((first, slice(0, 300)), (second, slice(300, 500))):
        assert torch.equal(joined.presence[joined.obs[rows]], part.presence[part.obs])
        assert torch.equal(joined.presence[joined.next_obs[rows]], part.presence[part.next_obs])
        assert torch.equal(joined.actions[rows], part.actions)
    narrower = InteractionDatabase(
        first.presence[:, :5],
        first.obs,
        first.actions,
        first.rewards,
        first.next_obs,
        first.terminal,
    )
    with pytest.raises(ValueError, match="features"):
        InteractionDatabase.concat(first, narrower)


def test_a_database_holds_each_repeated_percept_once_and_learns_the_same_classes():
    # Percepts drawn from a bank of 40 distinct ones, so most of the 2,000 repeat.
    rng = np.random.default_rng(3)
    bank = rng.random((40, 12)) < 0.4
    bank[:, 0] = np.arange(40) % 2 == 0  # the feature that the TD errors follow
    obs, next_obs = rng.integers(0, 40, 1000), rng.integers(0, 40, 1000)
    percept = np.arange(2000)
    drawn = np.concatenate([obs, next_obs])
    db = InteractionDatabase(
        torch.from_numpy(bank[drawn]),
        torch.from_numpy(percept[:1000]),
        torch.from_numpy(rng.integers(0, 2, 1000)),
        torch.from_numpy(np.where(bank[next_obs, 0], 1.0, 0.0)),
        torch.from_numpy(percept[1000:]),
        torch.zeros(1000, dtype=torch.bool),
        positions=np.stack([drawn % 40, drawn % 40], axis=1).astype(float),
    )
    once = db.without_repeats()
    assert len(once.presence) == 40 and len(once) == len(db)
    in_order = drawn[np.sort(np.unique(drawn, return_index=True)[1])]  # by first appearance
    np.testing.assert_array_equal(once.counts, np.bincount(drawn)[in_order])
    for side in ("obs", "next_obs"):
        assert torch.equal(once.presence[getattr(once, side)], db.presence[getattr(db, side)])
        np.testing.assert_array_equal(
            once.positions[getattr(once, side)], db.positions[getattr(db, side)]
        )
    # First seen first: the first interaction's percept is percept 0.
    assert once.obs[0] == 0
    # The same classes, compacted and regrown too: compaction weighs a percept by its count.
    for compaction in (False, True):
        learned = [
            RLVC(12, 2, gamma=0.9, compaction=compaction).learn(d, progress=False)
            for d in (db, once)
        ]
        if compaction:
            learned = [rlvc.regrow(d) for rlvc, d in zip(learned, (db, once), strict=True)]
        assert learned[0].n_classes > 1
        assert learned[0].structure.state_dict() == learned[1].structure.state_dict()
    assert torch.equal(InteractionDatabase.from_state_dict(once.state_dict()).counts, once.counts)
    # Another position keeps a percept apart; a database that keeps occurrences is kept whole.
    db.positions[0] += 1.0
    assert len(db.without_repeats().presence) == 41
    image, feature = db.presence.nonzero()
    n = len(image)
    where = Occurrences(image.numpy(), feature.numpy(), np.zeros((n, 2)), np.ones(n), 2000)
    kept = replace(db, occurrences=where)
    assert kept.without_repeats() is kept


def test_parts_without_their_repeats_join_into_the_same_database():
    # What learn does to hold less: each part drops its repeats before the parts are joined.
    rng = np.random.default_rng(4)
    bank = rng.random((30, 10)) < 0.4

    def part(n: int) -> InteractionDatabase:
        seen = rng.integers(0, 30, 2 * n)
        return InteractionDatabase(
            torch.from_numpy(bank[seen]),
            torch.arange(n),
            torch.from_numpy(rng.integers(0, 2, n)),
            torch.from_numpy(rng.random(n)),
            torch.arange(n, 2 * n),
            torch.zeros(n, dtype=torch.bool),
            positions=np.stack([seen % 3, seen % 3], axis=1).astype(float),
        )

    parts = [part(n) for n in (300, 200, 100)]
    whole = InteractionDatabase.concat(*parts).without_repeats()
    first = InteractionDatabase.concat(*(p.without_repeats() for p in parts)).without_repeats()
    assert len(whole.presence) == 30
    assert torch.equal(first.presence.dense(), whole.presence.dense())
    for name in ("obs", "next_obs", "counts", "actions", "rewards"):
        assert torch.equal(getattr(first, name), getattr(whole, name))
    np.testing.assert_array_equal(first.positions, whole.positions)


def synthetic_chain(n_states: int = 6, n: int = 4000, seed: int = 0) -> InteractionDatabase:
    """A noisy chain whose state is shown by one of n_states features: RLVC must split
    the single initial class into the chain's states to act well."""
    rng = np.random.default_rng(seed)
    states = rng.integers(0, n_states, n)
    actions = rng.integers(0, 2, n)  # 0: left, 1: right
    nxt = np.clip(states + np.where(actions == 1, 1, -1), 0, n_states - 1)
    terminal = nxt == n_states - 1
    rewards = np.where(terminal, 10.0, 0.0)
    presence = np.zeros((2 * n, n_states + 20), bool)
    presence[np.arange(n), states] = True
    presence[n + np.arange(n), nxt] = True
    presence[:, n_states:] = rng.random((2 * n, 20)) < 0.5  # distractors
    return InteractionDatabase(
        torch.from_numpy(presence),
        torch.arange(n),
        torch.from_numpy(actions),
        torch.from_numpy(rewards),
        torch.arange(n, 2 * n),
        torch.from_numpy(terminal),
    )


def test_rlvc_learns_the_synthetic_chain_and_its_incremental_classes_match_the_tree():
    db = synthetic_chain()
    rlvc = RLVC(db.n_features, 2, gamma=0.9).learn(db, progress=False)
    assert rlvc.history[-1].splits == 0
    assert set(rlvc.structure.selected_features) <= set(range(6))  # no distractor selected
    chain = torch.eye(6 + 20, dtype=torch.bool)[:5]
    assert rlvc.greedy(chain).tolist() == [1, 1, 1, 1, 1]
    # Each stage's mean |TD| shrinks as aliasing is removed.
    assert rlvc.history[-1].mean_abs_td < 0.5 * rlvc.history[0].mean_abs_td


def test_min_effect_stops_the_splits_of_small_value_differences():
    # The chain's values grow towards its rewarding end; splits that tell its far states
    # apart show TD errors that differ by a small share of that range.
    db = synthetic_chain(n_states=20, n=8000)
    plain = RLVC(db.n_features, 2, gamma=0.9).learn(db, progress=False)
    coarse = RLVC(db.n_features, 2, gamma=0.9, min_effect=0.1).learn(db, progress=False)
    assert 1 < coarse.n_classes < plain.n_classes
    assert RLVC.from_state_dict(coarse.state_dict()).min_effect == 0.1
    with pytest.raises(ValueError, match="min_effect"):
        RLVC(db.n_features, 2, gamma=0.9, min_effect=1.0)


@pytest.mark.parametrize("max_stages", [2, 200])  # cut while splitting, and run to the end
def test_learned_q_is_solved_on_the_final_classes(max_stages):
    db = synthetic_chain(n=1000)
    rlvc = RLVC(db.n_features, 2, gamma=0.9).learn(db, max_stages=max_stages, progress=False)
    assert (rlvc.history[-1].splits > 0) == (max_stages == 2)
    classes = rlvc.structure.classify(db.presence)
    torch.testing.assert_close(rlvc.q, rlvc.solve(db, classes))


def test_a_later_learn_call_continues_and_on_stage_can_stop_it():
    db = synthetic_chain(n=1000)
    rlvc = RLVC(db.n_features, 2, gamma=0.9)
    seen = []
    for _ in range(2):  # as RLVCAgent continues on a later database, each call capped
        rlvc.learn(db, max_stages=2, on_stage=lambda r: seen.append(r.stage), progress=False)
    assert len(rlvc.history) == 4 and rlvc.history[-1].splits > 0  # cut while splitting
    assert seen == [0, 1, 2, 3]
    rlvc.learn(db, on_stage=lambda r: False, progress=False)  # False stops after one stage
    assert len(rlvc.history) == 5
    with pytest.raises(ValueError, match="max_stages"):
        rlvc.learn(db, max_stages=0, progress=False)
    classes = rlvc.structure.classify(db.presence)
    torch.testing.assert_close(rlvc.q, rlvc.solve(db, classes))


def test_rlvc_save_load_round_trip(tmp_path):
    db = synthetic_chain(n=1000)
    rlvc = RLVC(db.n_features, 2, gamma=0.9).learn(db, progress=False)
    rlvc.save(tmp_path / "rlvc.pt")
    loaded = RLVC.load(tmp_path / "rlvc.pt")
    assert torch.equal(loaded.structure.classify(db.presence), rlvc.structure.classify(db.presence))
    torch.testing.assert_close(loaded.q, rlvc.q)
    assert loaded.history == rlvc.history
