"""Floor plans: project YAML walls and boxes, ROS map_server maps merged into rectangles."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from scipy import ndimage

from swarm.formats.floor_plan import (
    FloorPlanError,
    load_floor_plan,
    load_ros_map,
    merge_cells,
)
from swarm.formats.map_image import read_map_image
from swarm.formats.ros_map import RosMap
from tests.support.paths import CONFIGS

MAPS = CONFIGS / "maps"


def test_project_yaml_walls_and_boxes(tmp_path):
    path = tmp_path / "plan.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "wall_height": 2.5,
                "walls": [
                    {"points": [[0, 0], [4, 0], [4, 3]], "thickness": 0.2},
                    {"points": [[0, 3], [0, 0]], "height": 1.0},
                ],
                "boxes": [{"centre": [2, 1.5], "size": [1.0, 0.5], "height": 0.7, "yaw": np.pi / 2}],
            }
        )
    )
    plan = load_floor_plan(path)
    assert plan.kinds == ["wall", "wall", "wall", "box"]
    assert plan.heights.tolist() == [2.5, 2.5, 1.0, 0.7]
    # The first segment, 0.2 thick, extended by 0.1 at both ends.
    lo, hi = plan.quad_bounds()
    np.testing.assert_allclose(lo[0], [-0.1, -0.1])
    np.testing.assert_allclose(hi[0], [4.1, 0.1])
    # The box turned by 90 degrees is 0.5 wide in x and 1.0 in y.
    np.testing.assert_allclose(hi[3] - lo[3], [0.5, 1.0], atol=1e-12)
    assert plan.height_at(np.array([[2.0, 1.9], [2.4, 1.5], [4.0, 2.0], [0.0, 1.0]])).tolist() == [
        0.7, 0.0, 2.5, 1.0,
    ]  # fmt: skip
    assert plan.clearance(np.array([[3.0, 0.6]]))[0] == pytest.approx(0.6 - 0.1)  # the wall
    assert plan.clearance(np.array([[2.0, 0.6]]))[0] == pytest.approx(1.0 - 0.6)  # the box


def test_project_yaml_errors_name_the_field(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"boxes": [{"centre": [0, 0], "size": [1, -1], "height": 1}]}))
    with pytest.raises(FloorPlanError, match=r"bad\.yaml: boxes\[0\]\.size\[1\]: must be > 0 \(got -1\)"):
        load_floor_plan(path)
    path.write_text(yaml.safe_dump({"walls": [{"points": [[0, 0]]}]}))
    with pytest.raises(FloorPlanError, match=r"walls\[0\]\.points: list should have at least 2"):
        load_floor_plan(path)


def test_merge_cells_covers_the_mask_exactly():
    rng = np.random.default_rng(3)
    mask = rng.random((40, 60)) < 0.3
    mask[10:20, 5:50] = True
    rects = merge_cells(mask)
    cover = np.zeros(mask.shape, dtype=int)
    for r0, c0, r1, c1 in rects:
        cover[r0:r1, c0:c1] += 1
    np.testing.assert_array_equal(cover, mask.astype(int))  # disjoint, and exactly the mask
    assert len(rects) < mask.sum() / 2


def test_ros_map_extent_and_walls():
    plan = load_floor_plan(MAPS / "tb3_sandbox.yaml")
    np.testing.assert_allclose(plan.lo, [-10.0, -10.0])
    np.testing.assert_allclose(plan.hi, [-10 + 384 * 0.05, -10 + 384 * 0.05])
    assert np.all(plan.heights == 2.0)

    image = cv2.imread(str(MAPS / "tb3_sandbox.pgm"), cv2.IMREAD_UNCHANGED)
    p = (255 - image.astype(float)) / 255
    free = p < 0.196  # the yaml's free_thresh
    # Walls: the occupied cells (the yaml's occupied_thresh) and the unknown cells touching
    # free ones (21 here: grey cells in the pillars and the hexagon's wall).
    occupied = (p > 0.65) | (ndimage.binary_dilation(free, np.ones((3, 3), bool)) & ~free)
    assert (occupied & ~(p > 0.65)).sum() == 21
    # Merged rectangles: far fewer bodies than cells, same area.
    area = sum(np.prod(q.max(axis=0) - q.min(axis=0)) for q in plan.quads)
    assert area == pytest.approx(occupied.sum() * 0.05**2)
    assert plan.count < occupied.sum() / 3
    # Every cell centre is covered exactly when it is a wall (row 0 = top = max y).
    rows, cols = np.mgrid[0:384, 0:384]
    centres = np.stack([-10 + (cols + 0.5) * 0.05, -10 + (383 - rows + 0.5) * 0.05], axis=-1)
    window = (slice(120, 260), slice(120, 270))  # the arena
    heights = plan.height_at(centres[window])
    np.testing.assert_array_equal(heights > 0, occupied[window])


def test_depot_extent():
    plan = load_floor_plan(MAPS / "depot.yaml", wall_height=3.0)
    np.testing.assert_allclose(plan.lo, [0.0, 0.0])
    np.testing.assert_allclose(plan.hi, [604 * 0.05, 307 * 0.05])
    assert plan.max_height == 3.0
    # The west wall: image columns 1-2 (x 0.05-0.15 m) are occupied, column 0 is not.
    assert plan.height_at(np.array([[0.1, 7.0], [0.02, 7.0], [0.2, 7.0]])).tolist() == [3.0, 0.0, 0.0]


def test_depot_grey_cells_are_unknown_whatever_its_free_thresh_says():
    """Nav2's depot is a map_saver image (0, 205, 254) with free_thresh 0.25, which read its
    grey cells as free (map_server does so): the floor ran under the pallet boxes' insides and
    to the image's border. Read with map_saver's own free_thresh, each shade keeps its meaning."""
    ros = load_ros_map(MAPS / "depot.yaml")
    levels = np.round(read_map_image(MAPS / "depot.pgm").shade * 255)[::-1]
    np.testing.assert_array_equal(ros.occupied, levels == 0)
    np.testing.assert_array_equal(ros.free, levels == 254)
    assert (levels == 205).any()


def test_ros_map_thresholds_negate_and_origin(tmp_path):
    image = np.array([[0, 100, 254], [255, 60, 200]], dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "m.png"), image)
    spec = {"image": "m.png", "resolution": 0.5, "origin": [1.0, 2.0, 0.0], "negate": 0,
            "occupied_thresh": 0.65, "free_thresh": 0.2}  # fmt: skip
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(spec))
    ros = load_ros_map(tmp_path / "m.yaml")
    # Row 0 of the arrays is the image's bottom row.
    # p = (255 - v) / 255: occupied above 0.65, free below 0.2, unknown between (v = 100).
    np.testing.assert_array_equal(ros.occupied, [[False, True, False], [True, False, False]])
    np.testing.assert_array_equal(ros.free, [[True, False, False], [False, False, True]])
    np.testing.assert_allclose(ros.to_world(np.array(1.0), np.array(1.0)), [1.5, 2.5])

    (tmp_path / "n.yaml").write_text(yaml.safe_dump({**spec, "negate": 1}))
    ros = load_ros_map(tmp_path / "n.yaml")
    np.testing.assert_array_equal(ros.occupied, [[True, False, True], [False, False, True]])  # p = v / 255

    (tmp_path / "r.yaml").write_text(yaml.safe_dump({**spec, "origin": [0.0, 0.0, np.pi / 2]}))
    plan = load_floor_plan(tmp_path / "r.yaml")
    np.testing.assert_allclose(plan.lo, [-1.0, 0.0], atol=1e-12)  # turned: x <- -y
    np.testing.assert_allclose(plan.hi, [0.0, 1.5], atol=1e-12)


def _ros_map(free: np.ndarray, resolution: float = 0.1) -> RosMap:
    free = np.asarray(free, dtype=bool)
    return RosMap(~free, free, resolution, (0.0, 0.0, 0.0), Path("hand.yaml"))


def test_ros_map_clearance_of_a_corridor_by_hand():
    """A corridor 5 cells wide and 9 long, walled on both long sides, open at both ends of the
    image: from the middle cell's centre the walls' edges are 2.5 cells away."""
    free = np.zeros((7, 9), bool)
    free[1:6, :] = True
    clearance = _ros_map(free, 0.1).clearance()
    assert clearance.shape == free.shape
    np.testing.assert_allclose(clearance[3, 4], 0.25)  # middle: 2.5 cells to either wall
    np.testing.assert_allclose(clearance[1, 4], 0.05)  # beside the wall: half a cell
    np.testing.assert_allclose(clearance[3, 0], 0.05)  # on the image's edge: outside counts as unknown
    np.testing.assert_allclose(clearance[3, 1], 0.15)
    assert np.all(clearance[~free] == 0.0)


def test_ros_map_clearance_matches_a_brute_force_distance():
    """Each free cell's centre to the nearest non-free cell's centre (also the ring of cells just
    beyond the image), less half a cell, computed cell by cell."""
    rng = np.random.default_rng(3)
    free = rng.random((12, 15)) > 0.2
    free[4:9, 3:12] = True
    resolution = 0.05
    got = _ros_map(free, resolution).clearance()
    rows, cols = free.shape
    blocked = [(r, c) for r in range(-1, rows + 1) for c in range(-1, cols + 1)
               if not (0 <= r < rows and 0 <= c < cols and free[r, c])]  # fmt: skip
    blocked = np.array(blocked, dtype=np.float64)
    for r in range(rows):
        for c in range(cols):
            want = 0.0
            if free[r, c]:
                want = (np.hypot(*(blocked - (r, c)).T).min() - 0.5) * resolution
            assert got[r, c] == pytest.approx(want), (r, c)
    # and scipy's transform of the hand-padded grid agrees
    padded = ndimage.distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1]
    np.testing.assert_allclose(got[free], (padded[free] - 0.5) * resolution)


def test_free_ray_lengths_stop_at_walls_unknown_cells_and_the_image_edge():
    free = np.zeros((10, 10), bool)
    free[1:9, 1:9] = True  # free x, y in [0.1, 0.9] at 0.1 m; walls round it
    free[4, 9] = True  # a free cell on the east edge of the image (x 0.9-1.0, y 0.4-0.5)
    ros_map = _ros_map(free, 0.1)
    east, north, west = 0.0, np.pi / 2, np.pi
    got = ros_map.free_ray_lengths(np.array([0.55, 0.45]), np.array([east, north, west]), 5.0)
    # samples every 0.05 m: east the last free one is x = 0.95 (the image ends at 1.0),
    # north y = 0.85 (wall from 0.9), west x = 0.10 (wall up to 0.1)
    np.testing.assert_allclose(got, [0.40, 0.40, 0.45])
    np.testing.assert_allclose(ros_map.free_ray_lengths(np.array([0.55, 0.45]), [west], 0.2), [0.2])  # reach
    assert ros_map.free_ray_lengths(np.array([0.05, 0.05]), [east], 5.0)[0] == 0.0  # starts on a wall
