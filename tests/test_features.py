"""Visual features: SIFT keypoints, the k-means vocabulary, presence, determinism, round trip."""

import os
import pickle

import cv2
import gymnasium as gym
import numpy as np
import pytest
import torch

from vistask.envs import VisualMazeEnv
from vistask.experiments.bench_keypoints import bench_keypoints, stay_put
from vistask.features import SiftExtractor, VisualFeatureExtractor, choose_enlarge
from vistask.features.keypoints import SUPPORT_RADIUS
from vistask.features.vocabulary import SMALL_BATCH, CoarseGroups, grouped_kmeans
from vistask.kmeans import kmeans
from vistask.rlvc import collect


@pytest.fixture(scope="module")
def percepts() -> list[np.ndarray]:
    env = VisualMazeEnv()
    positions = env.geometry.sample_free(np.random.default_rng(0), 120)
    return [env.percept_at(p) for p in positions]


@pytest.fixture(scope="module")
def extractor(percepts) -> VisualFeatureExtractor:
    return VisualFeatureExtractor.fit(percepts, n_words=256, iters=5, groups=0)


def test_sift_finds_keypoints_inside_the_image(percepts):
    kps = SiftExtractor()(percepts[0])
    assert len(kps) > 5
    assert kps.descriptors.shape == (len(kps), 128) and kps.descriptors.dtype == np.float32
    assert ((kps.xy >= 0) & (kps.xy < 64)).all()


def test_color_descriptors_append_chromaticity(percepts):
    kps = SiftExtractor(color_weight=0.5)(percepts[0])
    assert kps.descriptors.shape[1] == 130
    grey = SiftExtractor()(percepts[0])
    np.testing.assert_array_equal(kps.descriptors[:, :128], grey.descriptors)


def test_batch_extraction_equals_one_by_one(percepts):
    extractor = SiftExtractor(threads=2)
    images = percepts[:41]  # the threads take one image at a time, in either order
    opencv_threads = cv2.getNumThreads()
    batch = extractor.batch(images)
    assert cv2.getNumThreads() == opencv_threads  # OpenCV's threads are back after the pool
    for image, kps in zip(images, batch, strict=True):
        single = extractor(image)
        np.testing.assert_array_equal(single.descriptors, kps.descriptors)
    # The pool is kept for the next batch, and left out of pickles (subprocess vector envs).
    again = pickle.loads(pickle.dumps(extractor)).batch(images[::-1])
    for kps, other in zip(batch, reversed(again), strict=True):
        np.testing.assert_array_equal(kps.xy, other.xy)
        np.testing.assert_array_equal(kps.descriptors, other.descriptors)


def test_an_enlarged_small_view_shows_keypoints_that_stay_put_as_it_moves(percepts):
    enlarged = SiftExtractor(0.005, 24, threads=1, enlarge=2)
    tapestry = VisualMazeEnv().tapestry
    staying = [
        stay_put(e, tapestry, window=32, views=30, shift=4, seed=0)["stay_put_per_view"]
        for e in (SiftExtractor(0.005, 24, threads=1), enlarged)
    ]
    assert staying[1] > 2 * staying[0]
    for percept in percepts[:20]:  # every descriptor lies inside the view
        kps = enlarged(percept)
        room = np.minimum(kps.xy, 64 - kps.xy).min(axis=1)
        assert 0 < len(kps) <= 24 and (room >= SUPPORT_RADIUS * kps.scale).all()
    strongest = SiftExtractor(0.005, 0, enlarge=2)(percepts[0])
    assert len(strongest) > 24 and len(enlarged(percepts[0])) == 24
    with pytest.raises(ValueError, match="enlarge"):
        SiftExtractor(enlarge=0)
    with pytest.raises(TypeError, match="enlarge"):
        SiftExtractor(enlarge=1.5)


def test_auto_enlarges_small_photo_views_but_not_smooth_rendered_ones():
    def views(env_id: str, **kwargs) -> list[np.ndarray]:
        return collect(gym.make(env_id, **kwargs), 300, seed=0).percepts

    assert choose_enlarge(views("vistask/VisualMaze-v0", window=32), 0.005, 24) == 2
    # Place navigation's rendered rooms show fewer keypoints enlarged at its threshold.
    small_rooms = views("vistask/PlaceNavigation-v0", image_size=32, views_per_state=2)
    assert choose_enlarge(small_rooms, 0.02, 24) == 1
    assert choose_enlarge(views("vistask/VisualMaze-v0", window=48), 0.005, 24) == 2
    # Views of 56 pixels or more, or of a panel that wide, are taken as they are.
    assert choose_enlarge(views("vistask/VisualMaze-v0", window=56), 0.005, 24) == 1
    car = gym.make("vistask/VisualMountainCar-v0")
    panels = car.unwrapped.panel_widths  # the road and the gauge, 96 pixels each
    assert choose_enlarge(collect(car, 300, seed=0).percepts, 0.005, 24, panels) == 1


