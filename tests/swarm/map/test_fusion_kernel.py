"""The compiled fusion kernel: equal to the numpy oracle, hit precedence, far rays, Numba's cache."""

import numpy as np
import pytest

from swarm.map import fusion, ray_batch
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import entropy_exact
from swarm.map.fusion import batch_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.map.voxel_information import LAM_MAX
from tests.support.fusion_oracle import reference_batch_information
from tests.support.numba_cache import second_run_cache_statistics

GRID = Grid((-2.0, -2.0, -1.0), 0.1, (40, 40, 20))
# (hit precedence, discretize, weighted)
OPTIONS = [
    (False, False, False),
    (True, False, False),
    (False, True, False),
    (True, True, False),
    (False, True, True),
    (True, True, True),
]


def assert_same(grid, sensor, origin, points, hit_precedence, discretize, weighted=False):
    ours = batch_information(grid, sensor, origin, points, hit_precedence, discretize, weighted)
    oracle = reference_batch_information(grid, sensor, origin, points, hit_precedence, discretize, weighted)
    for field in ("rays", "measurements", "voxel_updates", "truncated", "clipped"):
        assert getattr(ours, field) == getattr(oracle, field), field
    for field in ("skipped_nonfinite", "skipped_outside", "skipped_degenerate"):
        assert getattr(ours, field) == getattr(oracle, field), field
    np.testing.assert_array_equal(ours.delta.idx, oracle.delta.idx)
    np.testing.assert_allclose(ours.delta.dlam, oracle.delta.dlam, rtol=1e-5)
    # eta = mu * lam with mu in [0, 1]: compare on the scale of lam
    np.testing.assert_allclose(
        ours.delta.deta, oracle.delta.deta, rtol=1e-5, atol=1e-5 * ours.delta.dlam.max()
    )
    return ours


