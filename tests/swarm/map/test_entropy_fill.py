"""swarm.map.entropy_fill: the chunked fill gives EntropyCache's own values and totals, bit for bit."""

import numpy as np
import pytest

from swarm.map import entropy_fill
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import default_table


def _map(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """lam, eta float32 (n,): prior-like voxels, observed ones, near-certain ones."""
    rng = np.random.default_rng(seed)
    lam = rng.choice([4.0, 0.5, 30.0, 2000.0], n).astype(np.float32) * rng.uniform(0.5, 2.0, n).astype(
        np.float32
    )
    mu = rng.uniform(-0.5, 1.5, n).astype(np.float32)
    return lam, (mu * lam).astype(np.float32)


@pytest.mark.parametrize("n", [1, entropy_fill.CHUNK - 1, 2 * entropy_fill.CHUNK + 17])
def test_entropy_cache_equals_from_information(n):
    lam, eta = _map(n)
    ours = entropy_fill.entropy_cache(lam, eta, table=default_table())
    theirs = EntropyCache.from_information(lam, eta, table=default_table())
    assert ours.values.dtype == np.float32
    np.testing.assert_array_equal(ours.values, theirs.values)
    assert ours.total == theirs.total
    assert ours.table is theirs.table


def test_refill_equals_refill_information_and_tells_every_voxel():
    n = 3 * entropy_fill.CHUNK + 5
    lam, eta = _map(n, 1)
    told_ours, told_theirs = [], []
    ours = entropy_fill.entropy_cache(lam, eta, on_change=told_ours.append)
    theirs = EntropyCache.from_information(lam, eta, on_change=told_theirs.append)
    lam2, eta2 = _map(n, 2)
    total = entropy_fill.refill_entropy(ours, lam2, eta2)
    assert total == theirs.refill_information(lam2, eta2)
    np.testing.assert_array_equal(ours.values, theirs.values)
    assert told_ours == told_theirs == [None]


def test_sizes_must_match():
    lam, eta = _map(10)
    with pytest.raises(ValueError, match="sizes differ"):
        entropy_fill.fill_entropy(np.zeros(9, np.float32), lam, eta, default_table())
