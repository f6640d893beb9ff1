"""The renderer: exact depth against analytic geometry, stereo pairs that SGBM can match, and the
compiled renderer equal to the numpy renderer it replaced (the oracle, tests/support/reference_render.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim2d.render import FACE_FLOOR, FACE_NONE, FACE_SIDE, FACE_TOP, Renderer, camera_pose
from sim2d.texture_sampling import texture_pyramid
from swarm.config import RigConfig
from swarm.formats.floor_plan import FloorPlan, load_floor_plan, rectangle, wall_segment
from swarm.protocol.wire import Camera
from tests.support import reference_render
from tests.support.paths import CONFIGS

CAMERA = RigConfig().camera()  # 160 x 120, 60 degrees, 9 cm


def pixel_rays(camera: Camera, pose) -> np.ndarray:
    """World direction of every pixel, scaled so that its optical z component is 1."""
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    optical = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(u.shape)], -1)
    return optical @ pose.optical_rotation().T


def plan_of(quads, heights) -> FloorPlan:
    quads = np.asarray(quads, dtype=float).reshape(-1, 4, 2)
    return FloorPlan(quads, heights, lo=(-10, -10), hi=(10, 10))


def box_reference_depth(boxes, camera: Camera, pose) -> np.ndarray:
    """Brute force: nearest intersection with each face plane of axis-aligned boxes and the floor."""
    d = pixel_rays(camera, pose)
    c = np.asarray(pose.xyz)
    best = np.full(d.shape[:2], np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -c[2] / d[..., 2]  # the floor, z = 0
        best = np.where(s > 0, s, best)
        for (x0, y0, x1, y1), h in boxes:
            lo, hi = np.array([x0, y0, 0.0]), np.array([x1, y1, h])
            for axis in range(3):
                for plane in (lo[axis], hi[axis]):
                    s = (plane - c[axis]) / d[..., axis]
                    p = c + s[..., None] * d
                    others = [a for a in range(3) if a != axis]
                    inside = np.all(
                        (p[..., others] >= lo[others] - 1e-9) & (p[..., others] <= hi[others] + 1e-9), -1
                    )
                    best = np.where((s > 1e-9) & inside & (s < best), s, best)
    return np.where(np.isfinite(best), best, np.nan)  # optical z = s, as d_z(optical) = 1


def test_depth_to_a_wall_and_to_the_floor_is_analytic():
    wall = wall_segment((3.0, -20.0), (3.0, 20.0), 0.1)  # face at x = 2.95
    renderer = Renderer(plan_of([wall], [2.5]), CAMERA, max_distance=1e6)
    for yaw in (0.0, 0.4):
        pose = camera_pose(0.0, 0.0, yaw, 0.4)
        hits = renderer.cast(pose)
        d = pixel_rays(CAMERA, pose)
        wall_depth = 2.95 / d[..., 0]
        z_at_wall = 0.4 + wall_depth * d[..., 2]
        sees_wall = (z_at_wall >= 0) & (z_at_wall <= 2.5)
        floor_depth = 0.4 / -np.where(d[..., 2] < 0, d[..., 2], np.nan)
        np.testing.assert_array_equal(hits.face == FACE_SIDE, sees_wall)
        np.testing.assert_allclose(hits.depth[sees_wall], wall_depth[sees_wall], rtol=0, atol=1e-12)
        floor = hits.face == FACE_FLOOR
        assert floor.sum() > 1000
        np.testing.assert_allclose(hits.depth[floor], floor_depth[floor], rtol=0, atol=1e-12)
        assert np.all(np.isnan(hits.depth[hits.face == FACE_NONE]))
        if yaw == 0.0:  # fronto-parallel: every wall pixel is at 2.95 m
            np.testing.assert_allclose(hits.depth[sees_wall], 2.95, atol=1e-12)


def test_floor_depth_of_an_empty_plan():
    renderer = Renderer(plan_of(np.zeros((0, 4, 2)), []), CAMERA, max_distance=1e6)
    depth = renderer.depth_image(camera_pose(1.0, 2.0, 0.7, 0.4))
    v = np.arange(CAMERA.height)[:, None] - CAMERA.cy
    expected = np.where(v > 0, 0.4 * CAMERA.fy / np.where(v > 0, v, 1), np.nan) * np.ones(CAMERA.width)
    np.testing.assert_allclose(depth, expected, rtol=1e-6)  # float32 output
    # Beyond the renderer's max distance (60 m by default, along the floor) there is no return.
    capped = Renderer(renderer.plan, CAMERA).depth_image(camera_pose(1.0, 2.0, 0.7, 0.4))
    along_floor = expected * np.hypot(1, (np.arange(CAMERA.width) - CAMERA.cx) / CAMERA.fx)
    np.testing.assert_array_equal(np.isnan(capped), np.isnan(expected) | (along_floor > 60))


@pytest.mark.parametrize("pitch", [0.0, 0.25, -0.2])
def test_depth_matches_brute_force_on_boxes(pitch):
    boxes = [
        ((1.0, -1.0, 3.0, 1.0), 0.2),  # low: seen from above, its top is visible
        ((3.5, -0.4, 3.9, 0.3), 1.5),
        ((-2.0, 1.5, 4.0, 1.8), 2.5),
        ((0.5, -2.5, 0.9, -0.8), 0.6),
    ]
    quads = [rectangle(((x0 + x1) / 2, (y0 + y1) / 2), (x1 - x0, y1 - y0)) for (x0, y0, x1, y1), _ in boxes]
    renderer = Renderer(plan_of(quads, [h for _, h in boxes]), CAMERA, max_distance=1e6)
    rng = np.random.default_rng(1)
    faces = set()
    for _ in range(6):
        pose = camera_pose(rng.uniform(-1.5, 0.0), rng.uniform(-0.5, 0.5), rng.uniform(-0.8, 0.8), 0.4, pitch)
        hits = renderer.cast(pose)
        expected = box_reference_depth(boxes, CAMERA, pose)
        np.testing.assert_array_equal(np.isnan(hits.depth), np.isnan(expected))
        np.testing.assert_allclose(hits.depth, expected, rtol=0, atol=1e-9)
        faces |= set(np.unique(hits.face).tolist())
    assert {FACE_FLOOR, FACE_SIDE, FACE_TOP} <= faces


def test_level_and_per_pixel_casting_agree_on_a_ros_map():
    """The column-ray path (with occlusion pruning) against the per-pixel path, on 1,722 quads."""
    renderer = Renderer(load_floor_plan(CONFIGS / "maps" / "depot.yaml"), CAMERA)
    for x, y, yaw in ((15.0, 7.6, 0.0), (5.0, 3.0, 0.7), (25.0, 12.0, 3.5)):
        level = renderer.cast(camera_pose(x, y, yaw, 0.4))
        tilted = renderer.cast(camera_pose(x, y, yaw, 0.4, pitch=1e-9))
        np.testing.assert_array_equal(level.face, tilted.face)
        np.testing.assert_array_equal(level.obstacle, tilted.obstacle)
        np.testing.assert_allclose(level.depth, tilted.depth, atol=1e-5)


def test_sgbm_recovers_depth_on_textured_walls():
    plan = load_floor_plan(CONFIGS / "plans" / "lab.yaml")
    rig = RigConfig(noise_std=1.0)
    camera = rig.camera()
    renderer = Renderer(plan, camera, seed=0)
    disparities = 16 * int(np.ceil(camera.fx * camera.baseline / 0.2 / 16))
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=disparities, blockSize=5, P1=8 * 25, P2=32 * 25,
        uniquenessRatio=5, mode=cv2.STEREO_SGBM_MODE_HH,
    )  # fmt: skip
    rng = np.random.default_rng(0)
    errors = []
    for x, y, yaw in ((0.6, 1.0, -0.6), (2.0, 1.0, 1.57), (3.0, 0.9, 3.14), (1.0, 0.8, -1.57)):
        pose = camera_pose(x, y, yaw, rig.camera_height)
        left, right = renderer.stereo_pair(pose, rig.noise_std, rng)
        assert left.shape == (120, 160) and left.dtype == np.uint8
        disparity = sgbm.compute(left, right).astype(np.float32) / 16
        truth = renderer.cast(pose)
        wall = (truth.face == FACE_SIDE) & (truth.depth <= 3.0)
        found = wall & (disparity > 0)
        assert found.sum() > 0.4 * wall[:, disparities:].sum()
        depth = camera.fx * camera.baseline / disparity[found]
        rel = np.abs(depth - truth.depth[found]) / truth.depth[found]
        assert np.median(rel) < 0.03
        errors.append(rel)
    assert np.median(np.concatenate(errors)) < 0.03


def test_range_mode_noise_grows_with_distance():
    plan = load_floor_plan(CONFIGS / "plans" / "office.yaml")
    camera = RigConfig(width=320, height=240, mode="range").camera()
    renderer = Renderer(plan, camera)
    pose = camera_pose(1.0, 5.0, 0.0, 0.4)  # down the corridor: 1 to 15 m
    truth = renderer.depth_image(pose)
    noisy = renderer.depth_image(pose, noise_per_m=0.02, rng=np.random.default_rng(0))
    assert noisy.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(noisy), np.isnan(truth))
    assert np.isnan(truth).any()  # above the walls: no return
    error = noisy - truth
    near, far = truth < 3, truth > 8
    assert np.nanstd(error[far]) > 3 * np.nanstd(error[near])
    assert np.nanstd(error / truth) == pytest.approx(0.02, rel=0.1)
    assert abs(np.nanmean(error / truth)) < 0.002
    capped = renderer.depth_image(pose, max_range=5.0)
    assert np.nanmax(capped) <= 5.0
    np.testing.assert_array_equal(np.isnan(capped), np.isnan(truth) | (truth > 5.0))


def test_image_noise_and_no_return_pixels():
    plan = load_floor_plan(CONFIGS / "plans" / "office.yaml")
    renderer = Renderer(plan, CAMERA)
    pose = camera_pose(1.0, 5.0, 0.0, 0.4)
    clean = renderer.image(pose)
    noisy = renderer.image(pose, noise_std=4.0, rng=np.random.default_rng(0))
    diff = noisy.astype(float) - clean
    assert np.std(diff) == pytest.approx(4.0, rel=0.1)
    sky = renderer.cast(pose).face == FACE_NONE
    assert sky.any() and np.all(clean[sky] == 30)
    assert clean[~sky].std() > 20  # textured


# -- the compiled renderer against the numpy one it replaced (tests/support/reference_render.py) ----------


def assert_same_hits(new, old):
    for field in ("distance", "depth", "face", "obstacle", "edge", "points", "footprint"):
        np.testing.assert_array_equal(getattr(new, field), getattr(old, field), err_msg=field)


OFFICE_POSES = [
    (1.0, 5.0, 0.0, 0.0),
    (2.0, 3.0, 0.7, 0.0),
    (3.0, 2.0, 2.0, 0.3),
    (6.0, 7.0, -1.2, -0.2),
    (4.0, 5.0, 1.3, 1e-13),
]
DEPOT_POSES = [(15.0, 7.6, 0.0, 0.0), (5.0, 3.0, 0.7, 0.0), (25.0, 12.0, 3.5, 0.0), (10.0, 8.0, 1.0, 0.25)]


@pytest.mark.slow
@pytest.mark.parametrize(
    "plan_file, poses, size",
    [
        ("plans/office.yaml", OFFICE_POSES, (160, 120)),
        ("plans/office.yaml", OFFICE_POSES[1:3], (320, 240)),
        ("maps/depot.yaml", DEPOT_POSES, (160, 120)),
    ],
)
def test_compiled_renderer_equals_the_numpy_oracle(plan_file, poses, size):
    """Same hits, bit for bit, and the same noisy stereo images (level and pitched cameras)."""
    plan = load_floor_plan(CONFIGS / plan_file)
    camera = RigConfig(width=size[0], height=size[1]).camera()
    new, old = Renderer(plan, camera, seed=3), reference_render.Renderer(plan, camera, seed=3)
    faces = set()
    for x, y, yaw, pitch in poses:
        pose = camera_pose(x, y, yaw, 0.4, pitch)
        hits = new.cast(pose)
        assert_same_hits(hits, old.cast(pose))
        faces |= set(np.unique(hits.face).tolist())
        pair = new.stereo_pair(pose, 2.0, np.random.default_rng(5))
        expected = old.stereo_pair(pose, 2.0, np.random.default_rng(5))
        np.testing.assert_array_equal(pair[0], expected[0])
        np.testing.assert_array_equal(pair[1], expected[1])
        np.testing.assert_array_equal(new.depth_image(pose, 0.01, 4.0, np.random.default_rng(2)),
                                      old.depth_image(pose, 0.01, 4.0, np.random.default_rng(2)))  # fmt: skip
    assert {FACE_FLOOR, FACE_SIDE, FACE_NONE} <= faces


def test_ties_between_quads_go_to_the_lower_index_as_in_the_oracle():
    """Duplicated and abutting boxes: equal hit distances, resolved as numpy's argmin did."""
    box = rectangle((2.0, 0.0), (1.0, 1.0))
    quads = [box, box, rectangle((3.0, 0.0), (1.0, 1.0)), rectangle((2.0, 1.0), (1.0, 1.0)), box]
    plan = plan_of(quads, [0.5, 0.5, 0.9, 0.3, 0.5])
    new, old = Renderer(plan, CAMERA), reference_render.Renderer(plan, CAMERA)
    for x, y, yaw, pitch in ((0.0, 0.0, 0.0, 0.0), (0.0, 1.0, -0.3, 0.0), (0.5, -0.5, 0.4, 0.3)):
        pose = camera_pose(x, y, yaw, 0.6, pitch)
        hits = new.cast(pose)
        assert_same_hits(hits, old.cast(pose))
        seen = set(np.unique(hits.obstacle).tolist())
        assert 0 in seen and 1 not in seen and 4 not in seen  # the duplicates never win a tie


