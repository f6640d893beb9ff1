"""Fusion of batches: against an independent per-ray computation, and order invariance."""

import numpy as np
import pytest

from swarm.map.coverage_map import CoverageMap, prior_information
from swarm.map.delta import Delta, merge_deltas
from swarm.map.fusion import batch_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from tests.support.traversal_oracle import reference

GRID = Grid((-3.0, -3.0, -1.0), 0.1, (60, 60, 30))
SENSOR = SensorModel(max_range=2.3)
SENSOR_5M = SensorModel(max_range=5.0)


def random_batch(rng, n=200):
    origin = rng.uniform(-0.5, 0.5, 3) * [1, 1, 0.4]
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = origin + direction * rng.uniform(0.3, 2.2, (n, 1)) * [1, 1, 0.3]
    return origin, points


CUT = 2.3  # where both sensors below cut a ray: SENSOR's max range, the other's hit range


@pytest.mark.parametrize("sensor", [SENSOR, SensorModel(max_range=5.0, hit_range=CUT)], ids=["max", "hit"])
@pytest.mark.parametrize("hit_precedence", [False, True])
def test_batch_equals_independent_per_ray_sum(hit_precedence, sensor):
    """Each ray's voxels (exact reference traversal) get lam = 1/sigma^2, eta = mu/sigma^2 (eq. 14).

    A ray beyond max range (or beyond the hit range, when shorter) is free space (mu = 0) up
    to that range, with the sigma of a ray of that length; with hit precedence a voxel
    holding a return gets nothing from the other rays but as the voxel behind their hit.
    """
    rng = np.random.default_rng(0)
    origin, points = random_batch(rng, 40)
    flat = np.array([[1.0, 0.2, 0.05], [-0.3, 1.0, 0.1], [-1, -1, 0], [0.2, -1, -0.1], [1, 1, 0.2]])
    points[:5] = origin + 4.0 * flat / np.linalg.norm(flat, axis=1, keepdims=True)  # beyond max range
    rays = []
    for p in points:
        dist = float(np.linalg.norm(p - origin))
        returned = dist <= CUT
        end = p if returned else origin + (p - origin) * CUT / dist
        voxels, _, behind = reference(GRID, origin, end, hit=returned)
        rays.append((min(dist, CUT), returned, voxels, behind, tuple(GRID.index_of(end))))
    hits = {r[4] for r in rays if r[1]}
    lam, eta = {}, {}
    for d, returned, voxels, behind, hit_voxel in rays:
        for v in voxels:
            if not GRID.contains_index(np.array(v)):
                continue
            own = returned and tuple(v) == hit_voxel
            if hit_precedence and tuple(v) in hits and not own and tuple(v) != behind:
                continue
            d_l = float(np.linalg.norm(GRID.centre(np.array(v)) - origin))
            mu = SENSOR.mean(d, d_l, GRID.voxel) if returned else 0.0
            sigma = SENSOR.sigma(d, d_l, GRID.voxel)  # eq. 14 does not depend on the max range
            key = int(GRID.flat(np.array(v)))
            lam[key] = lam.get(key, 0.0) + 1 / sigma**2
            eta[key] = eta.get(key, 0.0) + mu / sigma**2
    result = batch_information(GRID, sensor, origin, points, hit_precedence=hit_precedence)
    assert result.truncated == 5
    assert sorted(lam) == result.delta.idx.tolist()
    keys = result.delta.idx.tolist()
    np.testing.assert_allclose(result.delta.dlam, [lam[k] for k in keys], rtol=2e-5)
    np.testing.assert_allclose(result.delta.deta, [eta[k] for k in keys], rtol=2e-5, atol=1e-3)


def test_a_return_beyond_the_hit_range_is_free_space_up_to_it_and_no_hit():
    """A wall 2.8 m away seen with a 2.0 m hit range: nothing occupied, and nothing updated
    farther than 2.0 m (the end voxel's centre is within half a voxel diagonal of the cut)."""
    origin = np.array([0.05, 0.05, 0.05])
    ys, zs = np.meshgrid(np.linspace(-0.5, 0.5, 11), np.linspace(-0.3, 0.3, 7))
    wall = np.column_stack([np.full(ys.size, 2.85), ys.ravel(), zs.ravel()])
    near = batch_information(GRID, SensorModel(max_range=5.0), origin, wall)
    cut = batch_information(GRID, SensorModel(max_range=5.0, hit_range=2.0), origin, wall)
    assert near.truncated == 0 and cut.truncated == len(wall) and cut.rays == len(wall)
    assert np.any(near.delta.deta > 0.5 * near.delta.dlam)  # the wall's hits: mean coverage above 0.5
    assert np.all(cut.delta.deta == 0.0)
    dist = np.linalg.norm(GRID.centre(GRID.unflat(cut.delta.idx.astype(np.int64))) - origin, axis=1)
    assert dist.max() <= 2.0 + 0.5 * np.sqrt(3) * GRID.voxel
    assert dist.max() > 2.0 - GRID.voxel  # free space right up to the cut
    # the hit range takes no part in the map's meaning: same prior, same equality
    assert SensorModel(max_range=5.0, hit_range=2.0) == SensorModel(max_range=5.0)


