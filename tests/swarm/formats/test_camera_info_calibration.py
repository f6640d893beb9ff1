"""ROS camera_info calibrations: a left/right pair equals OpenCV's rectification, echoed
messages, the camera_calibration tool's ost.txt/.ini, binned cameras, what is refused by name."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError, rectify_stereo
from tests.support.calibration_files import (
    D1,
    D2,
    K1,
    K2,
    SIZE,
    R,
    T,
    camera_infos,
)


def test_camera_info_pair_equals_the_opencv_rectification(tmp_path):
    left, right = camera_infos(tmp_path)
    got = load_stereo_calibration(left, right)
    want = rectify_stereo(K1, D1, K2, D2, R, T, SIZE)
    assert got.baseline == pytest.approx(np.linalg.norm(T), rel=1e-6)
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right"):
        assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-9)
    raw = np.random.default_rng(0).integers(0, 255, (SIZE[1], SIZE[0]), dtype=np.uint8)
    for a, b in zip(got.rectify(raw, raw), want.rectify(raw, raw), strict=True):
        assert np.array_equal(a, b)


def test_camera_info_alone_or_swapped_is_refused_by_name(tmp_path):
    left, right = camera_infos(tmp_path)
    with pytest.raises(CalibrationError, match="right camera's too"):
        load_stereo_calibration(left)
    with pytest.raises(CalibrationError, match=r"right.yaml: projection_matrix: P\[0\]\[3\] = .* swapped"):
        load_stereo_calibration(right, left)


def test_camera_info_sizes_written_as_whole_floats_load(tmp_path):
    """``image_width: 640.0``, as some tools write it, is 640; 640.5 is refused naming the fields."""
    left, right = camera_infos(tmp_path)
    want = load_stereo_calibration(left, right)
    for path in (left, right):
        info = yaml.safe_load(path.read_text())
        info["image_width"], info["image_height"] = float(SIZE[0]), float(SIZE[1])
        path.write_text(yaml.safe_dump(info))
    got = load_stereo_calibration(left, right)
    assert (got.fx, got.baseline, got.image_size) == (want.fx, want.baseline, want.image_size)
    info["image_width"] = SIZE[0] + 0.5
    right.write_text(yaml.safe_dump(info))
    with pytest.raises(
        CalibrationError, match=r"right.yaml: image_width, image_height: must be positive integers"
    ):
        load_stereo_calibration(left, right)


def test_yaml_document_separators(tmp_path):
    """``---`` after a document (how ``rostopic echo`` ends a message) is not a second calibration;
    documents that differ are refused by name."""
    left, right = camera_infos(tmp_path)
    for path in (left, right):
        path.write_text("---\n" + path.read_text() + "---\n")
    assert load_stereo_calibration(left, right).baseline == pytest.approx(np.linalg.norm(T), rel=1e-6)
    right.write_text(right.read_text() + left.read_text())
    with pytest.raises(CalibrationError, match=r"right.yaml: holds 2 different YAML documents"):
        load_stereo_calibration(left, right)


def _echoed_camera_infos(tmp_path, ros: int):
    """The two CameraInfo messages as ``rostopic echo -n 1`` (ROS 1: ``K D R P``, flow lists) or
    ``ros2 topic echo --once`` (ROS 2: ``k d r p``, block lists) print them, ``---`` at the end."""
    r1, r2, p1, p2, *_ = cv2.stereoRectify(
        K1, D1, K2, D2, SIZE, R, T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    paths = []
    for name, k, d, r, p in (("left", K1, D1, r1, p1), ("right", K2, D2, r2, p2)):
        fields = {"d": d, "k": k, "r": r, "p": p}
        if ros == 1:
            stamp = 'header: \n  seq: 7\n  stamp: \n    secs: 1700000000\n    nsecs: 5\n  frame_id: "cam"\n'
            body = "".join(f"{f.upper()}: {np.ravel(v).tolist()}\n" for f, v in fields.items())
        else:
            stamp = "header:\n  stamp:\n    sec: 1700000000\n    nanosec: 5000\n  frame_id: cam\n"
            body = yaml.safe_dump({f: np.ravel(v).tolist() for f, v in fields.items()}, sort_keys=False)
        text = (
            f"{stamp}height: {SIZE[1]}\nwidth: {SIZE[0]}\ndistortion_model: plumb_bob\n{body}"
            "binning_x: 0\nbinning_y: 0\nroi:\n  x_offset: 0\n  y_offset: 0\n  height: 0\n  width: 0\n"
            "  do_rectify: false\n---\n"
        )
        path = tmp_path / f"{name}_info{ros}.yaml"
        path.write_text(text)
        paths.append(path)
    return paths


@pytest.mark.parametrize("ros", [1, 2])
def test_echoed_camera_info_messages(tmp_path, ros):
    want = load_stereo_calibration(*camera_infos(tmp_path))
    left, right = _echoed_camera_infos(tmp_path, ros)
    got = load_stereo_calibration(left, right)
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right", "image_size"):
        assert getattr(got, field) == getattr(want, field)
    with pytest.raises(CalibrationError, match="right camera's too"):
        load_stereo_calibration(left)


def _ost_block(name: str, k: np.ndarray, d: np.ndarray, r: np.ndarray, p: np.ndarray) -> str:
    """One camera as ROS camera_calibration's calibrator writes it to ost.txt (numbers as %8f)."""
    rows = lambda m: "\n".join(" ".join(f"{v:8f}" for v in row) for row in np.atleast_2d(m))  # noqa: E731
    return (
        f"# oST version 5.0 parameters\n\n\n[image]\n\nwidth\n{SIZE[0]}\n\nheight\n{SIZE[1]}\n\n"
        f"[{name}]\n\ncamera matrix\n{rows(k)}\n\ndistortion\n{rows(d)}\n\n"
        f"rectification\n{rows(r)}\n\nprojection\n{rows(p)}\n\n"
    )


