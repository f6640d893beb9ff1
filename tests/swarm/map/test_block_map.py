"""The block-sparse map against the dense CoverageMap as the oracle: same rays, same deltas, same bits.

Equality here is bit for bit (float32 lam and eta compared as integers), except where a sum
of many float64 terms is taken in another order (map entropy totals: 1e-12 relative).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarm.map.block_delta import BlockDelta
from swarm.map.block_fusion import MAX_BOX_VOXELS, block_batch_information
from swarm.map.block_map import BlockMap
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_cache import EntropyCache
from swarm.map.fusion import batch_information
from swarm.map.gradient import entropy_gradient
from swarm.map.grid import Grid
from swarm.map.lattice import KEY_LIMIT, Lattice
from swarm.map.sensor_model import SensorModel
from tests.support.numba_cache import second_run_cache_statistics

GRID = Grid((-2.0, -2.0, -1.0), 0.1, (40, 40, 20))
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.ascontiguousarray(a, np.float32), np.ascontiguousarray(b, np.float32)
    return a.shape == b.shape and np.array_equal(a.view(np.uint32), b.view(np.uint32))


def assert_same_map(sparse: BlockMap, dense: CoverageMap) -> None:
    twin = sparse.to_dense(dense.grid)
    assert same_bits(twin.lam, dense.lam), "lam differs"
    assert same_bits(twin.eta, dense.eta), "eta differs"


def rays(rng, centre, spread, n, reach):
    """``n`` points around an origin drawn near ``centre``: near, far (past max range), NaN, zero-length."""
    origin = centre + rng.uniform(-1, 1, 3) * spread
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = origin + direction * rng.uniform(0.02, reach, (n, 1))
    points[:2] = np.nan
    points[2:4] = origin
    return origin, points


options = st.tuples(st.booleans(), st.sampled_from([(False, False), (True, False), (True, True)]))


@pytest.mark.slow
@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), opts=options, bits=st.sampled_from([2, 3, 4, 5]))
def test_a_bounded_block_map_fuses_exactly_as_the_dense_map(seed, opts, bits):
    """Bounds = the dense grid: rays cut and skipped at its boundary alike; every counter and bit equal."""
    hit_precedence, (discretize, weighted) = opts
    rng = np.random.default_rng(seed)
    sensor = SensorModel(max_range=float(rng.choice([1.2, 5.0])), hit_precedence=hit_precedence)
    dense, sparse = CoverageMap(GRID, sensor), BlockMap.for_grid(GRID, sensor, block_bits=bits)
    for _ in range(3):
        origin, points = rays(rng, np.array([0.0, 0.0, 0.0]), [1.5, 1.5, 0.7], 300, 3.5)
        kw = {"hit_precedence": hit_precedence, "discretize": discretize, "weighted": weighted}
        a = batch_information(GRID, sensor, origin, points, **kw)
        b = block_batch_information(sparse.lattice, sensor, origin, points, GRID, **kw)
        for field in ("rays", "measurements", "voxel_updates", "truncated", "clipped", "skipped_outside"):
            assert getattr(a, field) == getattr(b, field), field
        dense.apply(a.delta)
        sparse.apply(b.delta)
        flat = b.delta.to_flat(GRID, sparse.lattice)
        np.testing.assert_array_equal(flat.idx, a.delta.idx)
        assert same_bits(flat.dlam, a.delta.dlam) and same_bits(flat.deta, a.delta.deta)
    assert_same_map(sparse, dense)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), precedence=st.booleans(), discretize=st.booleans())
def test_an_unbounded_block_map_equals_a_dense_map_large_enough_for_the_rays(seed, precedence, discretize):
    """No box at all: where no ray leaves the dense grid, the unbounded lattice gets the same bits."""
    rng = np.random.default_rng(seed)
    grid = Grid((-4.0, -4.0, -3.0), 0.1, (80, 80, 60))
    sensor = SensorModel(max_range=2.0, hit_precedence=precedence, discretize=discretize)
    dense = CoverageMap(grid, sensor)
    sparse = BlockMap(Lattice.of_grid(grid), sensor)
    for _ in range(3):
        origin, points = rays(rng, np.zeros(3), [1.0, 1.0, 0.8], 300, 3.0)  # cut at 2 m: inside
        assert dense.integrate(origin, points).clipped == 0
        sparse.integrate(origin, points)
    assert_same_map(sparse, dense)
    assert sparse.n_blocks < grid.size / sparse.lattice.block_voxels


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), shift=st.tuples(*[st.integers(-8, 8)] * 3))
def test_negative_lattice_indices_give_the_same_bits(seed, shift):
    """With a power-of-two voxel and dyadic points every coordinate is exact in any frame, so a
    lattice whose origin lies inside the grid (rays at negative indices, floor division, masks)
    must equal the dense grid bit for bit. (Every point within max range: a ray cut at max range
    ends at a point that is not dyadic.)"""
    rng = np.random.default_rng(seed)
    grid = Grid((-8.0, -8.0, -4.0), 0.25, (64, 64, 32))
    sensor = SensorModel(max_range=3.0)
    dense = CoverageMap(grid, sensor)
    lattice = Lattice(tuple(0.25 * np.array(shift)), 0.25, 3)  # within 2 m of the rays' centre
    sparse = BlockMap(lattice, sensor)
    for _ in range(2):
        origin, points = rays(rng, np.zeros(3), [2.0, 2.0, 1.0], 200, 2.9)
        origin, points = np.round(origin * 64) / 64, np.round(points * 64) / 64  # dyadic
        dense.integrate(origin, points)
        sparse.integrate(origin, points)
    assert (sparse.keys < 0).any()
    assert_same_map(sparse, dense)


def batch_deltas(rng, count):
    sensor = SensorModel(max_range=3.0)
    out = []
    for _ in range(count):
        origin, points = rays(rng, np.zeros(3), [1.5, 1.5, 0.7], 200, 3.5)
        out.append(batch_information(GRID, sensor, origin, points).delta)
    return sensor, out


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), order=st.randoms(use_true_random=False))
def test_deltas_in_any_order_and_twice_add_as_on_the_dense_map(seed, order):
    rng = np.random.default_rng(seed)
    sensor, deltas = batch_deltas(rng, 4)
    deltas.append(deltas[1])  # applied twice: adds twice, like the dense map (dedup is not this layer's job)
    order.shuffle(deltas)
    dense, sparse, unbounded = CoverageMap(GRID, sensor), BlockMap.for_grid(GRID, sensor), None
    unbounded = BlockMap(Lattice.of_grid(GRID, 3), sensor)
    for d in deltas:
        dense.apply(d)
        sparse.apply(BlockDelta.from_flat(d, GRID, sparse.lattice))
        unbounded.apply_flat(d, GRID)
    assert_same_map(sparse, dense)
    assert_same_map(unbounded, dense)


def test_another_order_differs_only_by_float32_rounding():
    sensor, deltas = batch_deltas(np.random.default_rng(1), 6)
    a, b = BlockMap.for_grid(GRID, sensor), BlockMap.for_grid(GRID, sensor)
    for d in deltas:
        a.apply_flat(d, GRID)
    for d in deltas[::-1]:
        b.apply_flat(d, GRID)
    np.testing.assert_allclose(a.to_dense().lam, b.to_dense().lam, rtol=1e-6)


def test_flat_and_block_deltas_convert_both_ways_exactly():
    sensor, (delta,) = batch_deltas(np.random.default_rng(2), 1)
    lattice = Lattice((GRID.lo[0] - 0.3, GRID.lo[1] + 0.5, GRID.lo[2]), 0.1, 4)  # grid at offset (3, -5, 0)
    block = BlockDelta.from_flat(delta, GRID, lattice)
    keys = block.keys.astype(np.int64)
    assert np.all(
        np.lexsort(keys.T[::-1]) == np.arange(len(keys))
    )  # keys sorted, then offsets within a block
    for lo, hi in zip(block.starts[:-1], block.starts[1:], strict=True):
        assert np.all(np.diff(block.offsets[lo:hi].astype(int)) > 0)
    back = block.to_flat(GRID, lattice)
    np.testing.assert_array_equal(back.idx, delta.idx)
    assert same_bits(back.dlam, delta.dlam) and same_bits(back.deta, delta.deta)
    entries = BlockDelta.from_entries(
        4, np.repeat(block.keys, block.counts, axis=0), block.offsets, block.dlam, block.deta
    )
    np.testing.assert_array_equal(entries.offsets, block.offsets)
    assert block.nbytes() < delta.nbytes()
    # a grid smaller than the delta: to_flat refuses, within cuts
    small = Grid(GRID.origin, 0.1, (20, 40, 20))
    with pytest.raises(ValueError, match="outside the grid"):
        block.to_flat(small, lattice)
    cut = block.within(small, lattice).to_flat(small, lattice)
    inside = GRID.unflat(delta.idx)[:, 0] < 20
    np.testing.assert_array_equal(cut.dlam, delta.dlam[inside])


def test_dense_maps_convert_both_ways_and_the_delta_from_prior_matches():
    sensor, deltas = batch_deltas(np.random.default_rng(3), 3)
    dense = CoverageMap(GRID, sensor)
    for d in deltas:
        dense.apply(d)
    sparse = BlockMap.from_dense(dense, block_bits=3)
    assert_same_map(sparse, dense)
    assert same_bits(sparse.entropy(GRID).ravel(), EntropyCache.from_information(dense.lam, dense.eta).values)
    mine = sparse.delta_from_prior().to_flat(GRID, sparse.lattice)
    theirs = dense.delta_from_prior()  # every voxel; keep those whose float32 beliefs moved
    lam0, eta0 = sparse.prior
    moved = (dense.lam[theirs.idx] != lam0) | (dense.eta[theirs.idx] != eta0)
    np.testing.assert_array_equal(mine.idx, theirs.idx[moved])
    assert same_bits(mine.dlam, theirs.dlam[moved]) and same_bits(mine.deta, theirs.deta[moved])


def fused_pair(seed=4, bits=4, entropy=True):
    rng = np.random.default_rng(seed)
    grid = Grid((-4.0, -4.0, -3.0), 0.1, (80, 80, 60))
    sensor = SensorModel(max_range=2.0)
    dense, sparse = CoverageMap(grid, sensor), BlockMap(Lattice.of_grid(grid, bits), sensor, entropy=entropy)
    for _ in range(4):
        origin, points = rays(rng, np.zeros(3), [1.0, 1.0, 0.8], 400, 3.0)
        sparse.apply_flat(dense.integrate(origin, points).delta, grid)
    return dense, sparse


@pytest.mark.parametrize("entropy", [True, False])
def test_entropy_over_regions_equals_the_dense_cache(entropy):
    dense, sparse = fused_pair(entropy=entropy)
    grid = dense.grid
    cache = EntropyCache.from_information(dense.lam, dense.eta)
    H = cache.values.reshape(grid.shape)
    assert sparse.entropy_bits(grid) == pytest.approx(cache.total, rel=1e-12)
    assert sparse.entropy_removed_bits() == pytest.approx(
        grid.size * float(sparse.prior_bits) - cache.total, rel=1e-9
    )
    lat = sparse.lattice
    for lo, hi in (((0, 0, 0), (80, 80, 60)), ((33, 7, 21), (61, 52, 40)), ((40, 40, 30), (41, 41, 31))):
        region = lat.grid(lo, hi)
        part = H[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        assert same_bits(sparse.entropy(region), part)
        assert sparse.entropy_bits(region) == pytest.approx(float(np.sum(part, dtype=np.float64)), rel=1e-12)
    far = lat.grid((500, 500, 500), (510, 520, 530))  # nothing seen there: the prior
    assert sparse.entropy_bits(far) == pytest.approx(far.size * float(sparse.prior_bits), rel=1e-12)


def test_the_entropy_cache_follows_every_update():
    """Repeated entries, refused deltas and deltas applied twice keep cache and beliefs in step."""
    dense, sparse = fused_pair(seed=5)
    d = dense.delta_from_prior()
    twice = Delta(
        np.r_[d.idx[:50], d.idx[:50]], np.r_[d.dlam[:50], d.dlam[:50]], np.r_[d.deta[:50], d.deta[:50]]
    )
    dense.apply(twice)
    sparse.apply_flat(twice, dense.grid)
    cache = EntropyCache.from_information(dense.lam, dense.eta)
    assert same_bits(sparse.entropy(dense.grid).ravel(), cache.values)
    assert sparse.entropy_bits(dense.grid) == pytest.approx(cache.total, rel=1e-12)


def test_the_gradient_of_a_region_equals_the_dense_gradient_there():
    dense, sparse = fused_pair(seed=6)
    grid = dense.grid
    G = entropy_gradient(
        EntropyCache.from_information(dense.lam, dense.eta).values.reshape(grid.shape), grid.voxel
    )
    lat = sparse.lattice
    for lo, hi in (((30, 35, 25), (50, 45, 31)), ((1, 1, 1), (79, 79, 59)), ((38, 40, 29), (39, 41, 30))):
        got = sparse.entropy_gradient(lat.grid(lo, hi))
        assert same_bits(got, G[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]])
    # bounded: at the bounds' lower faces the component is 0, as at the dense grid's boundary
    bounded = BlockMap.from_dense(dense)
    got = bounded.entropy_gradient(lat.grid((0, 10, 0), (20, 30, 8)))
    assert same_bits(got, G[0:20, 10:30, 0:8])
    cov = expected_coverage(dense.mean(), dense.sigma()).reshape(grid.shape)
    np.testing.assert_array_equal(
        sparse.expected_coverage(lat.grid((20, 20, 20), (60, 60, 40))), cov[20:60, 20:60, 20:40]
    )
    assert np.array_equal(sparse.known_mask(grid).ravel(), dense.known_mask())


def test_bad_deltas_are_refused_whole_and_leave_the_map_as_it_was():
    sensor, (delta,) = batch_deltas(np.random.default_rng(7), 1)
    sparse = BlockMap.for_grid(Grid(GRID.origin, 0.1, (20, 40, 20)), sensor)
    lattice = sparse.lattice
    block = BlockDelta.from_flat(delta, GRID, lattice)
    before = (sparse.n_blocks, sparse.to_dense().lam.copy())

    def unchanged():
        assert sparse.n_blocks == before[0] and same_bits(sparse.to_dense().lam, before[1])

    with pytest.raises(ValueError, match="outside the map's bounds"):
        sparse.apply(block)  # reaches x >= 2 m, beyond the bounds
    unchanged()
    inside = block.within(sparse.bounds, lattice)
    for bad, match in (
        (np.where(np.arange(len(inside)) == 3, np.nan, inside.dlam).astype(np.float32), "NaN or inf"),
        (-10 * inside.dlam, "outside"),
    ):
        forged = BlockDelta(4, inside.keys, inside.counts, inside.offsets, bad, inside.deta)
        with pytest.raises(ValueError, match=match):
            sparse.apply_received(forged)
        unchanged()
    offsets = inside.offsets.copy()
    offsets[-1] = 4096
    with pytest.raises(ValueError, match="offset beyond"):
        sparse.apply(BlockDelta(4, inside.keys, inside.counts, offsets, inside.dlam, inside.deta))
    unchanged()
    with pytest.raises(ValueError, match="blocks of 8"):
        BlockMap(Lattice.of_grid(GRID, 4)).apply(BlockDelta.from_flat(delta, GRID, Lattice.of_grid(GRID, 3)))
    one = np.ones(1, np.float32)
    far = BlockDelta(
        4, np.array([[KEY_LIMIT, 0, 0]], np.int32), np.ones(1, np.uint32), np.zeros(1, np.uint16), one, one
    )
    with pytest.raises(ValueError, match="block key out of range"):
        BlockMap(lattice).apply(far)
    with pytest.raises(ValueError, match="counts add up"):
        BlockDelta(4, inside.keys, inside.counts + 1, inside.offsets, inside.dlam, inside.deta)
    sparse.apply(inside)
    assert sparse.n_blocks > before[0]


def test_memory_grows_with_what_is_seen_not_with_the_distance():
    """A sensor 100 km from the lattice's origin allocates the blocks it sees there, nothing between."""
    sensor = SensorModel(max_range=2.0)
    sparse = BlockMap(Lattice((0.0, 0.0, 0.0), 0.1), sensor)
    rng = np.random.default_rng(8)
    origin, points = rays(rng, np.array([1e5, -3e4, 2.0]), [0.5, 0.5, 0.2], 500, 3.0)
    result = sparse.integrate(origin, points)
    assert 0 < sparse.n_blocks <= 64 and result.rays == 496
    assert np.all(np.abs(sparse.keys[:, 0] * 1.6 - 1e5) < 10)
    region = sparse.lattice.grid(*sparse.extent())
    assert sparse.entropy_bits(region) < region.size * float(sparse.prior_bits)
    copy = sparse.copy()
    copy.integrate(origin, points)
    assert sparse.allocated_entropy_bits() > copy.allocated_entropy_bits()  # the copy is its own


