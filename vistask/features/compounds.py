"""Compound visual features (paper section 2.5.1): pairs of features in a stable spatial relation.

A local feature tells *what* is in a percept, not *where* it is relative to something else: the
velocity shown by a gauge's needle is in the relation between the needle's tip and the dial's
numerals, not in either. A compound ``(first, second, offset, tolerance)`` is present in an
image when some occurrence of part ``second`` lies at ``offset`` from some occurrence of part
``first``, within ``tolerance``; both are in units of the first occurrence's scale, so the
relation holds at any image scale. A compound occurs at the midpoint of the matching pair, with
the mean of their scales, so compounds can be paired again (a hierarchy of compounds).

The parts of a compound are coarser than words. A fine vocabulary (8192 words) spreads the
keypoints of one small object over hundreds of words (the car gauge's needle tip: 628 words in
2000 percepts, but 5 coarse groups hold 90% of it), so that a relation between two words recurs
too rarely to be found; the relation itself, tight in position, is what makes a compound
selective. A word's part is its coarse group in the vocabulary tree (the word itself in a flat
vocabulary); a compound's part is its own feature id (ids above every group's, so both share
one space).

Occurrences of all features of a set of images are one flat table (``Occurrences``), sorted by
image; pairs within an image are enumerated with a sort and a ``searchsorted``, never a loop
over images.

Example:
    >>> occ = extractor.occurrences(images)               # words, where they occur
    >>> candidates = propose(occ, tolerances=(1.0, 2.0), min_count=10)
    >>> occ = add_compound_occurrences(occ, candidates[:1], first_id=extractor.n_features)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from vistask.checks import checked

# Pairs farther apart than this many scales of their first part are not related (the bins of
# ``propose`` pack into one int64 key).
MAX_REACH = 256


@checked
@dataclass
class Occurrences:
    """Where features occur in ``n_images`` images: occurrence k is feature ``feature[k]`` (of
    compound part ``part[k]``) at pixel ``xy[k]`` with keypoint scale ``scale[k]`` in image
    ``image[k]``; sorted by image.

    24 bytes per occurrence: 30,000 percepts of 24 keypoints take 17 MB.

    Attributes:
        image: (P,) int32. feature: (P,) int32. xy: (P, 2) float32. scale: (P,) float32.
        n_images: number of images (some may have no occurrence).
        part: (P,) int32 compound part of each occurrence (default: its feature).
    """

    image: np.ndarray
    feature: np.ndarray
    xy: np.ndarray
    scale: np.ndarray
    n_images: int
    part: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.image = np.asarray(self.image, np.int32)
        self.feature = np.asarray(self.feature, np.int32)
        self.part = np.asarray(self.feature if self.part is None else self.part, np.int32)
        self.xy = np.asarray(self.xy, np.float32).reshape(-1, 2)
        self.scale = np.asarray(self.scale, np.float32)
        n = len(self.image)
        if not (len(self.feature) == len(self.xy) == len(self.scale) == len(self.part) == n):
            raise ValueError("image, feature, xy, scale and part need one entry per occurrence")
        if n and (np.any(np.diff(self.image) < 0) or self.image[-1] >= self.n_images):
            raise ValueError(f"image ids must be sorted and below n_images={self.n_images}")

    def __len__(self) -> int:
        return len(self.image)

    @classmethod
    def concat(cls, parts: list[Occurrences]) -> Occurrences:
        """The images of ``parts`` one after the other (image ids shifted)."""
        offsets = np.cumsum([0] + [p.n_images for p in parts])
        return cls(
            np.concatenate(
                [np.zeros(0, np.int32)]
                + [p.image + o for p, o in zip(parts, offsets[:-1], strict=True)]
            ),
            np.concatenate([np.zeros(0, np.int32)] + [p.feature for p in parts]),
            np.concatenate([np.zeros((0, 2), np.float32)] + [p.xy for p in parts]),
            np.concatenate([np.zeros(0, np.float32)] + [p.scale for p in parts]),
            int(offsets[-1]),
            np.concatenate([np.zeros(0, np.int32)] + [p.part for p in parts]),
        )

    def take(self, keep: np.ndarray) -> Occurrences:
        """The occurrences where the (P,) bool ``keep`` holds, or at the sorted indices
        ``keep`` (same images)."""
        return Occurrences(
            self.image[keep],
            self.feature[keep],
            self.xy[keep],
            self.scale[keep],
            self.n_images,
            self.part[keep],
        )

    def select(self, images: np.ndarray) -> Occurrences:
        """Occurrences of the sorted distinct ``images``, renumbered 0..len(images)-1."""
        images = np.asarray(images)
        lo = np.searchsorted(self.image, images, "left")
        count = np.searchsorted(self.image, images, "right") - lo
        index = concatenated_ranges(lo, count)
        return Occurrences(
            np.repeat(np.arange(len(images), dtype=np.int32), count),
            self.feature[index],
            self.xy[index],
            self.scale[index],
            len(images),
            self.part[index],
        )

    def merge(self, *others: Occurrences) -> Occurrences:
        """The tables' occurrences in the same images, sorted by image (stable: of an image,
        this table's occurrences come first, then each other's in order)."""
        if not others:
            return self
        tables = (self, *others)
        if any(other.n_images != self.n_images for other in others):
            sizes = [t.n_images for t in tables]
            raise ValueError(f"cannot merge occurrences of different images: {sizes} images")
        image = np.concatenate([t.image for t in tables])
        order = np.argsort(image, kind="stable")
        return Occurrences(
            image[order],
            np.concatenate([t.feature for t in tables])[order],
            np.concatenate([t.xy for t in tables])[order],
            np.concatenate([t.scale for t in tables])[order],
            self.n_images,
            np.concatenate([t.part for t in tables])[order],
        )

    def presence(self, n_features: int) -> torch.Tensor:
        """(n_images, n_features) bool: feature f occurs in image i."""
        if len(self) and int(self.feature.max()) >= n_features:
            raise ValueError(f"feature ids reach {self.feature.max()}, above n_features")
        presence = torch.zeros(self.n_images, n_features, dtype=torch.bool)
        presence[torch.from_numpy(self.image).long(), torch.from_numpy(self.feature).long()] = True
        return presence


@checked
@dataclass(frozen=True)
class Compound:
    """Part ``second`` at ``offset`` (dx, dy) from part ``first``, within ``tolerance``; offset
    and tolerance in units of the ``first`` occurrence's scale (parts: see the module)."""

    first: int
    second: int
    offset: tuple[float, float]
    tolerance: float

    def as_list(self) -> list:
        """The compound as plain values (for saved files)."""
        return [self.first, self.second, list(self.offset), self.tolerance]

    @classmethod
    def from_list(cls, values: list) -> Compound:
        """The compound that ``as_list`` gave."""
        first, second, offset, tolerance = values
        return cls(int(first), int(second), (float(offset[0]), float(offset[1])), float(tolerance))


