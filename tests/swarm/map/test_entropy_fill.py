"""EntropyCache fills a whole map a chunk at a time: the values and total of one whole-map pass."""

import numpy as np
import pytest

from swarm.map.entropy import moments
from swarm.map.entropy_cache import FILL_CHUNK, EntropyCache
from swarm.map.entropy_table import default_table


def _map(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """lam, eta float32 (n,): prior-like voxels, observed ones, near-certain ones."""
    rng = np.random.default_rng(seed)
    scale = rng.uniform(0.5, 2.0, n).astype(np.float32)
    lam = rng.choice([4.0, 0.5, 30.0, 2000.0], n).astype(np.float32) * scale
    mu = rng.uniform(-0.5, 1.5, n).astype(np.float32)
    return lam, (mu * lam).astype(np.float32)


def whole_map_pass(lam: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """The oracle: the table over the whole map's moments at once."""
    return default_table()(*moments(lam, eta))


@pytest.mark.parametrize("n", [1, FILL_CHUNK - 1, 2 * FILL_CHUNK + 17])
def test_from_information_equals_one_whole_map_pass(n):
    lam, eta = _map(n)
    cache = EntropyCache.from_information(lam, eta)
    expected = whole_map_pass(lam, eta)
    assert cache.values.dtype == np.float32
    np.testing.assert_array_equal(cache.values, expected)
    assert cache.total == float(np.sum(expected, dtype=np.float64))
    assert cache.table is default_table()


def test_refill_equals_one_whole_map_pass_and_tells_every_voxel():
    n = 3 * FILL_CHUNK + 5
    lam, eta = _map(n, 1)
    told = []
    cache = EntropyCache.from_information(lam, eta, on_change=told.append)
    assert told == []  # building the cache is not a change
    lam2, eta2 = _map(n, 2)
    total = cache.refill_information(lam2.reshape(1, -1), eta2)  # any shape of the map's size
    expected = whole_map_pass(lam2, eta2)
    np.testing.assert_array_equal(cache.values, expected)
    assert total == cache.total == float(np.sum(expected, dtype=np.float64))
    assert told == [None]


def test_sizes_must_match():
    cache = EntropyCache.from_information(*_map(10))
    lam, eta = _map(9)
    with pytest.raises(ValueError, match="sizes differ"):
        cache.refill_information(lam, eta)