def test_a_batch_spanning_too_many_voxels_is_refused():
    sensor = SensorModel(max_range=1e4)
    lattice = Lattice((0.0, 0.0, 0.0), 0.1)
    points = np.array([[900.0, 0, 0], [0, 900.0, 0], [0, 0, 900.0], [-900.0, -900, -900]])
    with pytest.raises(ValueError, match=f"at most {MAX_BOX_VOXELS:,}"):
        block_batch_information(lattice, sensor, np.zeros(3), points)
    with pytest.raises(ValueError, match="beyond the lattice's block keys"):
        block_batch_information(lattice, SensorModel(), np.array([1e9, 0, 0]), np.array([[1e9 + 1, 0, 0]]))


def test_lattices_refuse_bad_geometry_and_grids_off_their_corners():
    with pytest.raises(ValueError, match="block_bits"):
        Lattice((0, 0, 0), 0.1, 6)
    with pytest.raises(ValueError, match="voxel size"):
        Lattice((0, 0, 0), 0.0)
    lattice = Lattice((0.0, 0.0, 0.0), 0.1)
    with pytest.raises(ValueError, match="not on the lattice"):
        lattice.offset_of_grid(Grid((0.05, 0.0, 0.0), 0.1, (2, 2, 2)))
    with pytest.raises(ValueError, match="voxel"):
        lattice.offset_of_grid(Grid((0.0, 0.0, 0.0), 0.2, (2, 2, 2)))
    ijk = np.array([[-1, -17, 33], [0, 15, -16]])
    np.testing.assert_array_equal(lattice.voxel_of(lattice.block_of(ijk), lattice.offset_of(ijk)), ijk)
    with pytest.raises(ValueError, match="needs a region"):
        BlockMap(lattice).entropy_bits()


@pytest.mark.slow
def test_a_second_process_loads_the_block_kernels_from_numbas_cache():
    stats = second_run_cache_statistics(
        "from swarm.map import block_kernels as b, block_map, fusion_kernel as k\nblock_map.warm_up()",
        "(b.ray_box, b.collect_blocks, b.scatter_box, b.find_slots, b.global_index, b.take_touched,"
        " b.put_touched, b.gather, b.region_sums, k.traverse_rays)",
    )
    assert len(stats) == 10
    for name, (hits, misses) in stats.items():
        assert hits >= 1 and misses == 0, (name, stats)