def test_bench_keypoints_writes_its_table_and_plot(tmp_path):
    summary = bench_keypoints((32,), (1, 2), views=10, out=tmp_path)
    assert (tmp_path / "summary.json").exists() and (tmp_path / "stay_put.png").exists()
    figures = summary["32"]
    assert figures["2"]["stay_put_per_view"] > figures["1"]["stay_put_per_view"]
    assert 0 <= figures["1"]["stay_put_share"] <= 1


def test_extraction_threads_follow_the_cpus_ray_gives_a_task(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # what Ray sets in a task of one CPU
    assert SiftExtractor().threads == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "")
    assert SiftExtractor().threads == os.cpu_count()
    assert SiftExtractor(threads=3).threads == 3


def sift_alone(view: np.ndarray, left: int) -> list[tuple]:
    """Brute force: (response, x, y, descriptor) of every keypoint of a view alone, x in the
    percept."""
    grey = cv2.cvtColor(view, cv2.COLOR_RGB2GRAY)
    points, descriptors = cv2.SIFT_create(contrastThreshold=0.02).detectAndCompute(grey, None)
    x = [np.float32(p.pt[0]) + np.float32(left) for p in points]  # float32, as the extractor's
    return [(p.response, x, p.pt[1], d) for p, x, d in zip(points, x, descriptors, strict=True)]


class CountingViews(SiftExtractor):
    """Counts the views it runs SIFT on."""

    detected = 0

    def _detect(self, image):
        self.detected += 1
        return super()._detect(image)


def test_views_side_by_side_are_extracted_alone_once_each_and_the_strongest_kept(percepts):
    lefts, rights = percepts[:3], percepts[3:5]
    images = [np.hstack([lefts[i % 3], rights[i % 2]]) for i in range(6)]  # (64, 128, 3)
    extractor = CountingViews(max_keypoints=10, threads=2, panel_widths=(64, 64))
    batch = extractor.batch(images)
    assert extractor.detected == 5  # three left views, two right ones
    for i, kps in enumerate(batch):
        alone = sift_alone(lefts[i % 3], 0) + sift_alone(rights[i % 2], 64)
        strongest = sorted(alone, key=lambda k: -k[0])[:10]
        # OpenCV orders keypoints of equal response freely: compared as sets.
        expected = {(round(float(x), 3), round(y, 3), d.tobytes()) for _, x, y, d in strongest}
        found = zip(kps.xy.astype(float).round(3).tolist(), kps.descriptors, strict=True)
        assert {(x, y, d.tobytes()) for (x, y), d in found} == expected
    assert (batch[0].xy[:, 0] >= 64).any() and (batch[0].xy[:, 0] < 64).any()
    again = [*extractor.batch(images[::-1]), extractor(images[1])]
    assert extractor.detected == 5  # every view came from the cache
    for kps, other in zip([*batch[::-1], batch[1]], again, strict=True):
        np.testing.assert_array_equal(kps.descriptors, other.descriptors)
    assert pickle.loads(pickle.dumps(extractor))._views == {}
    with pytest.raises(ValueError, match="add up to 128 pixels, but the image is 64 wide"):
        extractor(percepts[0])


def test_the_same_image_always_gives_the_same_features(extractor, percepts):
    first = extractor.presence(percepts)
    again = extractor.presence(list(reversed(percepts)))
    assert torch.equal(first, again.flip(0))
    one = torch.stack([torch.from_numpy(extractor(p)).bool() for p in percepts[:10]])
    assert torch.equal(one, first[:10])


class CountingSift(SiftExtractor):
    """Records the batch sizes it extracts."""

    def batch(self, images):
        self.calls = [*getattr(self, "calls", []), len(images)]
        return super().batch(images)


