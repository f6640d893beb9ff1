"""Voxel entropy (eq. 16-17), its lookup table, expected coverage and the entropy cache."""

import numpy as np
import pytest
from scipy import integrate, stats

from swarm.map.entropy import BINS, MU_LIM, SIGMA_MAX, SIGMA_MIN, entropy_exact, expected_coverage, moments
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import EntropyTable, default_table, entropy_info

W = 1.0 / BINS


@pytest.fixture(scope="module")
def table() -> EntropyTable:
    return default_table()


# -- independent references ---------------------------------------------------------
def _shifted_density(mu: float, sigma: float):
    """The belief's density on [0, 1] divided by its value at the point of [0, 1] nearest mu.

    It is <= 1 everywhere and 1 somewhere in [0, 1], so nothing underflows however far
    outside mu lies; normalising afterwards removes the factor.
    """
    c0 = min(max(mu, 0.0), 1.0)

    def f(c):
        return np.exp(-((c - mu) ** 2 - (c0 - mu) ** 2) / (2 * sigma * sigma))

    return f


def reference_entropy_quad(mu: float, sigma: float) -> float:
    """Bin masses by adaptive quadrature of the (shifted) density over each bin."""
    f = _shifted_density(mu, sigma)
    masses = []
    for i in range(BINS):
        a, b = i * W, (i + 1) * W
        pts = [mu] if a < mu < b else None
        m, _ = integrate.quad(f, a, b, points=pts, epsabs=1e-15, epsrel=1e-12, limit=200)
        masses.append(m)
    p = np.array(masses) / np.sum(masses)
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())


def reference_entropy_truncnorm(mu: float, sigma: float) -> float:
    """Bin masses as differences of scipy.stats.truncnorm's CDF."""
    a, b = (0 - mu) / sigma, (1 - mu) / sigma
    p = np.diff(stats.truncnorm.cdf(np.arange(BINS + 1) * W, a, b, loc=mu, scale=sigma))
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())


def reference_coverage_quad(mu: float, sigma: float) -> float:
    f = _shifted_density(mu, sigma)
    pts = [min(max(mu, 0.0), 1.0)]
    z, _ = integrate.quad(f, 0, 1, points=pts, epsabs=1e-15, epsrel=1e-12, limit=400)
    m, _ = integrate.quad(lambda c: c * f(c), 0, 1, points=pts, epsabs=1e-15, epsrel=1e-12, limit=400)
    return m / z


# -- entropy_exact -------------------------------------------------------------------
def test_prior_is_about_seven_bits(table):
    assert 6.99 < entropy_exact(0.5, 2.5) <= 7.0
    assert 6.99 < float(table(0.5, 2.5)) <= 7.0
    # a truly flat belief is exactly 7 bits; a point mass inside a bin is 0
    assert entropy_exact(0.5, SIGMA_MAX) == pytest.approx(7.0, abs=1e-4)
    assert entropy_exact(0.5 + 0.5 * W, 1e-4) == pytest.approx(0.0, abs=1e-12)
    # on a bin edge a narrow belief splits evenly over two bins
    assert entropy_exact(0.5, 1e-4) == pytest.approx(1.0, abs=1e-9)


def test_entropy_is_between_0_and_7_bits(table):
    rng = np.random.default_rng(3)
    mu = rng.uniform(-5, 6, 20_000)
    sigma = np.exp(rng.uniform(np.log(SIGMA_MIN), np.log(SIGMA_MAX), mu.size))
    h = entropy_exact(mu, sigma)
    assert np.all(np.isfinite(h))
    assert h.min() >= -1e-12 and h.max() <= 7.0 + 1e-12
    t = table(mu, sigma)
    assert t.min() >= -1e-3 and t.max() <= 7.0 + 1e-3


@pytest.mark.parametrize("mu", [0.0, 0.05, 0.3, 0.5, 0.123, 0.9, 1.0, 1 / 128, 0.5 + 0.5 / 128])
def test_entropy_decreases_as_sigma_shrinks(table, mu):
    sigma = np.geomspace(SIGMA_MAX, SIGMA_MIN, 300)
    h = entropy_exact(mu, sigma)
    assert np.all(np.diff(h) <= 1e-12)
    assert h[0] > 6.99 and h[-1] < 1.0 + 1e-9
    assert np.all(np.diff(table(np.full(sigma.shape, mu), sigma)) <= 0.02)


