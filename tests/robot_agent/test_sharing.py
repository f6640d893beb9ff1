"""The agent's delta outbox: utility filter, numbering, acks, bounded unacked store."""

import math

import numpy as np
import pytest

from robot_agent.sharing import DeltaOutbox
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy_table import default_table
from swarm.map.grid import Grid
from tests.support.dense_outbox import DenseOutbox

GRID = Grid((0, 0, 0), 0.1, (10, 10, 4))


def delta(idx, dlam, mu=0.0) -> Delta:
    idx = np.asarray(idx, np.uint32)
    dlam = np.full(len(idx), dlam, np.float32)
    return Delta(idx, dlam, (dlam * mu).astype(np.float32))


def fused(cmap: CoverageMap, outbox: DeltaOutbox, d: Delta) -> None:
    cmap.apply(d)
    outbox.add(d)


def test_only_voxels_worth_share_min_bits_are_sent_and_the_rest_waits():
    cmap = CoverageMap(GRID)
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.5, table=default_table())
    fused(cmap, outbox, delta([1, 2], 400.0))  # sigma 0.05: several bits each
    fused(cmap, outbox, delta([7], 0.01))  # next to nothing
    seq, sent = outbox.take(cmap.lam, cmap.eta)
    assert seq == 1 and sent.idx.tolist() == [1, 2]
    # the team's entropy drop for each sent voxel is at least the threshold, computed independently
    table = default_table()
    lam0 = cmap.lam[[1, 2]] - sent.dlam
    drop = table(0.5 * np.ones(2), 1 / np.sqrt(lam0)) - table(cmap.mean([1, 2]), cmap.sigma([1, 2]))
    assert np.all(drop >= 0.5)
    assert outbox.take(cmap.lam, cmap.eta) is None  # voxel 7 is still not worth it
    for _ in range(200):  # ... until enough information piles up
        fused(cmap, outbox, delta([7], 5.0))
    seq, sent = outbox.take(cmap.lam, cmap.eta)
    assert seq == 2 and sent.idx.tolist() == [7]
    assert sent.dlam[0] == np.float32(0.01 + 200 * 5.0)


def test_flush_sends_everything_and_sums_equal_what_was_gathered():
    cmap = CoverageMap(GRID)
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.5, table=default_table())
    gathered = [delta([3, 4, 5], 0.02, 1.0), delta([4, 9], 300.0), delta([5], 0.05, 0.5)]
    for d in gathered:
        fused(cmap, outbox, d)
    sent = [outbox.take(cmap.lam, cmap.eta), outbox.take(cmap.lam, cmap.eta, flush=True)]
    sent = [d for _, d in filter(None, sent)]
    team = CoverageMap(GRID)
    for d in sent:
        team.apply(d)
    np.testing.assert_allclose(team.lam, cmap.lam, rtol=1e-6)
    np.testing.assert_allclose(team.eta, cmap.eta, rtol=1e-6, atol=1e-6)
    assert outbox.take(cmap.lam, cmap.eta, flush=True) is None


def test_acks_forget_deltas_and_the_store_is_bounded():
    cmap = CoverageMap(GRID)
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.0, table=default_table(), max_unacked=3)
    for i in range(5):
        fused(cmap, outbox, delta([i], 100.0))
        assert outbox.take(cmap.lam, cmap.eta)[0] == i + 1
    assert [s for s, _ in outbox.to_resend()] == [3, 4, 5]
    assert outbox.stats.dropped_unacked == 2
    outbox.acknowledge(4)
    assert [s for s, _ in outbox.to_resend()] == [5]


def reference_useful(table, lam, eta, pending_lam, pending_eta, touched, share_min_bits):
    """The utility filter judged afresh on every pending voxel (the outbox skips unchanged ones)."""
    idx = np.flatnonzero(touched)
    dlam, deta = pending_lam[idx], pending_eta[idx]
    lam_now, eta_now = lam[idx], eta[idx]
    lam_team = np.maximum(lam_now - dlam, np.float32(1e-12))
    h_team = table((eta_now - deta) / lam_team, 1.0 / np.sqrt(lam_team))
    h_now = table(eta_now / lam_now, 1.0 / np.sqrt(lam_now))
    return idx[np.abs(h_team - h_now) >= share_min_bits]