def test_a_hit_range_must_be_positive():
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="hit_range"):
            SensorModel(hit_range=bad)
    assert SensorModel(max_range=5.0, hit_range=7.0).reach == 5.0
    assert SensorModel(max_range=5.0, hit_range=3.0).reach == 3.0


def test_order_of_batches_and_deltas_does_not_matter():
    rng = np.random.default_rng(1)
    batches = [random_batch(rng) for _ in range(6)]
    deltas = [batch_information(GRID, SENSOR, o, p).delta for o, p in batches]

    in_order = CoverageMap(GRID, SENSOR)
    for o, p in batches:
        in_order.integrate(o, p)

    reversed_map = CoverageMap(GRID, SENSOR)
    for o, p in reversed(batches):
        reversed_map.integrate(o, p)

    shuffled = CoverageMap(GRID, SENSOR)
    for i in rng.permutation(len(deltas)):
        shuffled.apply(deltas[i])

    merged = CoverageMap(GRID, SENSOR)
    merged.apply(merge_deltas([deltas[i] for i in (5, 1, 3)], GRID.size))
    merged.apply(merge_deltas([deltas[i] for i in (0, 4, 2)], GRID.size))

    for other in (reversed_map, shuffled, merged):
        np.testing.assert_allclose(other.lam, in_order.lam, rtol=1e-5)
        np.testing.assert_allclose(other.eta, in_order.eta, rtol=1e-5, atol=1e-4)


def test_prior_counted_once_and_delta_from_prior_rebuilds_the_map():
    rng = np.random.default_rng(2)
    cmap = CoverageMap(GRID, SENSOR)
    for _ in range(3):
        cmap.integrate(*random_batch(rng))
    rebuilt = CoverageMap(GRID, SENSOR)
    rebuilt.apply(cmap.delta_from_prior())
    np.testing.assert_allclose(rebuilt.lam, cmap.lam, rtol=1e-5)
    lam0, eta0 = prior_information(SENSOR)
    untouched = ~cmap.known_mask()
    assert untouched.any()
    assert np.all(cmap.lam[untouched] == np.float32(lam0))
    assert np.all(cmap.eta[untouched] == np.float32(eta0))


def test_fused_map_marks_hits_covered_and_free_space_free():
    origin = np.array([0.05, 0.05, 0.05])
    wall = np.array([[1.05, y, z] for y in np.arange(-0.45, 0.5, 0.1) for z in np.arange(-0.15, 0.2, 0.1)])
    cmap = CoverageMap(GRID, SENSOR)
    for _ in range(3):
        cmap.integrate(origin, wall)
    mu = cmap.mean().reshape(GRID.shape)
    i_wall = GRID.index_of(np.array([1.05, 0.05, 0.05]))
    i_free = GRID.index_of(np.array([0.55, 0.05, 0.05]))
    assert mu[tuple(i_wall)] > 0.4
    assert mu[tuple(i_free)] < 0.05


def test_nonfinite_degenerate_and_outside_points_are_counted_and_the_rest_fused():
    origin = np.zeros(3)
    points = np.array(
        [
            [1.0, 0.2, 0.1],
            [np.nan, 0, 0],
            [np.inf, 1, 1],
            [0, 0, 0],
            [50.0, 0.0, 0.0],  # leaves the grid at x = 3: free space up to there
            [0.5, -0.5, 0.0],
        ]
    )
    result = batch_information(GRID, SensorModel(max_range=100), origin, points)
    assert (result.skipped_nonfinite, result.skipped_degenerate, result.skipped_outside) == (2, 1, 0)
    assert (result.rays, result.clipped) == (3, 1)
    outside_sensor = batch_information(GRID, SENSOR, np.array([5.0, 0.0, 0.0]), points[:1])
    assert (outside_sensor.rays, outside_sensor.skipped_outside, len(outside_sensor.delta)) == (0, 1, 0)


