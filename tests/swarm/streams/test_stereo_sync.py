"""Pairing a live camera's left and right images by stamp (``swarm.streams.stereo_sync``)."""

from __future__ import annotations

from swarm.streams.stereo_sync import StereoSync


def test_pairs_by_stamp_within_the_tolerance_and_counts_what_never_pairs():
    sync = StereoSync(tolerance=0.005, depth=3)
    assert sync.add("left", 1.000, "L1") == []
    assert sync.add("right", 1.002, "R1") == [(1.000, "L1", "R1")]
    assert sync.add("right", 1.100, "R2") == []  # its left image is lost
    assert sync.add("left", 1.200, "L3") == []
    assert sync.add("right", 1.201, "R3") == [(1.200, "L3", "R3")]
    assert sync.dropped == {"right image with no left image within 0.005 s": 1}
    assert sync.waiting() == 0


def test_the_nearest_partner_wins_and_a_full_queue_drops_its_oldest():
    sync = StereoSync(tolerance=0.01, depth=2)
    sync.add("right", 2.000, "Ra")
    sync.add("right", 2.008, "Rb")
    assert sync.add("left", 2.007, "L") == [(2.007, "L", "Rb")]  # Ra is older than Rb: dropped
    for k in range(4):
        sync.add("left", 3.0 + k, f"L{k}")  # no right images at all: the queue keeps the newest 2
    assert sync.waiting() == 2
    assert sync.dropped == {"right image with no left image within 0.01 s": 1,
                            "left image with no right image within 0.01 s": 2}  # fmt: skip


def test_images_arriving_out_of_order_still_pair():
    sync = StereoSync(tolerance=0.001)
    sync.add("left", 5.0, "L5")
    sync.add("left", 4.0, "L4")
    assert sync.add("right", 4.0, "R4") == [(4.0, "L4", "R4")]
    assert sync.add("right", 5.0, "R5") == [(5.0, "L5", "R5")]
    assert not sync.dropped