def dense_pending(outbox: DeltaOutbox) -> tuple[np.ndarray, np.ndarray]:
    """The outbox's pending information as arrays over the whole grid."""
    lam, eta = np.zeros(GRID.size, np.float32), np.zeros(GRID.size, np.float32)
    pending = outbox.pending()
    lam[pending.idx], eta[pending.idx] = pending.dlam, pending.deta
    return lam, eta


def test_skipping_unchanged_voxels_sends_what_judging_all_of_them_would():
    # own frames add small and large information, teammates' deltas change the map under
    # pending voxels (which can make them worth sending), and some steps change nothing
    rng = np.random.default_rng(2)
    table = default_table()
    cmap = CoverageMap(GRID)
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.5, table=table)
    sent_any = 0
    for step in range(60):
        if step % 3 != 2:
            idx = np.unique(rng.integers(0, GRID.size, 40))
            own = Delta(
                idx.astype(np.uint32),
                rng.lognormal(0.0, 2.0, len(idx)).astype(np.float32),
                rng.uniform(0, 1, len(idx)).astype(np.float32),
            )
            fused(cmap, outbox, own)
        if step % 4 == 1:
            idx = np.unique(rng.integers(0, GRID.size, 60))
            dl = rng.lognormal(1.0, 2.0, len(idx)).astype(np.float32)
            cmap.apply(Delta(idx.astype(np.uint32), dl, (dl * 0.1).astype(np.float32)))  # a teammate's
        pending = dense_pending(outbox)
        touched = np.zeros(GRID.size, bool)
        touched[outbox.pending().idx] = True
        expected = reference_useful(table, cmap.lam, cmap.eta, *pending, touched, 0.5)
        taken = outbox.take(cmap.lam, cmap.eta)
        got = np.zeros(0, np.int64) if taken is None else taken[1].idx.astype(np.int64)
        assert np.array_equal(got, expected), step
        if taken is not None:
            sent_any += 1
            assert np.array_equal(taken[1].dlam, pending[0][got]) and np.array_equal(
                taken[1].deta, pending[1][got]
            )
    assert sent_any >= 10


def test_what_is_held_back_is_bounded_and_the_most_valuable_goes_first():
    """max_held_bits: faint readings, each under share_min_bits, are held until together they
    are worth more than the bound; then the most valuable go out until at most half is held."""
    table = default_table()
    cmap = CoverageMap(GRID)
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.5, table=table, max_held_bits=4.0)
    # faint readings of different strength on 40 voxels: each worth well under 0.5 bit
    idx = np.arange(40)
    d = Delta(idx.astype(np.uint32), np.linspace(1.0, 7.0, 40).astype(np.float32), np.zeros(40, np.float32))
    fused(cmap, outbox, d)
    lam0 = cmap.lam - dense_pending(outbox)[0]
    worth = table(np.full(40, 0.5), 1 / np.sqrt(lam0[idx])) - table(cmap.mean(idx), cmap.sigma(idx))
    assert worth.max() < 0.5 and worth.sum() > 4.0  # the premise, computed independently
    seq, sent = outbox.take(cmap.lam, cmap.eta)
    # the sent voxels are the most valuable ones, and what stays held is worth at most half the bound
    held = np.setdiff1d(idx, sent.idx)
    assert worth[held].max() <= worth[sent.idx].min()
    assert worth[held].sum() <= 2.0 + 1e-4 < worth[held].sum() + worth[sent.idx].min()
    assert outbox.held_bits == pytest.approx(worth[held].sum(), rel=1e-4)
    assert outbox.stats.released_held == len(sent)
    assert outbox.take(cmap.lam, cmap.eta) is None  # under the bound now: nothing more goes