def test_repeated_percepts_are_extracted_once_and_give_the_same_features(extractor, percepts):
    cold = VisualFeatureExtractor(extractor.keypoints, extractor.centroids, cache_size=0)
    fresh = cold.presence_of(cold.keypoints.batch(percepts[:20]))
    counting = CountingSift(**extractor.keypoints.config())
    warm = VisualFeatureExtractor(counting, extractor.centroids)
    repeated = percepts[:20] + [p.copy() for p in percepts[:5]]  # equal pixels, new arrays
    assert torch.equal(warm.presence(repeated), torch.cat([fresh, fresh[:5]]))
    assert torch.equal(warm.presence(percepts[:10]), fresh[:10])
    assert counting.calls == [20]  # the repeats and the second call came from the cache
    assert torch.equal(cold.presence(percepts[:20]), fresh)
    copy = pickle.loads(pickle.dumps(warm))  # e.g. into a subprocess vector env
    assert copy._cache == {} and torch.equal(copy.presence(percepts[:3]), fresh[:3])


def test_a_batch_that_fills_the_cache_keeps_its_cached_percepts(extractor, percepts):
    fresh = extractor.presence_of(extractor.keypoints.batch(percepts[:30]))
    small = VisualFeatureExtractor(extractor.keypoints, extractor.centroids, cache_size=20)
    small.presence(percepts[:15])  # cached
    # 15 cached and 15 new percepts overflow the cache of 20: the cached ones still count.
    assert torch.equal(small.presence(percepts[:30]), fresh)
    assert torch.equal(small.presence(percepts[:30]), fresh)


def test_presence_is_a_bool_matrix_over_the_vocabulary(extractor, percepts):
    presence = extractor.presence(percepts)
    assert presence.shape == (len(percepts), 256) and presence.dtype == torch.bool
    assert presence.sum(1).float().mean() > 10  # dozens of features per percept
    assert presence.any(0).sum() > 200  # most prototypes describe some percept


def test_nearby_percepts_share_more_features_than_distant_ones(extractor):
    env = VisualMazeEnv()
    a = extractor.presence([env.percept_at((0.5, 0.2))])[0]
    near = extractor.presence([env.percept_at((0.51, 0.2))])[0]
    far = extractor.presence([env.percept_at((0.1, 0.9))])[0]
    assert (a & near).sum() > 3 * (a & far).sum()


def test_vocabulary_round_trip(tmp_path, extractor, percepts):
    extractor.save(tmp_path / "vocab.pt")
    loaded = VisualFeatureExtractor.load(tmp_path / "vocab.pt")
    assert loaded.fingerprint == extractor.fingerprint
    assert torch.equal(loaded.presence(percepts), extractor.presence(percepts))


