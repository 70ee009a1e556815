"""A vocabulary of prototype descriptors: what makes "feature f is present in image x" defined.

A visual feature is a prototype (a k-means centroid of descriptors seen in sample percepts); it
is present in a percept when one of the percept's descriptors is assigned to it (nearest
prototype, optionally within ``max_distance``).

Matching every descriptor against thousands of prototypes is the largest cost after SIFT. A
vocabulary fitted with ``groups`` is a two-level tree (hierarchical k-means, as in Nister and
Stewenius's vocabulary tree): prototypes are fitted within coarse groups of descriptors, and a
descriptor is compared with the coarse centres and then only with the prototypes of its
``probes`` nearest groups.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from vistask.checks import check_at_least, check_positive, checked
from vistask.features.compounds import Compound, Occurrences, add_compound_occurrences
from vistask.features.keypoints import Keypoints, SiftExtractor, extract_once
from vistask.kmeans import kmeans, nearest_centroids
from vistask.saving import load_state, save_state

SMALL_BATCH = 200  # descriptors: below, one product with every prototype beats the group loop
VOCABULARY_GROUPS = 64  # coarse groups of a vocabulary tree, unless told otherwise
CACHE_SIZE = 100_000  # distinct images whose words an extractor remembers, by default
# Descriptors matched at a time: a grouped search copies each descriptor once per probed group,
# so a first database's descriptors matched at once took hundreds of MB.
ASSIGN_CHUNK = 1 << 15


@dataclass
class CoarseGroups:
    """Prototypes grouped under coarse centres, searched group by group.

    Args:
        centres: (G, D) coarse centres.
        group_of: (F,) group of each prototype, non-decreasing: the prototypes are stored group
            by group (as ``grouped_kmeans`` makes them), so that a group's are one slice.
        probes: number of nearest groups whose prototypes a descriptor is compared with.
    """

    centres: torch.Tensor
    group_of: torch.Tensor
    probes: int = 3

    def __post_init__(self) -> None:
        if self.probes < 1:
            raise ValueError(f"probes must be >= 1, got {self.probes}")
        if bool((self.group_of[1:] < self.group_of[:-1]).any()):
            raise ValueError("group_of must be non-decreasing: store the prototypes group by group")
        self.probes = min(self.probes, len(self.centres))
        sizes = torch.bincount(self.group_of, minlength=len(self.centres))
        ends = sizes.cumsum(0)
        self.bounds = [0, *ends.tolist()]  # group g: prototypes bounds[g]:bounds[g + 1]
        # (G, largest group) prototype ids, -1 past a group's end.
        members = torch.arange(int(sizes.max()), device=sizes.device)
        self.padded = torch.where(members < sizes[:, None], (ends - sizes)[:, None] + members, -1)

    def nearest(
        self, x: torch.Tensor, centroids: torch.Tensor, k: int = 1, c_sq: torch.Tensor | None = None
    ):
        """K nearest prototypes of each row of x (M, D) among its probed groups, nearest
        first: (indices (M, k), squared distances (M, k)), like ``_nearest``; ``c_sq`` (F,)
        are the prototypes' squared norms when the caller has them."""
        if c_sq is None:
            c_sq = (centroids * centroids).sum(1)
        probed = nearest_centroids(x, self.centres, self.probes)[0]  # (M, P)
        if len(x) < SMALL_BATCH:
            return self._nearest_among_all(x, centroids, c_sq, probed, k)
        groups = probed.flatten()  # (M * P,) (row, probe) pairs
        # The pairs sorted by group: each group's rows are one slice, its prototypes another.
        order = torch.argsort(groups, stable=True)
        counts = torch.bincount(groups, minlength=len(self.centres)).tolist()
        rows = x[order // self.probes]
        found = torch.zeros(len(groups), k, dtype=torch.long, device=x.device)
        near = torch.full((len(groups), k), torch.inf, dtype=x.dtype, device=x.device)
        start = 0
        for g, n in enumerate(counts):
            lo, hi = self.bounds[g], self.bounds[g + 1]
            if n and hi > lo:
                end, kg = start + n, min(k, hi - lo)
                i, d = nearest_centroids(rows[start:end], centroids[lo:hi], kg, c_sq[lo:hi])
                found[start:end, :kg], near[start:end, :kg] = i + lo, d
            start += n
        # Back to (row, probe) order.
        index = torch.empty_like(found).index_copy_(0, order, found)
        dist = torch.empty_like(near).index_copy_(0, order, near)
        dist, best = dist.view(len(x), -1).topk(k, largest=False)
        return index.view(len(x), -1).gather(1, best), dist

    def _nearest_among_all(self, x, centroids, c_sq, probed, k):
        """The same search for a few descriptors (one percept, as a control loop has): one
        product with every prototype, then each row's probed groups, beats a loop over groups."""
        columns = self.padded[probed].flatten(1)  # (M, P * largest group)
        d = torch.addmm(c_sq, x, centroids.T, alpha=-2.0)
        d = d.gather(1, columns.clamp_min(0)).masked_fill_(columns < 0, torch.inf)
        if d.shape[1] < k:  # tiny vocabularies: fewer candidates than neighbours asked for
            d = torch.nn.functional.pad(d, (0, k - d.shape[1]), value=torch.inf)
            columns = torch.nn.functional.pad(columns, (0, k - columns.shape[1]), value=0)
        best, position = d.topk(k, largest=False)
        dist = (best + (x * x).sum(1, keepdim=True)).clamp_min_(0)
        return columns.gather(1, position).clamp_min_(0), dist


def grouped_kmeans(
    x: torch.Tensor, k: int, groups: int, iters: int = 20, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Two-level k-means: ``groups`` coarse centres, then k prototypes in all, fitted within
    each coarse group, as many as its share of the descriptors.

    Returns (prototypes (k, D), group of each prototype (k,), coarse centres (G, D)).
    """
    if len(x) < k:
        raise ValueError(f"k-means needs at least k={k} descriptors, got {len(x)}")
    centres = kmeans(x, min(groups, k), iters, seed)
    group = nearest_centroids(x, centres)[0][:, 0]
    sizes = torch.bincount(group, minlength=len(centres))
    share = sizes.double() * k / len(x)  # <= sizes, as k <= len(x)
    quota = share.floor().long()
    # The largest remainders take the words left (fewer than G; each such group has room).
    left = k - int(quota.sum())
    quota[torch.argsort(share - quota, descending=True, stable=True)[:left]] += 1
    prototypes, group_of = [], []
    for g in torch.nonzero(quota).flatten().tolist():
        prototypes.append(kmeans(x[group == g], int(quota[g]), iters, seed))
        group_of.append(torch.full((int(quota[g]),), g, dtype=torch.long))
    return torch.cat(prototypes), torch.cat(group_of), centres


def _assign(
    x: torch.Tensor,
    nearest: Callable[[torch.Tensor, int], tuple[torch.Tensor, torch.Tensor]],
    max_distance: float | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The word of each descriptor: its nearest prototype (none farther than ``max_distance``).
    ``nearest(x, k)`` gives the k nearest prototypes and their squared distances.

    Returns (descriptor index (P,), word (P,)) pairs, ordered by descriptor; x holds at least
    one descriptor.
    """
    rows, words = [], []
    for start in range(0, len(x), ASSIGN_CHUNK):
        index, dist = nearest(x[start : start + ASSIGN_CHUNK], 1)
        keep = torch.ones_like(dist, dtype=torch.bool)
        if max_distance is not None:
            keep &= dist <= max_distance**2
        row, column = keep.nonzero(as_tuple=True)
        rows.append(row + start)
        words.append(index[row, column])
    return torch.cat(rows), torch.cat(words)


@checked
class VisualFeatureExtractor:
    """Image -> set of visual features present (and where), through a learned vocabulary.

    Example:
        >>> extractor = VisualFeatureExtractor.fit(sample_images, n_words=2048)
        >>> presence = extractor.presence(images)   # (N, F) bool tensor
        >>> extractor.save("vocab.pt"); VisualFeatureExtractor.load("vocab.pt")
        >>> fast = VisualFeatureExtractor.fit(sample_images, n_words=8192, groups=64)

    Args:
        keypoints: the local-descriptor extractor.
        centroids: (F, D) prototype descriptors.
        groups: coarse groups of the prototypes (a vocabulary tree), searched instead of all
            prototypes (None: exact nearest prototype).
        max_distance: descriptors farther than this from every prototype are ignored (None: never).
        cache_size: ``occurrences`` (and so ``presence``) remembers the words, positions and
            scales of this many distinct images (0: none).
            Control loops see the same percept again and again (a blocked move leaves the
            view unchanged; evaluations replay the same starts), and extraction is the
            dominant cost.
        image_shape: the shape of the images it was fitted on, which the wrappers check an
            env's observations against (None: not known).
        env_id: the id of the registered env whose images it was fitted on; the wrappers warn
            when they wrap another (None: not known).
    """

    def __init__(
        self,
        keypoints: SiftExtractor,
        centroids: torch.Tensor,
        max_distance: float | None = None,
        cache_size: int = CACHE_SIZE,
        groups: CoarseGroups | None = None,
        image_shape: tuple[int, ...] | None = None,
        env_id: str | None = None,
    ) -> None:
        if centroids.ndim != 2 or centroids.shape[1] != keypoints.descriptor_size:
            raise ValueError(
                f"centroids must be (F, {keypoints.descriptor_size}), got {tuple(centroids.shape)}"
            )
        if groups is not None and groups.group_of.shape != (len(centroids),):
            raise ValueError(
                f"groups must give the group of each of the {len(centroids)} prototypes, "
                f"got group_of of shape {tuple(groups.group_of.shape)}"
            )
        self.keypoints = keypoints
        self.centroids = centroids.float().contiguous()
        # Every match needs the prototypes' squared norms; they are fixed, so computed once.
        self._centroid_sq = (self.centroids * self.centroids).sum(1)
        self.groups = groups
        self._group_of = None if groups is None else groups.group_of.cpu().numpy()
        if max_distance is not None:
            check_positive(max_distance=max_distance)
        check_at_least(0, cache_size=cache_size)
        self.max_distance = max_distance
        self.cache_size = cache_size
        self.image_shape = None if image_shape is None else tuple(int(n) for n in image_shape)
        self.env_id = env_id
        self._cache: dict[tuple, tuple] = {}  # image digest -> (words, xy, scale)

    def __getstate__(self) -> dict:
        # Pickled copies (subprocess vector envs) start with an empty cache.
        return {**self.__dict__, "_cache": {}}

    def check_env(self, env: gym.Env, user: str) -> None:
        """Raise ValueError, naming ``user``, where ``env``'s observations are images of another
        shape than the vocabulary was fitted on; warn where ``env`` is another registered env."""
        self.check_shape(getattr(env.observation_space, "shape", None) or (), user)
        env_id = getattr(env.spec, "id", None)
        if None not in (self.env_id, env_id) and env_id != self.env_id:
            warnings.warn(
                f"{user}: the vocabulary was learned on {self.env_id}'s images and wraps "
                f"{env_id}: what it learned may not mean the same here",
                stacklevel=3,
            )

    def check_shape(
        self, shape: Sequence[int], user: str, images: str = "this env's observations"
    ) -> None:
        """Raise ValueError, naming ``user`` and the ``images``, where ``shape`` is not the shape
        of the images the vocabulary was fitted on (nothing where that is not known)."""
        shape = tuple(shape)
        if self.image_shape is not None and shape != self.image_shape:
            raise ValueError(
                f"{user}: the vocabulary was learned on images of shape {self.image_shape}; "
                f"{images} are {shape}"
            )

    @property
    def n_features(self) -> int:
        """Number of visual features (the vocabulary's words; compounds come after them)."""
        return len(self.centroids)

    @property
    def fingerprint(self) -> str:
        """Short hash of the vocabulary and extractor settings (checked when loading trees)."""
        h = hashlib.sha1(self.centroids.cpu().numpy().tobytes())
        h.update(repr(sorted(self.keypoints.config().items())).encode())
        h.update(repr(self.max_distance).encode())
        if self.groups is not None:
            h.update(self.groups.group_of.cpu().numpy().tobytes())
            h.update(self.groups.centres.cpu().numpy().tobytes())
            h.update(repr(self.groups.probes).encode())
        return h.hexdigest()[:16]

    @classmethod
    def fit(
        cls,
        images: Sequence[np.ndarray] | None = None,
        n_words: int = 2048,
        keypoints: SiftExtractor | None = None,
        detected: Sequence[Keypoints] | None = None,
        max_descriptors: int = 60_000,
        iters: int = 15,
        max_distance: float | None = None,
        groups: int = VOCABULARY_GROUPS,
        probes: int = 3,
        seed: int = 0,
        image_shape: tuple[int, ...] | None = None,
        env_id: str | None = None,
    ) -> VisualFeatureExtractor:
        """Learn the vocabulary by k-means over descriptors of sample percepts.

        Args:
            images: sample percepts (or pass ``detected`` when keypoints are already extracted).
            n_words: vocabulary size F (number of visual features).
            keypoints: descriptor extractor (default ``SiftExtractor()``).
            detected: keypoints already extracted from the sample percepts.
            max_descriptors: random subset of descriptors used by k-means (speed).
            iters: k-means iterations.
            max_distance: see the class.
            groups: fit a two-level vocabulary with this many coarse groups (at most n_words
                are used; 0: flat k-means, exact matching); with 8192 words, 64 groups and 3
                probes match several times faster, and fit much faster
                (``scripts/bench_features.py``).
            probes: groups searched per descriptor (with ``groups``); one probe misses the
                nearest prototype of descriptors near a group border.
            seed: seed of the subset and of the k-means initialisation.
            image_shape: see the class (default: the shape of ``images``' first).
            env_id: see the class.
        """
        check_at_least(2, n_words=n_words)  # one word is present in every percept
        check_at_least(1, max_descriptors=max_descriptors, iters=iters, probes=probes)
        check_at_least(0, groups=groups, seed=seed)
        if max_distance is not None:
            check_positive(max_distance=max_distance)
        keypoints = keypoints or SiftExtractor()
        if detected is None:
            if not images:
                raise ValueError("fit needs sample images or already detected keypoints")
            detected = keypoints.batch(images)
        descriptors = [k.descriptors for k in detected if len(k)]
        if not descriptors:
            raise ValueError("no keypoints found in the sample percepts: cannot learn a vocabulary")
        x = torch.from_numpy(np.concatenate(descriptors))
        if len(x) > max_descriptors:
            generator = torch.Generator().manual_seed(seed)
            x = x[torch.randperm(len(x), generator=generator)[:max_descriptors]]
        if len(x) < n_words:
            raise ValueError(
                f"only {len(x)} descriptors in the sample percepts for {n_words} words: "
                "use more sample percepts or fewer words"
            )
        if image_shape is None and images:
            image_shape = np.shape(images[0])
        if groups <= 0:
            centroids = kmeans(x, n_words, iters, seed)
            coarse = None
        else:
            centroids, group_of, centres = grouped_kmeans(x, n_words, groups, iters, seed)
            coarse = CoarseGroups(centres, group_of, probes)
        return cls(
            keypoints,
            centroids,
            max_distance,
            groups=coarse,
            image_shape=image_shape,
            env_id=env_id,
        )

    def nearest(self, x: torch.Tensor, k: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
        """K nearest prototypes of descriptors x (M, D): (indices (M, k), squared distances)."""
        k = min(k, self.n_features)
        if self.groups is None:
            return nearest_centroids(x, self.centroids, k, self._centroid_sq)
        return self.groups.nearest(x, self.centroids, k, self._centroid_sq)

    def words(self, detected: Sequence[Keypoints]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per image, (keypoint index (P,), feature id (P,)) pairs: every keypoint's words."""
        sizes = np.array([len(k) for k in detected])
        if sizes.sum() == 0:
            return [(np.zeros(0, np.int64), np.zeros(0, np.int64)) for _ in detected]
        x = torch.from_numpy(np.concatenate([k.descriptors for k in detected]))
        rows, words = _assign(x, self.nearest, self.max_distance)
        image = np.repeat(np.arange(len(detected)), sizes)[rows.numpy()]
        local = rows.numpy() - (np.cumsum(sizes) - sizes)[image]
        bounds = np.searchsorted(image, np.arange(1, len(detected)))
        return list(zip(np.split(local, bounds), np.split(words.numpy(), bounds), strict=True))

    def occurrences_of(
        self, detected: Sequence[Keypoints], compounds: Sequence[Compound] = ()
    ) -> Occurrences:
        """Where each word (and compound) occurs in images whose keypoints are already
        extracted (see ``occurrences``)."""
        words = self._table(self._per_image(detected))
        return add_compound_occurrences(words, list(compounds), self.n_features)

    def _per_image(self, detected: Sequence[Keypoints]) -> list[tuple]:
        """Per image, the (words, xy, scale) of its keypoints that have a word."""
        return [
            (w.astype(np.int32), k.xy[i], k.scale[i])
            for k, (i, w) in zip(detected, self.words(detected), strict=True)
        ]

    def _table(self, per_image: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> Occurrences:
        """One ``Occurrences`` table from per-image (words, xy, scale); a word's compound
        part is its coarse group (the word itself in a flat vocabulary)."""
        sizes = [len(words) for words, _, _ in per_image]
        words = np.concatenate([np.zeros(0, np.int64)] + [w for w, _, _ in per_image])
        return Occurrences(
            np.repeat(np.arange(len(per_image)), sizes),
            words,
            np.concatenate([np.zeros((0, 2), np.float32)] + [xy for _, xy, _ in per_image]),
            np.concatenate([np.zeros(0, np.float32)] + [s for _, _, s in per_image]),
            len(per_image),
            words if self.groups is None else self._group_of[words],
        )

    def occurrences(
        self, images: Sequence[np.ndarray], compounds: Sequence[Compound] = ()
    ) -> Occurrences:
        """Where each word occurs in each image (keypoint position and scale), and each of
        ``compounds``, compound c as feature ``n_features + c``.

        Each distinct image is extracted once: repeats, within the batch or cached from
        earlier calls, are looked up by a digest of their pixels.
        """
        rows = extract_once(
            self._cache,
            images,
            lambda todo: self._per_image(self.keypoints.batch(todo)),
            self.cache_size,
        )
        return add_compound_occurrences(self._table(rows), list(compounds), self.n_features)

    def presence_of(
        self, detected: Sequence[Keypoints], compounds: Sequence[Compound] = ()
    ) -> torch.Tensor:
        """(N, F + C) bool presence matrix of already extracted keypoints."""
        return self.occurrences_of(detected, compounds).presence(self.n_features + len(compounds))

    def presence(
        self, images: Sequence[np.ndarray], compounds: Sequence[Compound] = ()
    ) -> torch.Tensor:
        """(N, F + C) bool: feature f present in image i, words then ``compounds``. Images are
        (H, W, 3) uint8 (see ``occurrences``)."""
        return self.occurrences(images, compounds).presence(self.n_features + len(compounds))

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """(F,) int8 presence vector of one image (the ``MultiBinary`` observation)."""
        return self.presence([image])[0].numpy().astype(np.int8)

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "keypoints": self.keypoints.config(),
            "centroids": self.centroids.cpu(),
            "max_distance": self.max_distance,
            "groups": None
            if self.groups is None
            else {
                "centres": self.groups.centres.cpu(),
                "group_of": self.groups.group_of.cpu(),
                "probes": self.groups.probes,
            },
            "image_shape": self.image_shape,
            "env_id": self.env_id,
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> VisualFeatureExtractor:
        """The object that ``state_dict`` described."""
        return cls(
            SiftExtractor(**state["keypoints"]),
            state["centroids"],
            state["max_distance"],
            groups=CoarseGroups(**state["groups"]) if state.get("groups") else None,
            image_shape=state.get("image_shape"),
            env_id=state.get("env_id"),
        )

    def save(self, path: str | Path) -> None:
        """Write it to ``path``; ``load`` reads it back."""
        save_state(path, "VisualFeatureExtractor", self.state_dict())

    @classmethod
    def load(cls, path: str | Path) -> VisualFeatureExtractor:
        """Read what ``save`` wrote to ``path``."""
        return cls.from_state_dict(load_state(path, "VisualFeatureExtractor"))