def test_without_a_bound_faint_readings_wait_for_the_flush():
    cmap = CoverageMap(GRID)
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.5, table=default_table())
    fused(cmap, outbox, delta(np.arange(40), 5.0))  # about 0.26 bit each
    assert outbox.take(cmap.lam, cmap.eta) is None and outbox.held_bits > 1.0
    _seq, sent = outbox.take(cmap.lam, cmap.eta, flush=True)
    assert len(sent) == 40 and outbox.held_bits == 0


def test_a_bound_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match="max_held_bits"):
        DeltaOutbox(GRID.size, share_min_bits=0.5, table=default_table(), max_held_bits=0.0)


def test_information_that_contradicts_the_team_belief_is_shared_too():
    """Worth is the change of the team's entropy either way: a voxel the team holds surely
    free, seen occupied, raises it; held back, the team map would be surer than the evidence."""
    table = default_table()
    cmap = CoverageMap(GRID)
    cmap.apply(delta([5, 6], 400.0, 0.0))  # the team: surely free (sigma 0.05 at 0)
    team = CoverageMap(GRID, cmap.sensor, cmap.lam.copy(), cmap.eta.copy())
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.5, table=table)
    fused(cmap, outbox, delta([5], 100.0, 1.0))  # this robot: occupied
    fused(cmap, outbox, delta([6], 100.0, 0.0))  # this robot agrees on 6: worth little
    change = table(cmap.mean([5, 6]), cmap.sigma([5, 6])) - table(team.mean([5, 6]), team.sigma([5, 6]))
    assert change[0] >= 0.5 and abs(change[1]) < 0.5  # the premise, computed independently
    _seq, sent = outbox.take(cmap.lam, cmap.eta)
    assert sent.idx.tolist() == [5]


@pytest.mark.parametrize("max_held_bits", [math.inf, 3.0])
def test_sparse_outbox_sends_what_the_dense_oracle_sends(max_held_bits):
    """Random own frames, teammates' deltas, takes and flushes: the outbox over its pending
    voxels gives, take after take, exactly the deltas of the filter over dense arrays."""
    rng = np.random.default_rng(7)
    table = default_table()
    cmap = CoverageMap(GRID)
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.5, table=table, max_held_bits=max_held_bits)
    oracle = DenseOutbox(GRID.size, 0.5, table, max_held_bits)
    sent = 0
    for step in range(300):
        idx = np.unique(rng.integers(0, GRID.size, int(rng.integers(1, 60))))
        dlam = rng.lognormal(-0.5, 2.0, len(idx)).astype(np.float32)
        d = Delta(idx.astype(np.uint32), dlam, (dlam * rng.uniform(0, 1, len(idx))).astype(np.float32))
        cmap.apply(d)
        if step % 5 != 3:  # else a teammate's
            outbox.add(d)
            oracle.add(d)
        flush = step % 37 == 36
        got, want = outbox.take(cmap.lam, cmap.eta, flush=flush), oracle.take(cmap.lam, cmap.eta, flush=flush)
        assert (got is None) == (want is None), step
        if got is not None:
            sent += 1
            np.testing.assert_array_equal(got[1].idx, want.idx)
            np.testing.assert_array_equal(got[1].dlam, want.dlam)
            np.testing.assert_array_equal(got[1].deta, want.deta)
        assert outbox.held_bits == pytest.approx(
            float(oracle.held_bits[oracle.touched].sum()), rel=1e-6, abs=1e-9
        )
    assert sent >= 50


def test_a_delta_that_is_not_sorted_or_outside_the_grid_is_refused():
    outbox = DeltaOutbox(GRID.size, share_min_bits=0.5, table=default_table())
    for idx in ([3, 2], [4, 4], [GRID.size]):
        with pytest.raises(ValueError, match="sorted, unique and under 400"):
            outbox.add(delta(idx, 1.0))
    assert len(outbox.pending()) == 0