POINTS = [
    (0.5, 2.5),
    (0.3, 0.1),
    (-0.2, 0.1),
    (1.3, 0.05),
    (0.001, 0.002),
    (-0.01, 0.01),
    (1 / 128 + 1e-5, 1e-4),
    (0.77, 0.02),
    (0.2, 40.0),
    (0.5 + 0.3 * W, 5e-4),  # nearest edge 4.7 sigma away: H ~ 1e-5, not 0
]


@pytest.mark.parametrize("mu,sigma", POINTS)
def test_exact_matches_truncnorm(mu, sigma):
    assert entropy_exact(mu, sigma) == pytest.approx(reference_entropy_truncnorm(mu, sigma), abs=1e-9)


@pytest.mark.parametrize(
    "mu,sigma",
    POINTS[:4] + [POINTS[-1], (-3.0, 0.5), (-30.0, 0.5), (4.0, 0.3), (-45.0, 7.0), (65.0, 1.0), (-0.3, 0.01)],
)
def test_exact_matches_quadrature(mu, sigma):
    """Including means far outside [0, 1], where the normaliser underflows."""
    assert entropy_exact(mu, sigma) == pytest.approx(reference_entropy_quad(mu, sigma), abs=1e-8)


def test_exact_far_outside_is_finite_and_concentrates():
    mu = np.array([-50.0, 51.0, -64.0, 1e6, -np.inf, np.inf])
    h = entropy_exact(mu, 1e-4)
    assert np.all(np.isfinite(h)) and np.all(h < 1e-9)
    # a wide belief far outside is still spread (rate |mu| / sigma^2 is small)
    assert entropy_exact(-50.0, 60.0) > 6.9
    # symmetry about 1/2
    assert entropy_exact(-0.37, 0.2) == pytest.approx(entropy_exact(1.37, 0.2), abs=1e-12)


# -- the lookup table ----------------------------------------------------------------
def _max_table_error(table, mu, sigma):
    mu = np.clip(mu, -MU_LIM, 1 + MU_LIM).astype(np.float32)
    sigma = np.clip(sigma, SIGMA_MIN, SIGMA_MAX).astype(np.float32)
    # the table works in float32: compare with the exact entropy of the same float32 inputs
    err = np.abs(table(mu, sigma) - entropy_exact(mu.astype(np.float64), sigma.astype(np.float64)))
    i = int(np.argmax(err))
    return float(err[i]), float(mu[i]), float(sigma[i])


def _adversarial(rng, n):
    log_s = rng.uniform(np.log(SIGMA_MIN), np.log(SIGMA_MAX), n)
    tiny = np.exp(rng.uniform(np.log(SIGMA_MIN), np.log(2e-3), n))
    edges = rng.integers(0, BINS + 1, n) / BINS
    sets = {
        "whole range": (rng.uniform(-MU_LIM, 1 + MU_LIM, n), np.exp(log_s)),
        "near 0 and 1": (
            rng.choice([0.0, 1.0], n) + rng.normal(size=n) * np.exp(log_s) * rng.uniform(0, 6, n),
            np.exp(log_s),
        ),
        "bin edges, tiny sigma": (edges + rng.normal(size=n) * tiny * rng.uniform(0, 5, n), tiny),
        "inside, tiny sigma": (rng.uniform(-0.02, 1.02, n), tiny),
        "huge sigma": (rng.uniform(-MU_LIM, 1 + MU_LIM, n), np.exp(rng.uniform(0, np.log(SIGMA_MAX), n))),
        "far outside": (
            rng.choice([-1, 1], n) * np.exp(rng.uniform(0, np.log(MU_LIM), n)) + 0.5,
            np.exp(log_s),
        ),
        "regime boundary": (
            rng.uniform(-0.1, 1.1, n),
            np.exp(rng.uniform(np.log(0.3 * W), np.log(3 * W), n)),
        ),
        "saturation knee": (rng.uniform(-0.5, 1.5, n), np.exp(rng.uniform(np.log(0.05), np.log(1.0), n))),
    }
    return sets