@pytest.mark.parametrize(("hit_precedence", "discretize", "weighted"), OPTIONS)
def test_random_rays_equal_the_numpy_oracle(hit_precedence, discretize, weighted):
    rng = np.random.default_rng(7)
    # (max range, hit range): the cut at max range, and at a shorter hit range
    for max_range, hit_range in ((1.2, None), (5.0, None), (5.0, 1.7), (1.2, 3.0)):
        sensor = SensorModel(max_range=max_range, hit_range=hit_range)
        for _ in range(3):
            origin = rng.uniform(-1.0, 1.0, 3) * [1, 1, 0.5]
            direction = rng.normal(size=(400, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            # near, far (beyond max range), beyond the grid, and a few NaN and zero-length rays
            points = origin + direction * rng.uniform(0.05, 3.5, (400, 1))
            points[:5] = np.nan
            points[5:8] = origin
            assert_same(GRID, sensor, origin, points, hit_precedence, discretize, weighted)


def adversarial_rays() -> tuple[np.ndarray, np.ndarray]:
    """Rays on grid planes: along axes, through edges and corners, leaving the grid, behind outside."""
    e = GRID.voxel
    lo, hi = GRID.lo, GRID.hi
    origin = lo + np.array([20, 20, 10]) * e  # exactly on a corner of eight voxels
    ends = []
    for axis in range(3):
        for sign in (1, -1):
            step = np.zeros(3)
            step[axis] = sign * e
            ends += [origin + 7 * step, origin + 7.5 * step, origin + 9.999999 * step]
    for v in ([1, 1, 0], [1, -1, 0], [1, 1, 1], [-1, 1, -1], [2, 1, 0], [3, 2, 1], [1, 0, 1]):
        ends += [origin + np.array(v) * 4 * e, origin + np.array(v) * 4.5 * e]
    # ends exactly on planes, edges and corners off the origin's planes
    ends += [
        origin + np.array([0.3, 0.5, 0.7]),
        origin + np.array([0.35, 0.5, 0.0]),
        origin + [0.5, 0.5, 0.5],
    ]
    # rays that leave the grid (cut at the boundary), far beyond it, and just beyond it (skipped)
    ends += [origin + [5.0, 0.0, 0.0], origin + [3.0, 3.0, 1.0], origin + [0.0, 0.0, -0.99999]]
    # the voxel behind the hit outside the grid: hits in the outer layer
    ends += [
        np.array([hi[0] - 0.01, 0.0, 0.0]),
        np.array([lo[0] + 0.01, 0.3, -0.2]),
        np.array([0.2, hi[1] - 1e-6, 0.1]),
    ]
    ends += [np.array([lo[0] + 1e-6, lo[1] + 1e-6, lo[2] + 1e-6])]
    return origin, np.array(ends)


@pytest.mark.parametrize(("hit_precedence", "discretize", "weighted"), OPTIONS)
def test_adversarial_rays_equal_the_numpy_oracle(hit_precedence, discretize, weighted):
    origin, ends = adversarial_rays()
    sensor = SensorModel(max_range=3.0)
    result = assert_same(GRID, sensor, origin, ends, hit_precedence, discretize, weighted)
    assert result.clipped >= 2 and result.truncated >= 1
    # the same rays from a sensor inside a voxel, and from the grid's corner voxel
    for start in (origin + [0.013, 0.021, 0.037], GRID.lo + 1e-9):
        assert_same(GRID, sensor, start, ends, hit_precedence, discretize, weighted)


def test_hit_precedence_on_a_hand_built_batch():
    """Ray A ends in voxel V; ray B passes through V to a farther wall. V keeps A's return only."""
    grid = Grid((0.0, 0.0, 0.0), 0.1, (20, 5, 5))
    sensor = SensorModel(max_range=5.0)
    origin = np.array([0.05, 0.25, 0.25])
    a = np.array([0.55, 0.25, 0.25])  # voxel (5, 2, 2), at its centre
    b = np.array([1.25, 0.25, 0.25])  # voxel (12, 2, 2)
    v = int(grid.flat(np.array([5, 2, 2])))
    behind_a = int(grid.flat(np.array([6, 2, 2])))

    def at(result, flat):
        k = int(np.searchsorted(result.delta.idx, flat))
        return float(result.delta.dlam[k]), float(result.delta.deta[k])

    # eq. 14 by hand: V's centre is A's hit (d_l = d = 0.5 m): mu = 1/2, sigma = sigma_s(0.5)
    lam_a = 1.0 / (sensor.sigma_min + sensor.zeta * 0.5) ** 2
    # from B at d = 1.2 m, V (d_l = 0.5) is free: mu = 0, sigma = sigma_s(1.2) exp(-(0.7 - 0.05) / tau)
    lam_b = 1.0 / ((sensor.sigma_min + sensor.zeta * 1.2) * np.exp(-0.65 / sensor.tau)) ** 2

    kept = batch_information(grid, sensor, origin, np.array([a, b]), hit_precedence=True)
    lam, eta = at(kept, v)
    assert lam == pytest.approx(lam_a, rel=1e-5) and eta / lam == pytest.approx(0.5, abs=1e-5)

    paper = batch_information(grid, sensor, origin, np.array([a, b]), hit_precedence=False)
    lam, eta = at(paper, v)
    assert lam == pytest.approx(lam_a + lam_b, rel=1e-5)
    assert eta / lam < 0.3  # B's free-space update outweighs A's return: the surface is lost

    # the voxel behind A still gets B's free-space update and A's behind update, either way
    assert at(kept, behind_a) == at(paper, behind_a)
    assert kept.voxel_updates == paper.voxel_updates - 1


@pytest.mark.parametrize("far", [1e3, 1e6, 1e9])
def test_far_points_give_finite_information(far):
    rng = np.random.default_rng(3)
    direction = rng.normal(size=(50, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    origin = np.zeros(3)
    for max_range in (5.0, 1e4):  # 1e4 m: a max range whose eq. 14 would overflow unbounded
        sensor = SensorModel(max_range=max_range)
        result = batch_information(GRID, sensor, origin, direction * far)
        assert result.delta.is_finite() and len(result.delta) > 0
        assert result.delta.dlam.max() <= np.float32(LAM_MAX) * 50
        CoverageMap(GRID, sensor).apply(result.delta)  # the map accepts it


def test_a_mix_of_near_and_far_points_fuses_the_near_and_counts_the_far():
    rng = np.random.default_rng(4)
    origin = np.array([0.03, 0.02, 0.01])
    direction = rng.normal(size=(866, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    near = origin + direction * rng.uniform(0.3, 0.9, (866, 1))
    far = origin + direction[:5] * np.array([[1e3], [1e6], [1e9], [1e12], [1e300]])
    sensor = SensorModel(max_range=5.0)
    mixed = batch_information(GRID, sensor, origin, np.vstack([near, far]))
    assert mixed.rays == 871 and mixed.truncated == 5 and mixed.delta.is_finite()
    alone = batch_information(GRID, sensor, origin, near)
    # every near ray is fused as it would be alone: with hit precedence the far rays' free space
    # leaves the near hits' voxels untouched, and adds to the rest
    hit = np.unique(GRID.flat(GRID.index_of(near)))
    np.testing.assert_allclose(
        mixed.delta.dlam[np.searchsorted(mixed.delta.idx, hit)],
        alone.delta.dlam[np.searchsorted(alone.delta.idx, hit)],
        rtol=1e-6,
    )
    assert set(alone.delta.idx.tolist()) <= set(mixed.delta.idx.tolist())
    assert mixed.voxel_updates > alone.voxel_updates


def test_the_kernel_restores_its_scratch_space_and_a_second_batch_equals_the_oracle():
    """The brick table is all -1 and the block pool all zero after a batch (with hit marks and
    far rays among it), so the next batch on the same thread starts clean."""
    rng = np.random.default_rng(5)
    sensor = SensorModel(max_range=5.0)
    origin = np.array([0.11, -0.07, 0.02])
    direction = rng.normal(size=(600, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = origin + direction * rng.uniform(0.05, 3.5, (600, 1))
    points[:3] = origin + direction[:3] * 1e9
    batch_information(GRID, sensor, origin, points, hit_precedence=True)
    table, (gains, sums) = fusion._local.table, fusion._local.pool
    assert np.all(table == -1)
    assert not np.any(gains) and not np.any(sums)
    assert_same(GRID, sensor, origin[::-1], points[::-1] * 0.5, True, False)


def test_rays_ordered_by_direction_are_a_stable_permutation_grouped_by_cell():
    rng = np.random.default_rng(11)
    start = np.array([20.5, 20.5, 10.5])
    ends = start + rng.normal(0.0, 8.0, (5_000, 3))
    ends[:50] = start + [3.0, 0.0, 0.0]  # repeats, to check stability
    d = np.arange(len(ends), dtype=np.float64)  # the original position, carried along
    returned = rng.uniform(size=len(ends)) < 0.5
    weight = rng.uniform(1.0, 9.0, len(ends))
    out = ray_batch.order_by_direction(start, ends, d, returned, weight, 32)
    out_ends, out_d, out_returned, out_weight = out
    order = out_d.astype(np.int64)
    assert sorted(order.tolist()) == list(range(len(ends)))  # a permutation
    assert np.array_equal(out_ends, ends[order]) and np.array_equal(out_returned, returned[order])
    assert np.array_equal(out_weight, weight[order])
    v = ends[order] - start
    n = np.abs(v).sum(axis=1)
    a = np.minimum(((v[:, 0] / n + 1) * 16).astype(int), 31)
    b = np.minimum(((v[:, 1] / n + 1) * 16).astype(int), 31)
    cells = ((v[:, 2] > 0) * 32 + a) * 32 + b
    assert np.all(np.diff(cells) >= 0)  # grouped by cell, cells in order
    same_cell = np.diff(cells) == 0
    assert np.all(np.diff(order)[same_cell] > 0)  # stable within a cell


@pytest.mark.slow
def test_a_second_process_loads_the_kernels_from_numbas_cache():
    """Numba's own statistics: a fresh interpreter compiles nothing and hits the cache."""
    stats = second_run_cache_statistics(
        "import numpy as np\n"
        "from swarm.map import fusion_kernel as k, ray_batch as rb\n"
        "from swarm.map.fusion import batch_information\n"
        "from swarm.map.grid import Grid\n"
        "from swarm.map.sensor_model import SensorModel\n"
        "g = Grid((0, 0, 0), 0.1, (10, 10, 10))\n"
        "s = SensorModel(discretize=True, weighted=True)\n"
        "batch_information(g, s, np.full(3, 0.05), np.full((3, 3), 0.5))",
        "(rb.prepare_rays, rb.discretize_rays, rb.order_by_direction, k.blocks_bound, k.fuse_rays)",
    )
    assert len(stats) == 5
    for name, (hits, misses) in stats.items():
        assert hits >= 1 and misses == 0, (name, stats)


def camera_frame(origin: np.ndarray, width: int = 160, height: int = 120) -> np.ndarray:
    """A pinhole camera's points (60 deg wide, looking along +x) on a wall 1.7 m ahead and the floor."""
    f = (width / 2) / np.tan(np.radians(30))
    u, v = np.meshgrid(np.arange(width) - (width - 1) / 2, np.arange(height) - (height - 1) / 2)
    rays = np.column_stack([np.full(u.size, f), -u.ravel(), -v.ravel()])
    t_wall = (1.7 - origin[0]) / rays[:, 0]
    with np.errstate(divide="ignore"):
        t_floor = np.where(rays[:, 2] < 0, (-0.9 - origin[2]) / rays[:, 2], np.inf)
    return origin + rays * np.minimum(t_wall, t_floor)[:, None]


def test_weighted_measurements_carry_what_their_rays_would():
    """Rays from one origin to one end voxel cross nearly the same voxels: one weighted
    measurement per end voxel gives the frame's information and map of one per ray."""
    origin = np.array([0.03, 0.02, 0.01])
    points = camera_frame(origin)
    sensor = SensorModel(max_range=5.0)
    per_ray = batch_information(GRID, sensor, origin, points, True, False, False)
    weighted = batch_information(GRID, sensor, origin, points, True, True, True)
    plain = batch_information(GRID, sensor, origin, points, True, True, False)
    assert weighted.measurements * 5 < per_ray.measurements
    assert weighted.voxel_updates * 3 < per_ray.voxel_updates
    total = float(per_ray.delta.dlam.sum(dtype=np.float64))
    assert float(weighted.delta.dlam.sum(dtype=np.float64)) == pytest.approx(total, rel=0.01)
    assert float(plain.delta.dlam.sum(dtype=np.float64)) < 0.5 * total  # OctoMap's discretize: far less
    maps = {}
    for name, result in (("per_ray", per_ray), ("weighted", weighted), ("plain", plain)):
        cmap = CoverageMap(GRID, sensor)
        cmap.apply(result.delta)
        maps[name] = cmap
    seen = np.union1d(per_ray.delta.idx, weighted.delta.idx)
    prior = CoverageMap(GRID, sensor)
    h0 = entropy_exact(prior.mean(seen), prior.sigma(seen)).sum()
    gain = {name: h0 - entropy_exact(m.mean(seen), m.sigma(seen)).sum() for name, m in maps.items()}
    occupied = {name: m.mean(seen) > 0.5 for name, m in maps.items()}
    # the entropy the frame removes: 2 % less weighted (the few voxels only side rays cross), half plain
    assert gain["weighted"] == pytest.approx(gain["per_ray"], rel=0.05)
    assert gain["plain"] < 0.6 * gain["per_ray"]
    assert np.mean(occupied["weighted"] == occupied["per_ray"]) > 0.98
