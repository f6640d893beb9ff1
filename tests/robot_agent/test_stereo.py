"""Stereo: SGBM depth on synthetic pairs, calibration files, world points, the CLI."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from robot_agent.disparity_kernels import depth_of_disparity, valid_disparity
from robot_agent.stereo import (
    StereoMatcher,
    depth_from_disparity,
    disparity_range,
    matcher_for_rig,
    points_from_depth,
    texture_threshold,
)
from swarm.formats.depth_picture import BAR_WIDTH
from swarm.formats.stereo_calibration import (
    CalibrationError,
    calibration_from_dict,
    load_calibration,
)
from tests.support.stereo_oracle import reference_depth, reference_valid_disparity
from tests.support.stereo_scenes import (
    BASELINE,
    CX,
    CY,
    FX,
    H,
    W,
    cli,
    relative_error,
    rig,
    synthetic_pair,
    texture,
    write_yaml,
)

# -- SGBM ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_sgbm_depth_of_synthetic_planes(seed: int) -> None:
    left, right, truth = synthetic_pair(seed)
    matcher = StereoMatcher()
    disp = matcher.disparity(left, right)
    assert disp.dtype == np.float32 and disp.shape == (H, W)
    depth = depth_from_disparity(disp, rig())
    median_err, valid = relative_error(depth, truth)
    assert median_err < 0.03, median_err
    assert valid > 0.6, valid
    plain = StereoMatcher(pad_border=False).disparity(left, right)
    assert np.isnan(plain[:, :48]).all() and np.isfinite(disp[:, 20:48]).mean() > 0.8
    # No pixel claims a match outside the right image.
    u = np.arange(W)[None, :]
    assert not np.any(np.isfinite(disp) & (u - np.nan_to_num(disp, nan=0.0) < 0))


def test_sgbm_accepts_bgr_and_rejects_bad_input() -> None:
    left, right, truth = synthetic_pair(2)
    bgr = StereoMatcher().disparity(
        cv2.cvtColor(left, cv2.COLOR_GRAY2BGR), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR)
    )
    gray = StereoMatcher().disparity(left, right)
    np.testing.assert_array_equal(np.isnan(bgr), np.isnan(gray))
    with pytest.raises(ValueError, match="right is"):
        StereoMatcher().disparity(left, right[:, :-1])
    with pytest.raises(ValueError, match="uint8"):
        StereoMatcher().disparity(left.astype(np.float32), right)
    with pytest.raises(ValueError, match="multiple of 16"):
        StereoMatcher(num_disparities=40)


def test_disparity_range_covers_near_depth() -> None:
    min_disp, num = disparity_range(rig(), min_depth=0.3)
    assert min_disp == 0 and num % 16 == 0
    assert num - 1 >= FX * BASELINE / 0.3  # 41.6 px at 0.3 m
    assert num == 48
    # A Middlebury-style offset shifts the search range down.
    min_disp, num = disparity_range(rig(cx_right=CX + 20), min_depth=0.3)
    assert min_disp == -20 and min_disp + num - 1 >= FX * BASELINE / 0.3 - 20


def test_depth_from_disparity_honours_cx_right() -> None:
    disp = np.array([[10.0, 0.0, -5.0, np.nan]], np.float32)
    plain = depth_from_disparity(disp, rig())
    np.testing.assert_allclose(plain[0, 0], FX * BASELINE / 10.0, rtol=1e-6)
    assert np.isnan(plain[0, 1:]).all()  # zero, negative and invalid disparity: unknown
    offset = depth_from_disparity(disp, rig(cx_right=CX + 7.5))
    np.testing.assert_allclose(offset[0, :3], FX * BASELINE / (disp[0, :3] + 7.5), rtol=1e-6)
    assert offset.dtype == np.float32


def test_matcher_with_disparity_offset_recovers_depth() -> None:
    left, right, truth = synthetic_pair(0, offset=3.0)  # doffs = 3 px: raw disparities d - 3
    calib = rig(cx_right=CX + 3.0)
    depth = StereoMatcher.for_rig(calib, min_depth=0.3).depth(left, right, calib)
    median_err, valid = relative_error(depth, truth)
    assert median_err < 0.03 and valid > 0.6


# -- points -------------------------------------------------------------------------------------


def test_points_from_depth_world_position() -> None:
    depth = np.full((H, W), np.nan, np.float32)
    u, v, z = 30, 100, 2.5
    depth[v, u] = z
    depth[0, 0] = -1.0  # invalid: dropped
    depth[1, 1] = np.inf
    xyz, ypr = np.array([1.0, -2.0, 0.4]), np.array([0.7, 0.2, -0.1])
    pts = points_from_depth(depth, FX, FX * 1.1, CX, CY, xyz, ypr)
    assert pts.shape == (1, 3)
    # Independent: optical ray (x right, y down, z forward) -> body (x fwd, y left, z up) -> world.
    optical = np.array([(u - CX) / FX * z, (v - CY) / (FX * 1.1) * z, z])
    body = np.array([optical[2], -optical[0], -optical[1]])
    world = Rotation.from_euler("ZYX", ypr).apply(body) + xyz
    np.testing.assert_allclose(pts[0], world, atol=1e-9)


def test_points_from_depth_pitch_down_and_max_range() -> None:
    depth = np.full((H, W), 2.0, np.float32)
    eye = np.array([0.0, 0.0, 0.4])
    pts = points_from_depth(depth, FX, FX, CX, CY, eye, (0.0, math.radians(30), 0.0))
    assert len(pts) == H * W
    assert np.mean(pts[:, 2]) == pytest.approx(0.4 - 2.0 * math.sin(math.radians(30)), abs=0.01)  # looks down
    kept = points_from_depth(depth, FX, FX, CX, CY, eye, (0, 0, 0), max_range=2.1)
    assert 0 < len(kept) < H * W
    assert np.all(np.linalg.norm(kept - eye, axis=1) <= 2.1 + 1e-9)


# -- calibration --------------------------------------------------------------------------------


def test_rectified_calibration_file(tmp_path) -> None:
    path = write_yaml(
        tmp_path / "rig.yaml",
        f"fx: {FX}\nfy: {FX}\ncx: {CX}\ncy: {CY}\nbaseline: 0.09\ncx_right: {CX + 2}\n"
        "width: 160\nheight: 120\n",
    )
    calib = load_calibration(path)
    assert calib.maps is None and calib.image_size == (160, 120)
    assert calib.disparity_offset == pytest.approx(2.0)
    assert calib.left_rotation is None and calib.source == str(path)
    with pytest.raises(CalibrationError, match="image_size") as info:
        calib.check_image_size(320, 240)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("fx: 100\nfy: 100\ncx: 50\ncy: 40\n", "baseline"),
        ("fx: -1\nfy: 100\ncx: 50\ncy: 40\nbaseline: 0.1\n", "fx"),
        ("fx: 100\nfy: 100\ncx: 50\ncy: 40\nbaseline: 193.0\n", "baseline"),
        ("fx: 100\nfy: 100\ncx: 50\ncy: 40\nbaseline: 0.1\nbasline: 2\n", "basline"),
        (
            "K1: [[1, 0, 0], [0, 1, 0]]\nK2: [1,0,0,0,1,0,0,0,1]\nR: [0,0,0]\nT: [-0.1,0,0]\n"
            "image_size: [8,8]\n",
            "K1",
        ),
        (
            "K1: [1,0,0,0,1,0,0,0,1]\nK2: [1,0,0,0,1,0,0,0,1]\nR: [[2,0,0],[0,1,0],[0,0,1]]\n"
            "T: [-0.1,0,0]\nimage_size: [8,8]\n",
            "R",
        ),
        ("K1: [1,0,0,0,1,0,0,0,1]\nK2: [1,0,0,0,1,0,0,0,1]\nR: [0,0,0]\nT: [-0.1,0,0]\n", "image_size"),
        ("just a string\n", "mapping"),
        ("a: 1\n", "no calibration"),
    ],
)
def test_calibration_errors_name_file_and_field(tmp_path, text: str, field: str) -> None:
    path = write_yaml(tmp_path / "bad.yaml", text)
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    assert str(path) in str(info.value) and field in str(info.value)


def test_missing_calibration_file(tmp_path) -> None:
    with pytest.raises(CalibrationError, match="nope.yaml: calibration file not found"):
        load_calibration(tmp_path / "nope.yaml")


def full_calibration(rvec_right=(0.0, 0.0, 0.0)) -> dict:
    k = [[FX, 0, CX], [0, FX, CY], [0, 0, 1]]
    r_rect = cv2.Rodrigues(np.asarray(rvec_right, np.float64))[0]  # raw right camera w.r.t. rectified
    t = r_rect @ np.array([-BASELINE, 0.0, 0.0])
    return {
        "K1": k,
        "D1": [0, 0, 0, 0, 0],
        "K2": k,
        "D2": [0, 0, 0, 0, 0],
        "R": r_rect.tolist(),
        "T": t.tolist(),
        "image_size": [W, H],
    }


def test_full_calibration_identity_rig_is_rectified_already() -> None:
    calib = calibration_from_dict(full_calibration(), "synthetic")
    assert calib.baseline == pytest.approx(BASELINE, rel=1e-6)
    assert calib.disparity_offset == pytest.approx(0.0, abs=1e-6)
    left, right, truth = synthetic_pair(4)
    rl, rr = calib.rectify(left, right)
    # R = I, no distortion: rectification is (nearly) the identity, so depth is unchanged.
    direct = depth_from_disparity(StereoMatcher().disparity(left, right), rig())
    via = StereoMatcher.for_rig(calib).depth(left, right, calib)
    both = np.isfinite(direct) & np.isfinite(via)
    assert np.median(np.abs(via[both] - direct[both]) / direct[both]) < 0.01
    assert np.mean(np.abs(rl.astype(int) - left.astype(int))[10:-10, 10:-10]) < 3
    assert relative_error(via, truth)[0] < 0.03


def test_full_calibration_rectifies_a_rotated_right_camera() -> None:
    """A raw right camera pitched by 1 deg and yawed by 1.5 deg; a slanted wall, 1.5 m -> 3 m."""
    rvec = (math.radians(1.0), math.radians(1.5), 0.0)
    right_rect = texture(np.random.default_rng(5))
    # Inverse depth is linear in u for a plane: 1/Z = alpha u + gamma.
    alpha, gamma = (1 / 3.0 - 1 / 1.5) / (W - 1), 1 / 1.5
    u, v = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    left = cv2.remap(right_rect, u - FX * BASELINE * (alpha * u + gamma), v, cv2.INTER_CUBIC)
    k = np.array([[FX, 0, CX], [0, FX, CY], [0, 0, 1]])
    r_rect = cv2.Rodrigues(np.asarray(rvec))[0]
    # The raw right image sees rectified-frame rays through its own rotation: p_raw ~ K R K^-1 p_rect.
    hom = k @ r_rect @ np.linalg.inv(k)
    right_raw = cv2.warpPerspective(right_rect, hom, (W, H), flags=cv2.INTER_CUBIC)
    calib = calibration_from_dict(full_calibration(rvec), "synthetic")
    depth = StereoMatcher.for_rig(calib).depth(left, right_raw, calib)
    # The same plane n . X = 1 (raw left camera: n = (alpha fx, 0, gamma + alpha cx)), seen from the
    # rectified left camera X' = R1 X: 1/Z' = (R1 n) . K'^-1 p'.
    n_rect = calib.left_rotation @ np.array([alpha * FX, 0.0, gamma + alpha * CX])
    rays = np.stack([(u - calib.cx) / calib.fx, (v - calib.cy) / calib.fy, np.ones_like(u)], axis=-1)
    truth = 1.0 / (rays @ n_rect)
    err, valid = relative_error(depth, truth)
    assert valid > 0.6 and err < 0.03, (valid, err)
    naive = depth_from_disparity(StereoMatcher().disparity(left, right_raw), rig())
    naive_err, naive_valid = relative_error(naive, 1.0 / (alpha * u + gamma))
    assert naive_valid < 0.6 or naive_err > 0.1  # without rectification it does fail


def test_full_calibration_rejects_swapped_cameras() -> None:
    data = full_calibration()
    data["T"] = [BASELINE, 0, 0]
    with pytest.raises(CalibrationError, match="T: the second camera must be to the right"):
        calibration_from_dict(data, "swapped.yaml")


def test_opencv_filestorage_yaml(tmp_path) -> None:
    k = f"[ {FX}, 0., {CX}, 0., {FX}, {CY}, 0., 0., 1. ]"
    mat = "!!opencv-matrix\n   rows: {r}\n   cols: {c}\n   dt: d\n   data: {d}\n"
    text = (
        "%YAML:1.0\n---\n"
        f"M1: {mat.format(r=3, c=3, d=k)}"
        f"D1: {mat.format(r=1, c=5, d='[0., 0., 0., 0., 0.]')}"
        f"M2: {mat.format(r=3, c=3, d=k)}"
        f"D2: {mat.format(r=1, c=5, d='[0., 0., 0., 0., 0.]')}"
        f"R: {mat.format(r=3, c=3, d='[1., 0., 0., 0., 1., 0., 0., 0., 1.]')}"
        f"T: {mat.format(r=3, c=1, d='[-0.09, 0., 0.]')}"
        "image_size: [160, 120]\n"
    )
    calib = load_calibration(write_yaml(tmp_path / "stereo.yml", text))
    assert calib.baseline == pytest.approx(BASELINE) and calib.maps is not None


# -- CLI ----------------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_writes_depth_and_png(pair_files, capsys) -> None:
    d, truth = pair_files
    rc = cli([str(d / "left.png"), str(d / "right.png"), "--calib", str(d / "calib.yaml"),
              "--out", str(d / "out" / "depth.npy"), "--png", str(d / "depth.png")])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    depth = np.load(d / "out" / "depth.npy")
    assert depth.shape == (H, W) and depth.dtype == np.float32
    assert np.isnan(depth).any() and np.isfinite(depth).mean() > 0.6
    assert relative_error(depth, truth)[0] < 0.03
    png = cv2.imread(str(d / "depth.png"))  # the picture (enlarged to >= 240 rows), then its colour bar
    factor = max(1, -(-240 // H))
    assert png.shape == (H * factor, W * factor + BAR_WIDTH, 3)
    assert np.all(png[: H * factor : factor, : W * factor : factor][np.isnan(depth)] == 0)
    assert "wrote" in capsys.readouterr().out
    rc = cli([str(d / "left.png"), str(d / "right.png"), "--calib", str(d / "calib.yaml"),
              "--out", str(d / "refined.npy"), "--refine-subpixel"])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    refined = np.load(d / "refined.npy")
    np.testing.assert_array_equal(np.isnan(refined), np.isnan(depth))  # the refinement fills nothing
    assert relative_error(refined, truth)[0] < 0.03 and not np.array_equal(refined, depth, equal_nan=True)


def test_cli_errors_name_the_file(pair_files, capsys) -> None:
    d, _ = pair_files
    out = str(d / "depth.npy")
    rc = cli([str(d / "missing.png"), str(d / "right.png"), "--calib", str(d / "calib.yaml"), "--out", out])
    assert rc == 2 and "missing.png" in capsys.readouterr().err
    rc = cli([str(d / "left.png"), str(d / "right.png"), "--calib", str(d / "nocal.yaml"), "--out", out])
    assert rc == 2 and "nocal.yaml" in capsys.readouterr().err
    small = np.zeros((60, 80), np.uint8)
    cv2.imwrite(str(d / "small.png"), small)
    rc = cli([str(d / "left.png"), str(d / "small.png"), "--calib", str(d / "calib.yaml"), "--out", out])
    err = capsys.readouterr().err
    assert rc == 2 and "small.png" in err and "80x60" in err
    write_yaml(d / "bad.yaml", "fx: 100\nfy: 100\ncx: 50\ncy: 40\nbaseline: -0.1\n")
    rc = cli([str(d / "left.png"), str(d / "right.png"), "--calib", str(d / "bad.yaml"), "--out", out])
    err = capsys.readouterr().err
    assert rc == 2 and "bad.yaml" in err and "baseline" in err
    write_yaml(
        d / "vga.yaml", f"fx: {FX}\nfy: {FX}\ncx: {CX}\ncy: {CY}\nbaseline: 0.09\nwidth: 640\nheight: 480\n"
    )
    rc = cli([str(d / "left.png"), str(d / "right.png"), "--calib", str(d / "vga.yaml"), "--out", out])
    err = capsys.readouterr().err
    assert rc == 2 and "vga.yaml" in err and "640x480" in err
    (d / "junk.png").write_bytes(b"not an image")
    rc = cli([str(d / "junk.png"), str(d / "right.png"), "--calib", str(d / "calib.yaml"), "--out", out])
    assert rc == 2 and "junk.png" in capsys.readouterr().err
    assert not (d / "depth.npy").exists()


def test_texture_filter_drops_blank_areas() -> None:
    # The top half of the scene is blank (the sky above walls, say): SGBM spreads disparities
    # into it from the textured half, the texture filter removes them.
    rng = np.random.default_rng(3)
    texture = rng.integers(0, 256, size=(60, 200)).astype(np.uint8)
    scene = np.full((120, 200), 30, dtype=np.uint8)
    scene[60:] = texture
    shift = 8
    left, right = scene[:, :160].copy(), scene[:, shift : shift + 160].copy()  # disparity 8 px
    filtered = StereoMatcher(num_disparities=16).disparity(left, right)
    plain = StereoMatcher(num_disparities=16, min_texture=0).disparity(left, right)
    assert np.isfinite(plain[:56]).sum() > 0  # without the filter, blank pixels get disparities
    assert not np.isfinite(filtered[:56]).any()
    textured = filtered[66:, 40:]
    assert np.nanmedian(textured) == pytest.approx(shift, abs=0.1) and np.isfinite(textured).mean() > 0.9
    with pytest.raises(ValueError, match="min_texture"):
        StereoMatcher(min_texture=-1)


def test_a_noisy_cameras_blank_area_is_blanked_by_its_texture_threshold() -> None:
    # Blank above, textured below, with independent Gaussian noise of 1 grey level in each
    # image (the simulated rig's): at the default 0.5 the noise passes as texture and SGBM
    # matches it; at texture_threshold(1.0) = 1.5 the blank half gets no disparity.
    rng = np.random.default_rng(5)
    scene = np.full((120, 220), 120.0)
    scene[60:] = rng.integers(0, 256, size=(60, 220))
    shift = 8
    noisy = [
        np.clip(scene[:, s : s + 180] + rng.normal(0.0, 1.0, (120, 180)), 0, 255).round().astype(np.uint8)
        for s in (0, shift)
    ]
    left, right = noisy[0], noisy[1]
    assert texture_threshold(0.0) == 0.5 and texture_threshold(1.0) == 1.5
    default = StereoMatcher(num_disparities=16).disparity(left, right)
    noise_aware = StereoMatcher(num_disparities=16, min_texture=texture_threshold(1.0)).disparity(left, right)
    assert np.isfinite(default[:54]).mean() > 0.2  # noise matched as if it were texture
    assert np.isfinite(noise_aware[:54]).mean() < 0.01
    textured = noise_aware[66:, 40:]
    assert np.nanmedian(textured) == pytest.approx(shift, abs=0.1) and np.isfinite(textured).mean() > 0.9


def test_the_agents_matcher_follows_its_rigs_camera_and_noise() -> None:
    from swarm.config.models import RigConfig  # noqa: PLC0415

    noisy, clean = RigConfig(width=640, height=480, noise_std=2.0), RigConfig()
    assert matcher_for_rig(noisy).min_texture == 3.0 and matcher_for_rig(clean).min_texture == 0.5
    assert matcher_for_rig(noisy).num_disparities == StereoMatcher.for_rig(noisy.camera()).num_disparities
    # rig.min_depth sets the disparity range: the nearest depth's disparity fx b / min_depth is
    # searched (disparities 0 .. num - 1), and no more than one block of 16 beyond it.
    for min_depth in (0.2, 0.35, 0.5, 1.0):
        rig = RigConfig(width=640, height=480, min_depth=min_depth)
        nearest = rig.fx * rig.baseline / min_depth
        num = matcher_for_rig(rig).num_disparities
        assert nearest <= num - 1 < nearest + 17, min_depth


def test_points_from_depth_equals_a_per_pixel_computation() -> None:
    """The compiled loop against numpy and scipy's rotation, on NaN, inf, negative and far depths."""
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.2, 9.0, (H, W)).astype(np.float32)
    depth[rng.random((H, W)) < 0.2] = np.nan
    depth[0, :5] = (np.inf, -np.inf, -1.0, 0.0, 1e30)
    xyz, ypr = np.array([1.0, -2.0, 0.5]), (0.7, -0.2, 0.1)
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[v, u].astype(np.float64)
    body = np.stack([z, -(u - CX) * z / FX, -(v - CY) * z / (FX * 1.1)], axis=1)
    near = np.linalg.norm(body, axis=1) <= 5.0
    expected = Rotation.from_euler("ZYX", ypr).apply(body[near]) + xyz
    got = points_from_depth(depth, FX, FX * 1.1, CX, CY, xyz, ypr, max_range=5.0)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    assert len(points_from_depth(depth, FX, FX * 1.1, CX, CY, xyz, ypr)) == len(z)