def test_texture_lookup_equals_the_numpy_oracle():
    """Trilinear lookups, clipped levels of detail at both ends included, and the blocked layout."""
    new = texture_pyramid(0, size=64, texel=0.01)
    old = reference_render._texture_pyramid(0, size=64, texel=0.01)
    rng = np.random.default_rng(0)
    u, v = rng.uniform(-50, 5000, 20000), rng.uniform(-50, 5000, 20000)
    footprint = np.exp(rng.uniform(np.log(1e-4), np.log(10.0), 20000))  # lod below 0 to above the top
    footprint[:10] = 0.0
    # Level of detail 0 is taken without log2 up to one texel: around exactly one texel, both sides.
    footprint[10:13] = np.nextafter(0.01, 0.0), 0.01, np.nextafter(0.01, 1.0)
    footprint[13:16] = 0.01 * 2.0**10, 0.01 * 2.0**6, 0.01 * 2.0**20  # exact powers of two, past the top
    # Equal to a few units in the last place: the compiled kernel may fuse a multiply and an add
    # (FMA) where NumPy rounds twice, depending on the machine it is compiled for.
    np.testing.assert_allclose(new.sample(u, v, footprint), old.sample(u, v, footprint), rtol=1e-14, atol=0)
    for k in range(new.count):
        n = old.sizes[k]
        np.testing.assert_array_equal(
            new.level(k), old.texels[old.starts[k] : old.starts[k] + n * n].reshape(n, n)
        )