def test_table_within_a_hundredth_of_a_bit(table):
    rng = np.random.default_rng(11)
    worst = {}
    for name, (mu, sigma) in _adversarial(rng, 12_000).items():
        worst[name] = _max_table_error(table, mu, sigma)
    # exact corners and edges of the domain
    mu = np.array([0.0, 1.0, 0.5, -MU_LIM, 1 + MU_LIM, W, 1 - W, 0.5 + 0.5 * W] * 2)
    sigma = np.repeat([SIGMA_MIN, SIGMA_MAX], 8)
    worst["corners"] = _max_table_error(table, mu, sigma)
    bad = {k: v for k, v in worst.items() if not v[0] < 0.01}
    assert not bad, f"table error >= 0.01 bit: {bad}"


def test_table_shapes_dtypes_and_clamps(table):
    h = table(np.full((4, 5, 6), 0.5, dtype=np.float64), 2.5)
    assert h.shape == (4, 5, 6) and h.dtype == np.float32
    assert np.allclose(h, entropy_exact(0.5, 2.5), atol=0.01)
    assert table(np.float32(0.5), np.float32(2.5)).shape == ()
    # clamps: mu beyond the range reads as the bound, sigma <= 0 as SIGMA_MIN
    assert table(-1e9, 1.0) == pytest.approx(table(-MU_LIM, 1.0), abs=1e-6)
    assert table(0.25 + 0.5 * W, 0.0) == pytest.approx(0.0, abs=0.01)
    assert np.isnan(table(np.nan, 1.0))
    # a small chunk size gives the same answer
    rng = np.random.default_rng(2)
    mu = rng.uniform(-1, 2, 1000)
    sigma = np.exp(rng.uniform(-9, 3, 1000))
    small = EntropyTable(chunk=97)
    assert np.array_equal(small(mu, sigma), table(mu, sigma))


def test_default_table_is_shared():
    assert default_table() is default_table()


# -- expected coverage ---------------------------------------------------------------
@pytest.mark.parametrize(
    "mu,sigma",
    [
        (0.5, 2.5),
        (0.3, 0.1),
        (-0.2, 0.1),
        (1.3, 0.05),
        (0.001, 0.002),
        (0.0, 0.3),
        (0.999, 1e-3),
        (-3.0, 0.5),
        (-10.0, 3.0),
        (60.0, 1.0),
        (0.2, 100.0),
        (-0.5, 0.02),
    ],
)
def test_expected_coverage_matches_quadrature(mu, sigma):
    assert expected_coverage(mu, sigma) == pytest.approx(reference_coverage_quad(mu, sigma), abs=1e-10)


def test_expected_coverage_tails_and_symmetry():
    # far outside with a narrow belief: the truncated belief is exponential with rate
    # |mu| / sigma^2 at the bound, so E[C] -> sigma^2 / |mu| (relative correction ~ sigma^2/mu^2)
    for mu, sigma in [(-50.0, 1e-4), (-64.0, 1e-3), (-5.0, 0.01)]:
        e = float(expected_coverage(mu, sigma))
        assert e == pytest.approx(sigma * sigma / abs(mu), rel=1e-4)
        assert float(expected_coverage(1 - mu, sigma)) == pytest.approx(1 - e, abs=1e-12)
    rng = np.random.default_rng(4)
    mu = rng.uniform(-60, 61, 10_000)
    sigma = np.exp(rng.uniform(np.log(SIGMA_MIN), np.log(SIGMA_MAX), mu.size))
    e = expected_coverage(mu, sigma)
    assert np.all((e >= 0) & (e <= 1))
    assert np.allclose(e + expected_coverage(1 - mu, sigma), 1.0, atol=1e-12)
    # increasing in mu at fixed sigma
    grid = np.linspace(-3, 4, 2001)
    assert np.all(np.diff(expected_coverage(grid, 0.3)) >= -1e-15)
    # exactly at a bound with a tiny sigma: half-normal mean sigma * sqrt(2/pi)
    assert float(expected_coverage(0.0, 1e-5)) == pytest.approx(1e-5 * np.sqrt(2 / np.pi), rel=1e-9)