@pytest.mark.parametrize("min_disparity", [0, -4, 3])
@pytest.mark.parametrize("pad_left", [0, 5])
def test_compiled_disparity_and_depth_equal_the_numpy_forms(min_disparity, pad_left):
    """valid_disparity and depth_of_disparity against tests/support/stereo_oracle.py, bit for bit."""
    rng = np.random.default_rng(pad_left + 10 * abs(min_disparity))
    height, width = 37, 61
    # SGBM's fixed-point output: invalid marks, sub-pixel values, matches landing in the padding
    raw = rng.integers((min_disparity - 1) * 16, 80 * 16, (height, pad_left + width + 3)).astype(np.int16)
    raw[:, :4] = (min_disparity - 1) * 16
    for given, threshold in ((rng.uniform(0, 4, (height, width)).astype(np.float32), 1.5), (None, 0.0)):
        tex = np.zeros((0, 0), np.float32) if given is None else given
        ours = valid_disparity(raw, pad_left, width, min_disparity, tex, np.float32(threshold))
        oracle = reference_valid_disparity(raw, pad_left, width, min_disparity, tex, threshold)
        np.testing.assert_array_equal(ours, oracle)  # NaN where the oracle has NaN
        assert np.isnan(ours).any() and np.isfinite(ours).any()
        for offset in (0.0, 7.5, -3.0):
            np.testing.assert_array_equal(
                depth_of_disparity(ours, 12.5, offset), reference_depth(ours, 12.5, offset)
            )
