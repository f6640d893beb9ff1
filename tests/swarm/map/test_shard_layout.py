"""The shard layout: every voxel has one owner, and a delta cut by owner is the delta."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.map.shard_layout import ShardLayout

GRID = Grid((-1.0, 2.0, 0.0), 0.1, (37, 5, 3))


@st.composite
def layouts(draw) -> ShardLayout:
    nx = GRID.shape[0]
    inner = draw(st.sets(st.integers(1, nx - 1), max_size=6))
    return ShardLayout(GRID, (0, *sorted(inner), nx))


@st.composite
def deltas(draw) -> Delta:
    idx = np.array(sorted(draw(st.sets(st.integers(0, GRID.size - 1), max_size=120))), dtype=np.uint32)
    lam = np.arange(1, len(idx) + 1, dtype=np.float32)
    return Delta(idx, lam, lam / 3)


@settings(max_examples=200, deadline=None)
@given(layouts(), deltas())
def test_split_parts_put_back_are_the_delta(layout: ShardLayout, delta: Delta) -> None:
    parts = layout.split(delta)
    back = [layout.to_global(k, part.idx) for k, part in sorted(parts.items())]
    joined = np.concatenate(back) if back else np.zeros(0, np.int64)
    np.testing.assert_array_equal(joined, delta.idx.astype(np.int64))
    np.testing.assert_array_equal(
        np.concatenate([p.dlam for _, p in sorted(parts.items())] or [[]]), delta.dlam
    )
    for k, part in parts.items():
        assert np.all(layout.owner(layout.to_global(k, part.idx)) == k)
        assert part.idx.dtype == np.uint32 and np.all(np.diff(part.idx.astype(np.int64)) > 0)
        assert int(part.idx.max()) < layout.grid_of(k).size


@settings(max_examples=100, deadline=None)
@given(layouts())
def test_slabs_tile_the_grid_and_match_world_coordinates(layout: ShardLayout) -> None:
    spans = [layout.span(k) for k in range(layout.count)]
    assert spans[0][0] == 0 and spans[-1][1] == GRID.size
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:], strict=False))
    rng = np.random.default_rng(0)
    for k in range(layout.count):
        sub = layout.grid_of(k)
        assert sub.size == spans[k][1] - spans[k][0]
        # a voxel's centre in the shard's grid is the same point as in the mission's grid
        local = rng.integers(0, sub.size, 20)
        centres = sub.lo + (np.stack(np.unravel_index(local, sub.shape), -1) + 0.5) * sub.voxel
        np.testing.assert_array_equal(
            np.ravel_multi_index(GRID.index_of(centres).T, GRID.shape), layout.to_global(k, local)
        )


def test_even_and_cut_layouts_and_their_refusals() -> None:
    assert ShardLayout.even(GRID, 1) == ShardLayout.single(GRID)
    assert ShardLayout.even(GRID, 2).bounds == (0, 18, 37)  # round(18.5) is 18 (to even)
    assert ShardLayout.at(GRID, [0.5]).bounds == (0, 15, 37)  # x = 0.5 m is 15 voxels from -1.0
    with pytest.raises(ValueError, match="between 1 and"):
        ShardLayout.even(GRID, 38)
    with pytest.raises(ValueError, match="inside the workspace"):
        ShardLayout.at(GRID, [0.5, 0.52])
    with pytest.raises(ValueError, match="inside the workspace"):
        ShardLayout.at(GRID, [9.0])
    with pytest.raises(ValueError, match="no shard 2"):
        ShardLayout.even(GRID, 2).span(2)
    with pytest.raises(ValueError, match="outside shard 0"):
        ShardLayout.even(GRID, 2).to_global(0, np.array([18 * 15]))