def test_a_ray_leaving_the_grid_gives_the_sub_box_what_a_larger_grid_gives_it():
    """Clipping at the boundary: the map of a sub-box gets exactly the larger map's information there."""
    sub = Grid((-1.0, -1.0, -0.5), 0.1, (20, 20, 10))
    sensor = SensorModel(max_range=5.0)
    rng = np.random.default_rng(3)
    origin = rng.uniform(-0.4, 0.4, 3) * [1, 1, 0.5]
    direction = rng.normal(size=(300, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    to_face = np.where(direction > 0, sub.hi - origin, sub.lo - origin) / direction
    exit_dist = to_face.min(axis=1)
    beyond = rng.uniform(0.3, 0.45, 300)  # past the margin (2 voxels), and inside GRID
    points = origin + direction * (exit_dist + beyond)[:, None]  # hits beyond the sub-box
    points[:20] = origin + direction[:20] * 0.5 * exit_dist[:20, None]  # and some hits inside it

    small = batch_information(sub, sensor, origin, points)
    large = batch_information(GRID, sensor, origin, points)
    assert small.clipped == 280 and small.skipped_outside == 0
    assert small.truncated == 0
    sub_offset = np.round((sub.lo - GRID.lo) / GRID.voxel).astype(int)
    sub_ijk = GRID.unflat(large.delta.idx.astype(np.int64)) - sub_offset
    in_sub = sub.contains_index(sub_ijk)
    expected_idx = sub.flat(sub_ijk[in_sub])
    order = np.argsort(expected_idx)
    np.testing.assert_array_equal(small.delta.idx, expected_idx[order])
    np.testing.assert_allclose(small.delta.dlam, large.delta.dlam[in_sub][order], rtol=1e-5)
    np.testing.assert_allclose(small.delta.deta, large.delta.deta[in_sub][order], rtol=1e-5, atol=1e-3)
    # Free space right up to the boundary: the voxels at the sub-box's faces were updated.
    faces = sub.unflat(small.delta.idx.astype(np.int64))
    assert np.any(faces == 0) and np.any(faces == np.asarray(sub.shape) - 1)


def test_a_wall_on_the_boundary_is_not_cleared_by_points_seen_just_beyond_it():
    """Points within the boundary margin beyond the grid are skipped, not cut: half the hits
    on a wall in the grid's outer layer (x 2.9-3.0) are seen 0.15 m too far, at x = 3.1."""
    origin = np.array([0.0, 0.0, 0.05])
    ys = np.linspace(-0.3, 0.3, 25)
    near = np.column_stack([np.full(25, 2.91), ys, np.full(25, 0.05)])
    far = np.column_stack([np.full(25, 3.1), ys, np.full(25, 0.05)])
    result = batch_information(GRID, SENSOR_5M, origin, np.vstack([near, far]))
    assert (result.rays, result.skipped_outside, result.clipped) == (25, 25, 0)
    cmap = CoverageMap(GRID, SENSOR_5M)
    cmap.apply(result.delta)
    wall = GRID.flat(GRID.index_of(near[12:13]))
    assert cmap.mean()[wall][0] > 0.5
    # Well beyond the margin (10% of the range, at least 2 voxels) a ray is cut and kept.
    far_and_near = np.array([[3.45, 0.0, 0.05], [3.25, 0.0, 0.05]])
    beyond = batch_information(GRID, SENSOR_5M, origin, far_and_near)
    assert (beyond.clipped, beyond.skipped_outside) == (1, 1)


def reference_apply(cmap: CoverageMap, delta: Delta) -> None:
    """CoverageMap.apply in numpy (the oracle of its compiled loop): indexed adds, np.add.at with repeats."""
    cmap.grid.check_flat(delta.idx)
    if not delta.is_finite():
        raise ValueError("delta holds NaN or inf information")
    idx = delta.idx.astype(np.int64)
    if len(idx) > 1 and not np.all(idx[1:] > idx[:-1]):
        np.add.at(cmap.lam, idx, delta.dlam)
        np.add.at(cmap.eta, idx, delta.deta)
    else:
        cmap.lam[idx] += delta.dlam
        cmap.eta[idx] += delta.deta


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_apply_equals_numpy_indexed_adds(dtype):
    rng = np.random.default_rng(5)
    fast, slow = CoverageMap(GRID, SENSOR), CoverageMap(GRID, SENSOR)
    for unique, index_type in ((True, np.uint32), (False, np.uint32), (False, np.int64), (True, np.int32)):
        for _ in range(3):
            idx = rng.integers(0, GRID.size, 5000)
            idx = np.unique(idx) if unique else idx
            dlam = (10 ** rng.uniform(-3, 6, len(idx))).astype(dtype)
            deta = (dlam * rng.uniform(-0.2, 1.2, len(idx))).astype(dtype)
            delta = Delta(idx.astype(index_type), dlam, deta)
            fast.apply(delta)
            reference_apply(slow, delta)
    np.testing.assert_array_equal(fast.lam, slow.lam)
    np.testing.assert_array_equal(fast.eta, slow.eta)
    assert fast.lam.dtype == np.float32 and fast.known_mask().sum() > 10_000


def test_bad_deltas_are_rejected_whole():
    cmap = CoverageMap(GRID, SENSOR)
    before = cmap.lam.copy()
    with pytest.raises(ValueError, match="out of grid"):
        cmap.apply(Delta(np.array([0, GRID.size], np.uint32), np.ones(2, np.float32), np.ones(2, np.float32)))
    with pytest.raises(ValueError, match="NaN"):
        cmap.apply(
            Delta(
                np.array([0, 1], np.uint32),
                np.array([1, np.nan], np.float32),
                np.ones(2, np.float32),
            )
        )
    with pytest.raises(ValueError, match="out of grid"):
        cmap.apply(Delta(np.array([3, -1], np.int64), np.ones(2, np.float32), np.ones(2, np.float32)))
    with pytest.raises(ValueError, match="NaN or inf"):
        cmap.apply(
            Delta(np.array([0, 1], np.uint32), np.ones(2, np.float32), np.array([1, np.inf], np.float32))
        )
    np.testing.assert_array_equal(cmap.lam, before)
