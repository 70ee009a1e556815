"""Feature presence held as bits answers a bool tensor's indexing with the same values."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vistask.rlvc.presence import PackedPresence


def dense_and_packed(m: int, f: int, seed: int) -> tuple[torch.Tensor, PackedPresence]:
    dense = torch.rand(m, f, generator=torch.Generator().manual_seed(seed)) < 0.3
    return dense, PackedPresence.from_dense(dense)


@settings(max_examples=40, deadline=None)
@given(m=st.integers(1, 40), f=st.integers(1, 30), seed=st.integers(0, 10**6))
def test_every_kind_of_index_reads_what_the_bool_tensor_reads(m, f, seed):
    dense, packed = dense_and_packed(m, f, seed)
    rng = np.random.default_rng(seed)
    rows = torch.from_numpy(rng.integers(0, m, 7))
    columns = torch.from_numpy(rng.integers(0, f, 7))
    mask = torch.from_numpy(rng.random(m) < 0.5)
    keys = [
        (slice(None), int(columns[0])),  # a column
        (slice(None), columns),  # columns
        (slice(1, m, 2), columns[:3]),  # a block
        (rows, columns),  # entry by entry
        (rows, int(columns[1])),
        (int(rows[0]), columns),
        (rows, slice(None)),  # whole rows
        (mask, int(columns[2])),
        (rows,),
        (slice(0, m // 2),),
    ]
    for key in keys:
        got = packed[key]
        assert got.dtype == torch.bool and torch.equal(got, dense[key]), key
        assert got.is_contiguous(), key  # numpy.packbits and void views of rows need it
        as_numpy = tuple(k.numpy() if isinstance(k, torch.Tensor) else k for k in key)
        assert np.array_equal(packed.numpy()[as_numpy], dense.numpy()[as_numpy]), key
    assert torch.equal(packed.dense(), dense) and packed.shape == dense.shape


def test_nonzero_pairs_columns_and_joins_are_the_tensors():
    dense, packed = dense_and_packed(9000, 21, 0)  # more rows than one unpacked chunk
    rows, features = dense.nonzero(as_tuple=True)
    assert all(torch.equal(a, b) for a, b in zip(packed.nonzero(), (rows, features), strict=True))
    again = PackedPresence.from_pairs(rows.numpy(), features.numpy(), 9000, 21)
    assert torch.equal(again.dense(), dense)
    extra = dense[:, :13].flip(1)
    assert torch.equal(packed.with_columns(extra).dense(), torch.cat([dense, extra], 1))
    assert torch.equal(PackedPresence.concat([packed, again]).dense(), torch.cat([dense, dense]))
    assert packed.nbytes == 9000 * 3  # 21 features in 3 bytes a row


def test_wrong_bits_and_features_are_refused():
    with pytest.raises(ValueError, match="uint8"):
        PackedPresence(np.zeros((3, 2), np.int64), 16)
    with pytest.raises(ValueError, match=r"\(M, 1\)"):
        PackedPresence(np.zeros((3, 2), np.uint8), 8)
    with pytest.raises(ValueError, match="feature ids"):
        PackedPresence.from_pairs(np.array([0]), np.array([8]), 1, 8)
    with pytest.raises(ValueError, match="join"):
        PackedPresence.concat([dense_and_packed(2, 8, 0)[1], dense_and_packed(2, 9, 0)[1]])