def test_ros_camera_calibration_ost_txt_and_ini_files_load_as_their_yaml(tmp_path):
    """ROS camera_calibration's tarball holds ost.txt (both cameras, INI form) beside left.yaml and
    right.yaml; camera_info_manager reads .ini files too (ros-perception/image_common#33). Both
    were refused ('cam0: required field is missing', 'not valid YAML'); they give the YAML's rig."""
    r1, r2, p1, p2, *_ = cv2.stereoRectify(
        K1, D1, K2, D2, SIZE, R, T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    want = load_stereo_calibration(*camera_infos(tmp_path))
    left = _ost_block("narrow_stereo/left", K1, D1, r1, p1)
    right = _ost_block("narrow_stereo/right", K2, D2, r2, p2)
    (tmp_path / "ost.txt").write_text(left + right)
    (tmp_path / "left.ini").write_text(left)
    (tmp_path / "right.ini").write_text(right)
    for got in (
        load_stereo_calibration(tmp_path / "ost.txt"),
        load_stereo_calibration(tmp_path / "left.ini", tmp_path / "right.ini"),
        load_stereo_calibration(tmp_path / "left.yaml", tmp_path / "right.ini"),
    ):
        for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right"):
            assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-5), field
        assert got.image_size == SIZE and got.maps is not None
    eight = _ost_block("cam", K1, np.r_[D1, 0.01, 0.0, 0.0], r1, p1)  # rational_polynomial
    (tmp_path / "left8.ini").write_text(eight)
    assert load_stereo_calibration(tmp_path / "left8.ini", tmp_path / "right.ini").baseline > 0
    with pytest.raises(CalibrationError, match=r"left.ini: a camera_info INI file describes one camera"):
        load_stereo_calibration(tmp_path / "left.ini")
    (tmp_path / "bad.ini").write_text(left.replace("distortion\n", "distortion\n0.1 x 0.2\n", 1))
    with pytest.raises(
        CalibrationError,
        match=r"bad.ini: \[narrow_stereo/left\]: distortion_coefficients: line \d+: not numbers",
    ):
        load_stereo_calibration(tmp_path / "bad.ini", tmp_path / "right.ini")


def test_camera_info_with_the_baseline_alone_in_p03_is_refused(tmp_path):
    """P[0][3] must be -fx * baseline; a driver that writes -baseline (metres) would give 0.4 mm."""
    left, right = camera_infos(tmp_path)
    info = yaml.safe_load(right.read_text())
    info["projection_matrix"]["data"][3] = -float(np.linalg.norm(T))
    right.write_text(yaml.safe_dump(info))
    with pytest.raises(
        CalibrationError, match=r"right.yaml: projection_matrix: P\[0\]\[3\] = -0.12.* gives a baseline"
    ):
        load_stereo_calibration(left, right)


@pytest.mark.parametrize("binning", [2, 4])
def test_camera_info_file_of_a_binned_camera_is_scaled_as_a_topic_is(tmp_path, binning):
    """A CameraInfo saved with ``ros2 topic echo`` from a binning driver keeps the full sensor's size,
    K and P with ``binning_x``, ``binning_y`` (REP-104): the file gives the binned images'
    calibration, as the bag's CameraInfo topic does, instead of a size mismatch on the images."""
    full = load_stereo_calibration(*camera_infos(tmp_path))
    for path in camera_infos(tmp_path):
        info = yaml.safe_load(path.read_text())
        path.write_text(yaml.safe_dump({**info, "binning_x": binning, "binning_y": binning}))
    binned = load_stereo_calibration(tmp_path / "left.yaml", tmp_path / "right.yaml")
    assert binned.image_size == (SIZE[0] // binning, SIZE[1] // binning)
    for field in ("fx", "fy", "cx", "cy", "cx_right"):
        assert getattr(binned, field) == pytest.approx(getattr(full, field) / binning, rel=1e-12)
    assert binned.baseline == pytest.approx(full.baseline, rel=1e-12)
    raw = np.zeros((SIZE[1] // binning, SIZE[0] // binning), np.uint8)
    assert binned.rectify(raw, raw)[0].shape == raw.shape


@pytest.mark.parametrize(
    ("roi", "refused"),
    [
        ({"x_offset": 0, "y_offset": 0, "width": 0, "height": 0, "do_rectify": False}, False),
        ({"x_offset": 0, "y_offset": 0, "width": SIZE[0], "height": SIZE[1], "do_rectify": False}, False),
        ({"x_offset": 8, "y_offset": 4, "width": 200, "height": 100, "do_rectify": True}, True),
        ("all", True),
    ],
)
def test_camera_info_file_with_a_region_of_interest_is_refused_by_name(tmp_path, roi, refused):
    left, right = camera_infos(tmp_path)
    left.write_text(yaml.safe_dump({**yaml.safe_load(left.read_text()), "roi": roi}))
    if not refused:
        assert load_stereo_calibration(left, right).image_size == SIZE
        return
    with pytest.raises(CalibrationError, match=r"left.yaml: roi: ") as info:
        load_stereo_calibration(left, right)
    assert "\n" not in str(info.value)