def test_words_are_the_nearest_prototypes_within_max_distance(extractor, percepts):
    detected = extractor.keypoints.batch(percepts[:20])
    x = torch.from_numpy(np.concatenate([k.descriptors for k in detected]))
    distance, nearest = torch.cdist(x, extractor.centroids).min(1)
    words = np.concatenate([w for _, w in extractor.words(detected)])
    assert np.array_equal(words, nearest.numpy())
    # Many prototypes make many row blocks; a threshold (between two descriptors' distances,
    # clear of rounding) drops the far descriptors.
    middle = distance.sort().values[len(distance) // 2 : len(distance) // 2 + 2]
    threshold = float(middle.mean())
    wide = VisualFeatureExtractor(
        extractor.keypoints, extractor.centroids.repeat(40, 1), max_distance=threshold
    )
    near = distance <= threshold
    kept = np.concatenate([w for _, w in wide.words(detected)])
    assert len(kept) == int(near.sum()) < len(x)
    assert np.array_equal(kept % len(extractor.centroids), nearest[near].numpy())


@pytest.fixture(scope="module")
def grouped(percepts) -> VisualFeatureExtractor:
    return VisualFeatureExtractor.fit(percepts, n_words=256, iters=5, groups=8, probes=2)


def descriptors_of(extractor, percepts) -> torch.Tensor:
    return torch.from_numpy(
        np.concatenate([k.descriptors for k in extractor.keypoints.batch(percepts)])
    )


def test_grouped_vocabulary_probing_every_group_is_exact(grouped, percepts):
    x = descriptors_of(grouped, percepts[:30])
    exact = torch.cdist(x, grouped.centroids).argmin(1)
    every = CoarseGroups(grouped.groups.centres, grouped.groups.group_of, probes=8)
    assert torch.equal(every.nearest(x, grouped.centroids)[0][:, 0], exact)
    # Two probes of eight groups: the nearest prototype of most, not all, descriptors.
    agree = (grouped.nearest(x)[0][:, 0] == exact).float().mean()
    assert 0.85 < agree < 1
    one = CoarseGroups(grouped.groups.centres, grouped.groups.group_of, probes=1)
    assert (one.nearest(x, grouped.centroids)[0][:, 0] == exact).float().mean() < agree
    # A few descriptors (one percept) take another path to the same words, nearest or soft.
    assert len(x) > SMALL_BATCH > 40
    for k in (1, 3):
        pieces = [grouped.nearest(x[s : s + 40], k)[0] for s in range(0, len(x), 40)]
        assert torch.equal(torch.cat(pieces), grouped.nearest(x, k)[0])


def test_grouped_kmeans_shares_the_words_by_descriptor_count():
    rng = np.random.default_rng(0)
    # Three blobs of 600, 300 and 100 points: 20 words split about 12 / 6 / 2.
    blobs = [rng.normal(centre, 1.0, (n, 4)) for centre, n in ((0, 600), (20, 300), (-20, 100))]
    x = torch.from_numpy(np.concatenate(blobs)).float()
    prototypes, group_of, centres = grouped_kmeans(x, 20, groups=3, iters=10)
    assert prototypes.shape == (20, 4) and len(centres) == 3
    assert sorted(torch.bincount(group_of).tolist()) == [2, 6, 12]
    # Every prototype lies in its group's blob.
    owner = torch.cdist(prototypes, centres).argmin(1)
    assert torch.equal(owner, group_of)


def test_grouped_vocabulary_round_trip_and_errors(tmp_path, grouped, percepts):
    grouped.save(tmp_path / "vocab.pt")
    loaded = VisualFeatureExtractor.load(tmp_path / "vocab.pt")
    assert loaded.fingerprint == grouped.fingerprint and loaded.groups.probes == 2
    assert torch.equal(loaded.presence(percepts), grouped.presence(percepts))
    flat = VisualFeatureExtractor(grouped.keypoints, grouped.centroids)
    assert flat.fingerprint != grouped.fingerprint
    with pytest.raises(ValueError, match="group of each"):
        VisualFeatureExtractor(grouped.keypoints, grouped.centroids[:100], groups=grouped.groups)
    with pytest.raises(ValueError, match="probes"):
        CoarseGroups(grouped.groups.centres, grouped.groups.group_of, probes=0)
    with pytest.raises(ValueError, match="group by group"):
        CoarseGroups(grouped.groups.centres, grouped.groups.group_of.flip(0))


def test_kmeans_converges_to_a_fixed_point_with_lower_error():
    rng = np.random.default_rng(0)
    centres = rng.normal(0, 10, (8, 8))
    x = torch.from_numpy(np.repeat(centres, 100, axis=0) + rng.normal(0, 0.5, (800, 8))).float()

    def sse(c):
        return torch.cdist(x, c).min(1).values.pow(2).sum()

    start = kmeans(x, 8, iters=0, seed=1)
    found = kmeans(x, 8, iters=30, seed=1)
    assert sse(found) < 0.9 * sse(start)
    nearest = torch.cdist(x, found).argmin(1)
    for k in range(8):  # every centroid is the mean of the points it owns
        torch.testing.assert_close(found[k], x[nearest == k].mean(0), rtol=0, atol=1e-4)
    assert torch.equal(kmeans(x, 8, iters=5, seed=3), kmeans(x, 8, iters=5, seed=3))


def test_clear_errors_for_bad_input(extractor):
    with pytest.raises(TypeError, match="uint8"):
        extractor(np.zeros((64, 64, 3), np.float32))
    with pytest.raises(ValueError, match="RGB"):
        extractor(np.zeros((64, 64, 4), np.uint8))
    with pytest.raises(ValueError, match="no keypoints"):
        VisualFeatureExtractor.fit([np.zeros((64, 64, 3), np.uint8)] * 3, n_words=4)
    with pytest.raises(ValueError, match="fewer words"):
        VisualFeatureExtractor.fit([np.zeros((64, 64, 3), np.uint8), image_with_corners()], 500)


def image_with_corners() -> np.ndarray:
    image = np.zeros((64, 64, 3), np.uint8)
    image[16:48, 16:48] = 255
    return image