def concatenated_ranges(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The ranges ``start[k] .. start[k] + count[k] - 1`` one after the other (sum(count),)."""
    return np.repeat(start - (np.cumsum(count) - count), count) + np.arange(count.sum())


def pairs(occ: Occurrences, first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every pair (i, j), i in ``first`` and j in ``second`` (sorted occurrence indices), of
    occurrences in the same image, i != j: (i (Q,), j (Q,))."""
    image_i, image_j = occ.image[first], occ.image[second]
    lo = np.searchsorted(image_j, image_i, "left")
    count = np.searchsorted(image_j, image_i, "right") - lo
    i = np.repeat(first, count)
    j = second[concatenated_ranges(lo, count)]
    distinct = i != j
    return i[distinct], j[distinct]


def _displacement(occ: Occurrences, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(Q, 2) displacement from occurrence i to occurrence j, in units of i's scale."""
    scale, x, y = occ.scale[i], occ.xy[:, 0], occ.xy[:, 1]
    # Column by column: gathers of single columns take 40% less time than gathers of rows.
    return np.stack([(x[j] - x[i]) / scale, (y[j] - y[i]) / scale], axis=1)


def _within(displacement: np.ndarray, offset: np.ndarray, radius2: np.ndarray) -> np.ndarray:
    """(Q,) bool: the displacements (Q, 2) within a tolerance of an offset: ``offset`` (2,) or
    (Q, 2) and the squared tolerance ``radius2`` () or (Q,), float32 as the displacements."""
    error = displacement - offset
    return error[:, 0] ** 2 + error[:, 1] ** 2 <= radius2


def match(occ: Occurrences, compound: Compound) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of occurrences that realise ``compound``: (i (Q,), j (Q,)) indices into ``occ``."""
    first = np.flatnonzero(occ.part == compound.first)
    second = np.flatnonzero(occ.part == compound.second)
    i, j = pairs(occ, first, second)
    offset = np.asarray(compound.offset, np.float32)
    near = _within(_displacement(occ, i, j), offset, np.float32(compound.tolerance**2))
    return i[near], j[near]


def compound_occurrences(occ: Occurrences, compound: Compound, feature: int) -> Occurrences:
    """Occurrences of ``compound`` (as feature and part ``feature``): at the midpoint of each
    matching pair, with the mean of the two scales."""
    i, j = match(occ, compound)
    return Occurrences(
        occ.image[i],
        np.full(len(i), feature),
        (occ.xy[i] + occ.xy[j]) / 2,
        (occ.scale[i] + occ.scale[j]) / 2,
        occ.n_images,
    )


@checked
def add_compound_occurrences(
    occ: Occurrences, compounds: list[Compound], first_id: int
) -> Occurrences:
    """``occ`` with the occurrences of every compound added, compound c as feature
    ``first_id + c``, in order, so that a compound may pair earlier ones."""
    if not compounds:
        return occ
    # Each compound is matched in a table of its two parts' occurrences alone, and the whole
    # table is sorted once at the end: a sort of it per compound took 6 s of a car run.
    by_part = np.argsort(occ.part, kind="stable")  # part by part, each part's in table order
    part_of = occ.part[by_part]
    made: list[Occurrences] = []  # compound c's occurrences
    for c, compound in enumerate(compounds):
        parts = sorted({compound.first, compound.second})
        in_occ = [
            by_part[np.searchsorted(part_of, p) : np.searchsorted(part_of, p, "right")]
            for p in parts
        ]
        earlier = [made[p - first_id] for p in parts if 0 <= p - first_id < len(made)]
        of_parts = occ.take(np.sort(np.concatenate(in_occ))).merge(*earlier)
        made.append(compound_occurrences(of_parts, compound, first_id + c))
    return occ.merge(*made)


@checked
def propose(
    occ: Occurrences,
    tolerances: Sequence[float] = (1.0,),
    min_count: int = 10,
    max_candidates: int = 512,
    rank: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> list[Compound]:
    """Candidate compounds: pairs of parts that recur in a stable relation in ``occ``.

    Every ordered pair of occurrences within an image is binned by (first part, second
    part, displacement in units of the first's scale, cut into cells of a tolerance).
    A bin seen in at least ``min_count`` images, and not in all but fewer than ``min_count``
    of them (it could not split those images), is a candidate, with the mean displacement of
    its pairs as offset; per tolerance, the ``max_candidates`` best ranked are returned,
    best first: by default the most frequent. Wider tolerances give compounds that cover
    more images (a wider band of needle angles on a gauge, say).

    Args:
        occ: occurrences of the parts (words or groups, and compounds) in the images.
        tolerances: cell sizes of the displacements, in units of the first part's scale.
        min_count: images a relation must be seen in.
        max_candidates: candidates returned per tolerance.
        rank: scores of the bins from the images they hold, higher first, instead of their
            image counts: ``rank(images, start)`` with ``images`` (Z,) the images of every
            bin one bin after the other and ``start`` (B,) where each bin's begin; it is
            called once per tolerance with the bins that could be candidates, and bins it
            scores ``-inf`` are left out (``vistask.rlvc.compound_search.ReductionRank``).
    """
    if min(tolerances, default=0) <= 0 or min_count < 1 or max_candidates < 1:
        raise ValueError(
            f"need tolerances > 0, min_count >= 1 and max_candidates >= 1, got {tolerances}, "
            f"{min_count}, {max_candidates}"
        )
    everything = np.arange(len(occ), dtype=np.int32)  # int32 indices: pairs twice as fast
    i, j = pairs(occ, everything, everything)
    d = _displacement(occ, i, j)
    # Dense part ids keep the parts' order and the (bin, image) codes below small.
    parts, dense = np.unique(occ.part, return_inverse=True)
    pair_key = dense[i].astype(np.int64) * len(parts) + dense[j]
    image = occ.image[i]
    candidates = []
    for tolerance in tolerances:
        cell = np.floor(d / tolerance + 0.5).astype(np.int64)
        reach = MAX_REACH / tolerance
        span = 2 * int(np.ceil(reach)) + 1
        if len(parts) ** 2 * span**2 * occ.n_images >= 2**63:
            raise ValueError(
                f"{len(parts)} parts in {occ.n_images} images are too many to bin at tolerance "
                f"{tolerance}: propose on fewer images or with a wider tolerance"
            )
        key = (pair_key * span + cell[:, 0] + span // 2) * span + cell[:, 1] + span // 2
        key[(np.abs(cell[:, 0]) >= reach) | (np.abs(cell[:, 1]) >= reach)] = -1  # in no bin
        # Distinct images per bin: the sorted distinct (bin, image) codes (a sort of values,
        # 4x faster than a stable argsort of the bins).
        code = np.unique(key * occ.n_images + image)
        code = code[code >= 0]  # codes of pairs in no bin are negative
        bin_of = code // occ.n_images
        start = np.flatnonzero(np.diff(bin_of, prepend=-1))  # bins are >= 0
        bins, images = bin_of[start], np.diff(np.r_[start, len(bin_of)])
        ok = np.flatnonzero((images >= min_count) & (images <= occ.n_images - min_count))
        if rank is None:
            score = images[ok]
        else:
            image_of = code % occ.n_images
            # The images of the candidate bins only, each bin's run cut out whole.
            kept = concatenated_ranges(start[ok], images[ok])
            score = rank(image_of[kept], np.cumsum(images[ok]) - images[ok])
            finite = score > -np.inf
            ok, score = ok[finite], score[finite]
        ranked = bins[ok[np.argsort(-score, kind="stable")][:max_candidates]]
        if not len(ranked):
            continue
        # Offsets: the mean displacement of each ranked bin's pairs, summed in the pairs' order.
        chosen = np.sort(ranked)
        at = np.searchsorted(chosen, key)
        member = np.flatnonzero(np.r_[chosen, -2][at] == key)  # -2: no bin (keys are >= -1)
        member = member[np.argsort(key[member], kind="stable")]
        first = np.flatnonzero(np.diff(key[member], prepend=-1))
        size = np.diff(np.r_[first, len(member)])
        offsets = np.add.reduceat(d[member], first, axis=0) / size[:, None]
        offsets = offsets[np.searchsorted(chosen, ranked)]
        pair = ranked // (span * span)
        candidates += [
            Compound(
                int(parts[p // len(parts)]),
                int(parts[p % len(parts)]),
                (float(x), float(y)),
                float(tolerance),
            )
            for p, (x, y) in zip(pair, offsets, strict=True)
        ]
    return candidates


def presence_of_candidates(occ: Occurrences, candidates: list[Compound]) -> torch.Tensor:
    """(n_images, K) bool: candidate k present in image i.

    The pairs of occurrences of every candidate's part pair are enumerated at once, each pair
    once however many candidates share its parts, and tested against the candidates of its
    part pair: the first candidate of every part pair in one pass, the second in the next, ...
    """
    presence = torch.zeros(occ.n_images, len(candidates), dtype=torch.bool)
    if not candidates:
        return presence
    parts, of_pair = np.unique(
        np.array([(c.first, c.second) for c in candidates], np.int64), axis=0, return_inverse=True
    )
    of_pair = of_pair.reshape(-1)
    # Part pairs with the most candidates first: the pairs that meet an m-th are a prefix.
    size = np.bincount(of_pair, minlength=len(parts))
    rank = np.argsort(-size, kind="stable")
    parts, size = parts[rank], size[rank]
    by_pair = np.argsort(np.argsort(rank)[of_pair], kind="stable")
    start = np.cumsum(size) - size  # candidates of part pair p: by_pair[start[p]:][:size[p]]
    # Occurrences sorted by (part, image): those of a part in an image are one slice of it.
    code = occ.part.astype(np.int64) * occ.n_images + occ.image
    order = np.argsort(code, kind="stable")
    code = code[order]
    lo = np.searchsorted(code, parts[:, 0] * occ.n_images)
    count = np.searchsorted(code, (parts[:, 0] + 1) * occ.n_images) - lo
    i = order[concatenated_ranges(lo, count)]  # occurrences of each part pair's first part
    pair = np.repeat(np.arange(len(parts)), count)
    second = parts[pair, 1] * occ.n_images + occ.image[i]  # ... and its second in that image
    lo = np.searchsorted(code, second, "left")
    count = np.searchsorted(code, second, "right") - lo
    i, j, pair = np.repeat(i, count), order[concatenated_ranges(lo, count)], np.repeat(pair, count)
    distinct = i != j
    i, j = i[distinct], j[distinct]
    block = np.bincount(pair[distinct], minlength=len(parts))  # pairs of each part pair
    d, image = _displacement(occ, i, j), occ.image[i]
    offset = np.array([c.offset for c in candidates], np.float32)
    radius2 = np.array([c.tolerance**2 for c in candidates], np.float32)
    for m in range(int(size[0])):
        active = int(np.count_nonzero(size > m))  # part pairs with an m-th candidate
        k = np.repeat(by_pair[start[:active] + m], block[:active])
        hit = np.flatnonzero(_within(d[: len(k)], offset[k], radius2[k]))
        presence[torch.from_numpy(image[hit]).long(), torch.from_numpy(k[hit])] = True
    return presence


@checked
def draw_compound(
    image: np.ndarray, occ: Occurrences, compound: Compound, scale: int = 4
) -> np.ndarray:
    """``image`` (H, W, 3) uint8 enlarged ``scale`` times, with every occurrence of
    ``compound`` drawn (paper Fig. 6 bottom): its two parts circled at their keypoint scale,
    the line between them, and a dot at the compound's location (the midpoint).
    ``occ``: the occurrences of this one image (``n_images == 1``), compounds included."""
    import cv2

    if occ.n_images != 1:
        raise ValueError(f"draw one image's occurrences, got {occ.n_images} images")
    big = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    big = np.ascontiguousarray(big)
    i, j = match(occ, compound)
    for a, b in zip(i, j, strict=True):
        pa, pb = occ.xy[a] * scale, occ.xy[b] * scale
        for p, s, colour in ((pa, occ.scale[a], (0, 160, 255)), (pb, occ.scale[b], (255, 0, 255))):
            radius = max(2, round(float(s) * scale / 2))
            cv2.circle(big, tuple(np.round(p).astype(int)), radius, colour, 2, cv2.LINE_AA)
        cv2.line(
            big,
            tuple(np.round(pa).astype(int)),
            tuple(np.round(pb).astype(int)),
            (0, 200, 0),
            2,
            cv2.LINE_AA,
        )
        mid = tuple(np.round((pa + pb) / 2).astype(int))
        cv2.circle(big, mid, 4, (0, 200, 0), -1, cv2.LINE_AA)
    return big
