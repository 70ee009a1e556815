"""Feature presence of a database's percepts, held as bits: eight features a byte.

A database's (M, F) presence is read a few columns at a time (the features a class structure
tests) or one entry per percept (the feature that a tree node tests), never whole. A bool
tensor takes a byte per (percept, feature), a kilobyte per percept of 8,192 words;
``PackedPresence`` holds the same matrix in an eighth of that and answers the same indexing
with bool tensors.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from vistask.checks import checked

ROWS_PER_CHUNK = 4096  # percepts unpacked at a time where every entry is read


def _index(key) -> np.ndarray | slice | int:
    """A row or column key as numpy indexing takes it (tensors and bool masks included)."""
    if isinstance(key, slice | int | np.integer):
        return key
    key = np.asarray(key.cpu() if isinstance(key, torch.Tensor) else key)
    if key.ndim == 0:
        return int(key)
    return np.flatnonzero(key) if key.dtype == bool else key.astype(np.int64, copy=False)


class PackedBits:
    """The numpy side of a ``PackedPresence`` (what ``numpy()`` gives, as a tensor's does):
    ``bits[rows, columns]`` is a numpy bool array."""

    def __init__(self, packed: np.ndarray, n_features: int) -> None:
        self.packed, self.n_features = packed, n_features

    def __len__(self) -> int:
        return len(self.packed)

    @property
    def shape(self) -> tuple[int, int]:
        """(M, F)."""
        return (len(self.packed), self.n_features)

    def __getitem__(self, key) -> np.ndarray:
        rows, columns = (*(key if isinstance(key, tuple) else (key,)), slice(None))[:2]
        rows, columns = _index(rows), _index(columns)
        block = isinstance(rows, slice) or isinstance(columns, slice)
        if isinstance(columns, slice):
            columns = np.arange(self.n_features)[columns]
        byte, shift = columns >> 3, np.asarray(columns & 7, dtype=np.uint8)
        # A slice of rows or columns: every listed row with every listed column; else rows and
        # columns paired entry by entry (broadcast), as numpy pairs index arrays.
        out = self.packed[rows][..., byte] if block else self.packed[rows, byte]
        if np.ndim(out) == 0:
            return np.asarray((out >> shift) & 1 == 1)
        if np.may_share_memory(out, self.packed):  # one column of a slice of rows: a view
            out = out.copy()
        out = np.ascontiguousarray(out)  # numpy may lay a read of columns out column-major
        # One copy of the bytes read, turned into their bits in place: reads of thousands of
        # columns of every percept are hundreds of MB.
        np.right_shift(out, shift, out=out)
        return np.bitwise_and(out, 1, out=out).view(bool)


@checked
class PackedPresence:
    """(M, F) bool feature presence in (M, ceil(F / 8)) uint8, bit f % 8 of byte f // 8.

    It answers a bool tensor's indexing with bool tensors (``presence[:, columns]``,
    ``presence[rows, feature]``, ``presence[rows, features]`` entry by entry), and ``numpy()``
    with ``PackedBits`` for numpy's. Held on the CPU.

    Example:
        >>> presence = PackedPresence.from_pairs(image, feature, n_images=3, n_features=100)
        >>> presence[:, [4, 7]]          # (3, 2) bool tensor
        >>> presence.dense()             # (3, 100) bool tensor

    Args:
        packed: (M, ceil(F / 8)) uint8 bits.
        n_features: F.
    """

    ndim = 2
    dtype = torch.bool
    device = torch.device("cpu")

    def __init__(self, packed: np.ndarray, n_features: int) -> None:
        if packed.dtype != np.uint8 or packed.ndim != 2 or packed.shape[1] != -(-n_features // 8):
            raise ValueError(
                f"packed must be (M, {-(-n_features // 8)}) uint8 for {n_features} features, "
                f"got {packed.shape} {packed.dtype}"
            )
        self._bits = PackedBits(np.ascontiguousarray(packed), n_features)

    @classmethod
    def from_dense(cls, presence: torch.Tensor) -> PackedPresence:
        """The bits of a (M, F) bool tensor."""
        bits = presence.cpu().numpy().astype(bool, copy=False)
        return cls(np.packbits(bits, axis=1, bitorder="little"), presence.shape[1])

    @classmethod
    def from_pairs(
        cls, image: np.ndarray, feature: np.ndarray, n_images: int, n_features: int
    ) -> PackedPresence:
        """Feature ``feature[k]`` present in image ``image[k]`` (repeats allowed)."""
        image, feature = np.asarray(image, np.int64), np.asarray(feature, np.int64)
        if len(feature) and not (feature.min() >= 0 and feature.max() < n_features):
            raise ValueError(f"feature ids must lie in 0..{n_features - 1}")
        packed = np.zeros((n_images, -(-n_features // 8)), np.uint8)
        np.bitwise_or.at(packed, (image, feature >> 3), (1 << (feature & 7)).astype(np.uint8))
        return cls(packed, n_features)

    @property
    def shape(self) -> torch.Size:
        """(M, F)."""
        return torch.Size(self._bits.shape)

    @property
    def nbytes(self) -> int:
        """Bytes the bits take."""
        return self._bits.packed.nbytes

    def __len__(self) -> int:
        return len(self._bits)

    def __getitem__(self, key) -> torch.Tensor:
        return torch.from_numpy(self._bits[key])

    def numpy(self) -> PackedBits:
        """The bits for numpy's indexing (``PackedBits``)."""
        return self._bits

    def cpu(self) -> PackedPresence:
        """Itself: the bits are on the CPU."""
        return self

    def dense(self) -> torch.Tensor:
        """The (M, F) bool tensor."""
        return self[:, :]

    def nonzero(self, as_tuple: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """Rows (nnz,) and features (nnz,) long of the present entries, by row then feature."""
        if not as_tuple:
            raise ValueError("PackedPresence.nonzero gives rows and features: as_tuple=True")
        # The nonzero bytes first (a percept shows a few dozen of thousands of features),
        # then their bits: in order by row, then byte, then bit, that is by feature.
        rows, byte = np.nonzero(self._bits.packed)
        bits = np.unpackbits(self._bits.packed[rows, byte][:, None], axis=1, bitorder="little")
        entry, bit = np.nonzero(bits)
        features = byte[entry] * 8 + bit
        return torch.from_numpy(rows[entry]), torch.from_numpy(features)

    def with_columns(self, columns: torch.Tensor) -> PackedPresence:
        """This presence with (M, C) bool ``columns`` after its F features."""
        m, f = self.shape
        if columns.shape[0] != m:
            raise ValueError(f"columns must have {m} rows, got {tuple(columns.shape)}")
        rows, added = np.nonzero(columns.cpu().numpy())
        width = -(-(f + columns.shape[1]) // 8)
        packed = np.zeros((m, width), np.uint8)
        packed[:, : self._bits.packed.shape[1]] = self._bits.packed
        added = added + f
        np.bitwise_or.at(packed, (rows, added >> 3), (1 << (added & 7)).astype(np.uint8))
        return PackedPresence(packed, f + columns.shape[1])

    @staticmethod
    def concat(parts: Sequence[PackedPresence]) -> PackedPresence:
        """The rows of ``parts`` (same features) one after another."""
        widths = {p.shape[1] for p in parts}
        if len(widths) != 1:
            raise ValueError(f"cannot join presence of {sorted(widths)} features")
        return PackedPresence(np.concatenate([p._bits.packed for p in parts]), widths.pop())


def distinct_rows(
    presence: PackedPresence | torch.Tensor,
    columns: Sequence[int],
    counts: torch.Tensor | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The distinct rows of ``presence[:, columns]``, read ``ROWS_PER_CHUNK`` rows at a time.

    Percepts equal on these columns, which a class structure testing them treats alike, are
    one row. Rows are compared as packed bytes.

    Args:
        presence: (M, F) bool presence (``PackedPresence`` or a bool tensor).
        columns: the C columns read.
        counts: (M,) long, the times each row was met (None: once each).

    Returns:
        bits (U, ceil(C / 8)) uint8, the distinct rows packed (``np.packbits``, big-endian
        bits); first (U,) the first row of each; inverse (M,) the distinct row of each row;
        counts (U,) int64, the times each was met.

    Example:
        >>> bits, first, inverse, counts = distinct_rows(torch.eye(3).bool()[[0, 1, 0]], [0, 1])
        >>> first, inverse, counts
        (array([1, 0]), array([1, 0, 1]), array([1, 2]))
    """
    columns = torch.as_tensor(np.asarray(columns, dtype=np.int64))
    packed = np.concatenate(
        [
            np.packbits(presence[start : start + ROWS_PER_CHUNK, columns].numpy(), axis=1)
            for start in range(0, len(presence), ROWS_PER_CHUNK)
        ]
        or [np.zeros((0, -(-len(columns) // 8)), np.uint8)]
    )
    rows_as_bytes = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()  # 20x np.unique(axis)
    _, first, inverse = np.unique(rows_as_bytes, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    met = None if counts is None else counts.cpu().numpy()
    return packed[first], first, inverse, np.bincount(inverse, met).astype(np.int64)


__all__ = ["PackedBits", "PackedPresence", "distinct_rows"]