def test_stereo_pair_in_one_or_two_threads_gives_the_same_images_and_draws():
    plan = load_floor_plan(CONFIGS / "plans" / "office.yaml")
    serial, threaded = Renderer(plan, CAMERA, threads=1), Renderer(plan, CAMERA, threads=2)
    rng_a, rng_b = np.random.default_rng(4), np.random.default_rng(4)
    for yaw in (0.0, 1.0):
        pose = camera_pose(2.0, 3.0, yaw, 0.4)
        pair_a, pair_b = serial.stereo_pair(pose, 3.0, rng_a), threaded.stereo_pair(pose, 3.0, rng_b)
        for a, b in zip(pair_a, pair_b, strict=True):
            np.testing.assert_array_equal(a, b)
    assert rng_a.random() == rng_b.random()  # the same number of draws
    with pytest.raises(ValueError, match="threads must be 1 or 2"):
        Renderer(plan, CAMERA, threads=3)


def test_image_noise_equals_the_oracles_normal_draws():
    """The noise is drawn as standard normals z and added as 0 + s z: the oracle's rng.normal(0, s)."""
    plan = load_floor_plan(CONFIGS / "plans" / "office.yaml")
    new, old = Renderer(plan, CAMERA, threads=2), reference_render.Renderer(plan, CAMERA)
    pose = camera_pose(2.0, 3.0, 0.7, 0.4)
    for noise_std in (0.37, 7.5, 60.0):  # 60: many pixels clip at 0 and 255
        rng_new, rng_old = np.random.default_rng(9), np.random.default_rng(9)
        pair, expected = new.stereo_pair(pose, noise_std, rng_new), old.stereo_pair(pose, noise_std, rng_old)
        for a, b in zip(pair, expected, strict=True):
            np.testing.assert_array_equal(a, b)
        image, expected_image = new.image(pose, noise_std, rng_new), old.image(pose, noise_std, rng_old)
        np.testing.assert_array_equal(image, expected_image)
        assert rng_new.random() == rng_old.random()  # the same number of draws


def test_images_and_hits_are_row_major_arrays():
    """The kernels work ray-major; what the renderer returns is the usual C-contiguous image layout."""
    renderer = Renderer(load_floor_plan(CONFIGS / "plans" / "office.yaml"), CAMERA)
    for pitch in (0.0, 0.3):
        pose = camera_pose(2.0, 3.0, 0.7, 0.4, pitch)
        hits = renderer.cast(pose)
        fields = ("distance", "depth", "face", "obstacle", "edge", "footprint")
        arrays = [getattr(hits, field) for field in fields]
        arrays += [hits.points, renderer.grey(pose), renderer.depth_image(pose, 0.01, 4.0)]
        arrays += list(renderer.stereo_pair(pose, 1.0, np.random.default_rng(0)))
        for array in arrays:
            assert array.shape[:2] == (CAMERA.height, CAMERA.width) and array.flags.c_contiguous