# -- information form ----------------------------------------------------------------
def test_moments_and_entropy_info(table):
    lam = np.array([4.0, 0.16, 1e6], dtype=np.float32)
    eta = np.array([2.0, 0.08, -3e5], dtype=np.float32)
    mu, sigma = moments(lam, eta)
    assert mu.dtype == np.float32 and sigma.dtype == np.float32
    assert np.allclose(mu, [0.5, 0.5, -0.3]) and np.allclose(sigma, [0.5, 2.5, 1e-3])
    assert np.array_equal(entropy_info(lam, eta, table), table(mu, sigma))
    mu64, sigma64 = moments(4.0, 1.0)
    assert float(mu64) == 0.25 and float(sigma64) == 0.5


# -- the cache -----------------------------------------------------------------------
def test_cache_incremental_total_matches_full_recomputation(table):
    rng = np.random.default_rng(7)
    n = 5000
    mu = np.full(n, 0.5, dtype=np.float32)
    sigma = np.full(n, 2.5, dtype=np.float32)
    cache = EntropyCache(table(mu, sigma), table=table, resum_every=10**12)  # never resums
    assert cache.total == pytest.approx(n * float(table(0.5, 2.5)), rel=1e-9)
    for _ in range(300):
        idx = rng.integers(0, n, rng.integers(1, 200))  # repeats allowed
        new_mu = rng.uniform(-2, 3, idx.size).astype(np.float32)
        new_sigma = np.exp(rng.uniform(-10, 1, idx.size)).astype(np.float32)
        cache.update(idx, new_mu, new_sigma)
        mu[idx] = new_mu  # numpy assignment: the last repeat wins, as in the cache
        sigma[idx] = new_sigma
    full = table(mu, sigma)
    assert np.array_equal(cache.values, full)
    assert cache.total == pytest.approx(float(np.sum(full, dtype=np.float64)), abs=1e-6)
    assert cache.total < 0.9 * n * 7


def test_cache_resums_periodically(table):
    cache = EntropyCache(np.full(100, 7.0, dtype=np.float32), table=table, resum_every=50)
    cache.total += 1.0  # simulated drift
    cache.update(np.arange(30), 0.5, 2.5)
    assert cache.total != pytest.approx(float(cache.values.sum(dtype=np.float64)), abs=1e-3)
    cache.update(np.arange(30, 60), 0.5, 2.5)  # 60 >= 50 recomputed voxels: resum
    assert cache.total == pytest.approx(float(cache.values.sum(dtype=np.float64)), abs=1e-9)


def test_cache_constructors_and_errors(table):
    lam = np.full(10, 0.16, dtype=np.float32)
    eta = np.full(10, 0.08, dtype=np.float32)
    cache = EntropyCache.from_information(lam, eta, table=table)
    assert len(cache) == 10 and cache.total == pytest.approx(10 * float(table(0.5, 2.5)))
    cache.update_information([3], np.float32(1e6), np.float32(0.0))
    assert cache.values[3] == pytest.approx(0.0, abs=1e-3)
    with pytest.raises(IndexError):
        cache.update([10], 0.5, 1.0)
    assert cache.update([], [], []) == cache.total


def test_refilling_a_cache_in_place_equals_a_fresh_cache_of_the_new_beliefs():
    rng = np.random.default_rng(5)
    lam0 = rng.uniform(1.0, 50.0, 500).astype(np.float32)
    cache = EntropyCache.from_information(lam0, lam0 * 0.3)
    values = cache.values  # a holder's reference: it must see the new entropies
    lam = rng.uniform(1.0, 400.0, 500).astype(np.float32)
    eta = lam * rng.uniform(0.0, 1.0, 500).astype(np.float32)
    total = cache.refill_information(lam, eta)
    fresh = EntropyCache.from_information(lam, eta)
    assert values is cache.values
    assert np.array_equal(values, fresh.values)
    assert total == cache.total == fresh.total
