"""Calibration readers: ROS camera_info pairs, EuRoC/Kalibr sensor.yaml pairs, Middlebury calib.txt,
OpenCV files with stereoRectify's extra outputs."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError, rectify_stereo
from tests.support.calibration_files import D1, D2, EUROC_CAM0, EUROC_CAM1, K1, K2, SIZE, R, _matrix
from tests.support.paths import TEST_DATA

T = np.array([-0.12, 0.002, 0.001])


def _camera_infos(tmp_path):
    r1, r2, p1, p2, *_ = cv2.stereoRectify(
        K1, D1, K2, D2, SIZE, R, T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    paths = []
    for name, k, d, r, p in (("left", K1, D1, r1, p1), ("right", K2, D2, r2, p2)):
        info = {
            "image_width": SIZE[0],
            "image_height": SIZE[1],
            "camera_name": name,
            "camera_matrix": _matrix(k),
            "distortion_model": "plumb_bob",
            "distortion_coefficients": _matrix(d),
            "rectification_matrix": _matrix(r),
            "projection_matrix": _matrix(p),
        }
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(info))
        paths.append(path)
    return paths


def test_camera_info_pair_equals_the_opencv_rectification(tmp_path):
    left, right = _camera_infos(tmp_path)
    got = load_stereo_calibration(left, right)
    want = rectify_stereo(K1, D1, K2, D2, R, T, SIZE)
    assert got.baseline == pytest.approx(np.linalg.norm(T), rel=1e-6)
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right"):
        assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-9)
    raw = np.random.default_rng(0).integers(0, 255, (SIZE[1], SIZE[0]), dtype=np.uint8)
    for a, b in zip(got.rectify(raw, raw), want.rectify(raw, raw), strict=True):
        assert np.array_equal(a, b)


def test_camera_info_alone_or_swapped_is_refused_by_name(tmp_path):
    left, right = _camera_infos(tmp_path)
    with pytest.raises(CalibrationError, match="right camera's too"):
        load_stereo_calibration(left)
    with pytest.raises(CalibrationError, match=r"right.yaml: projection_matrix: P\[0\]\[3\] = .* swapped"):
        load_stereo_calibration(right, left)


@pytest.mark.parametrize("resolution", ["[-752, 480]", "[0, 480]", "[752.5, 480]"])
def test_euroc_resolution_that_cannot_be_is_refused_naming_it(tmp_path, resolution):
    """A negative width reached OpenCV as a cv2.error traceback (an 18-exabyte allocation), a zero
    one as 'the second camera must be to the right', 752.5 was cut to 752."""
    (tmp_path / "cam0.yaml").write_text(EUROC_CAM0.replace("[752, 480]", resolution))
    (tmp_path / "cam1.yaml").write_text(EUROC_CAM1)
    with pytest.raises(
        CalibrationError, match=r"cam0.yaml: resolution: must be \[width, height\], two whole"
    ):
        load_stereo_calibration(tmp_path / "cam0.yaml", tmp_path / "cam1.yaml")


def test_euroc_sensor_yaml_pair(tmp_path):
    (tmp_path / "cam0.yaml").write_text(EUROC_CAM0)
    (tmp_path / "cam1.yaml").write_text(EUROC_CAM1)
    calib = load_stereo_calibration(tmp_path / "cam0.yaml", tmp_path / "cam1.yaml")
    # The two T_BS translations are 0.110 m apart (EuRoC's VI-sensor baseline).
    assert calib.baseline == pytest.approx(0.1101, abs=5e-4)
    assert calib.image_size == (752, 480)
    assert calib.cx_right == pytest.approx(calib.cx)
    assert np.degrees(np.arccos((np.trace(calib.left_rotation) - 1) / 2)) < 2.0
    with pytest.raises(CalibrationError, match="cam1's sensor.yaml too"):
        load_stereo_calibration(tmp_path / "cam0.yaml")


def test_middlebury_calib_txt(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(
        "cam0=[1000.5 0 300.25; 0 1000.5 200; 0 0 1]\ncam1=[1000.5 0 320.75; 0 1000.5 200; 0 0 1]\n"
        "doffs=20.5\nbaseline=176.25\nwidth=640\nheight=400\nndisp=120\nisint=0\nvmin=10\nvmax=100\n"
    )
    calib = load_stereo_calibration(path)
    assert calib.baseline == pytest.approx(0.17625)
    assert calib.disparity_offset == pytest.approx(20.5)
    assert (calib.fx, calib.cx, calib.image_size, calib.ndisp) == (1000.5, 300.25, (640, 400), 120)
    path.write_text("cam0=[1000 0 300; 0 1000 200; 0 0 1]\ncam1=[1000 0 320; 0 1000 200; 0 0 1]\nwidth=640\n")
    with pytest.raises(CalibrationError, match="calib.txt: baseline: required field is missing"):
        load_stereo_calibration(path)


@pytest.mark.parametrize(
    ("line", "field"),
    [("ndisp=-5", "ndisp"), ("ndisp=0", "ndisp"), ("ndisp=120.5", "ndisp"), ("width=640.5", "width"),
     ("height=0", "height"), ("baseline=nan", "baseline"), ("doffs=inf", "doffs")],
)  # fmt: skip
def test_middlebury_numbers_that_cannot_be_are_refused_naming_the_field(tmp_path, line, field):
    """A negative ndisp reached the matcher as 'need 0 < min_depth < max_depth, got -1.0, inf', a
    width of 640.5 was cut to 640: each is now refused by its field."""
    good = {"cam0": "[1000 0 300; 0 1000 200; 0 0 1]", "cam1": "[1000 0 320; 0 1000 200; 0 0 1]",
            "doffs": "20", "baseline": "176", "width": "640", "height": "400", "ndisp": "120"}  # fmt: skip
    key, value = line.split("=")
    path = tmp_path / "calib.txt"
    path.write_text("".join(f"{k}={value if k == key else v}\n" for k, v in good.items()))
    with pytest.raises(
        CalibrationError, match=rf"calib.txt: {field}: must be a (whole|finite) number"
    ) as info:
        load_stereo_calibration(path)
    assert "\n" not in str(info.value)


def test_an_opencv_matrix_whose_rows_and_cols_miss_its_data_is_refused_naming_both(tmp_path):
    text = _opencv_storage({"M1": K1, "D1": D1, "M2": K2, "D2": D2, "R": R, "T": T})
    text = text.replace("rows: 3\n   cols: 3", "rows: 3\n   cols: 2", 1) + f"image_size: {list(SIZE)}\n"
    (tmp_path / "stereo.yml").write_text(text)
    with pytest.raises(
        CalibrationError, match=r"stereo.yml: M1: rows x cols is 3 x 2 but data holds 9 numbers"
    ):
        load_stereo_calibration(tmp_path / "stereo.yml")


def test_camera_info_sizes_written_as_whole_floats_load(tmp_path):
    """``image_width: 640.0``, as some tools write it, is 640; 640.5 is refused naming the fields."""
    left, right = _camera_infos(tmp_path)
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


def test_opencv_file_with_stereo_rectify_outputs_loads_with_a_note(tmp_path):
    r1, r2, p1, p2, q, *_ = cv2.stereoRectify(K1, D1, K2, D2, SIZE, R, T.reshape(3, 1))
    e = np.eye(3)
    lines = ["%YAML:1.0"]
    for name, m in {"M1": K1, "D1": D1, "M2": K2, "D2": D2, "R": R, "T": T, "E": e, "F": e,
                    "R1": r1, "R2": r2, "P1": p1, "P2": p2, "Q": q}.items():  # fmt: skip
        m = np.atleast_2d(m)
        data = ", ".join(f"{v:.12g}" for v in m.ravel())
        head = f"{name}: !!opencv-matrix\n   rows: {m.shape[0]}\n   cols: {m.shape[1]}\n   dt: d"
        lines.append(f"{head}\n   data: [{data}]")
    lines.append(f"image_size: [{SIZE[0]}, {SIZE[1]}]")
    path = tmp_path / "stereo.yml"
    path.write_text("\n".join(lines) + "\n")
    calib = load_stereo_calibration(path)
    assert calib.baseline == pytest.approx(np.linalg.norm(T), rel=1e-6)
    assert any("E, F, R1, R2, P1, P2, Q: ignored" in note for note in calib.notes)


def _plain_opencv_yaml(**extra) -> str:
    """A full calibration in plain YAML plus ``extra`` top-level fields."""
    data = {"K1": K1.tolist(), "D1": D1.tolist(), "K2": K2.tolist(), "D2": D2.tolist(), "R": R.tolist()}
    data |= {"T": T.tolist(), "image_size": list(SIZE)} | extra
    return yaml.safe_dump(data)


def test_what_calibration_tools_add_beside_the_calibration_is_ignored_with_a_note(tmp_path):
    """calibration_time, reprojection errors, board sizes: written by OpenCV's samples and other
    tools; the file loads, with the same numbers as without them, and a note names them."""
    added = {
        "calibration_time": "Mon Nov 30 10:00:00 2026",
        "avg_reprojection_error": 0.21,
        "rmsErr": 0.3,
        "board_width": 9,
        "board_height": 6,
        "square_size": 0.025,
        "Valid_ROI_Left": [0, 0, 320, 240],
    }
    (tmp_path / "plain.yaml").write_text(_plain_opencv_yaml())
    (tmp_path / "tool.yaml").write_text(_plain_opencv_yaml(**added))
    plain = load_stereo_calibration(tmp_path / "plain.yaml")
    tool = load_stereo_calibration(tmp_path / "tool.yaml")
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right"):
        assert getattr(tool, field) == getattr(plain, field)
    (note,) = [n for n in tool.notes if "ignored" in n]
    assert all(name in note for name in added)


@pytest.mark.parametrize(("typo", "field"), [("alpah", "alpha"), ("image_sise", "image_size"), ("R_1", "R1")])
def test_a_misspelt_field_is_refused_naming_the_field_it_resembles(tmp_path, typo, field):
    (tmp_path / "typo.yaml").write_text(_plain_opencv_yaml(**{typo: 0}))
    with pytest.raises(
        CalibrationError, match=rf"typo.yaml: {typo}: unknown field \(did you mean {field}\?\)"
    ):
        load_stereo_calibration(tmp_path / "typo.yaml")


def _opencv_storage(mats: dict) -> str:
    """An OpenCV FileStorage YAML (``%YAML:1.0``, ``---``, ``!!opencv-matrix`` nodes, data on
    several lines) as ``cv::FileStorage`` writes it."""
    lines = ["%YAML:1.0", "---"]
    for name, m in mats.items():
        m = np.atleast_2d(m)
        values = [f"{v:.16e}" for v in m.ravel()]
        data = ",\n       ".join(", ".join(values[i : i + 3]) for i in range(0, len(values), 3))
        lines.append(f"{name}: !!opencv-matrix\n   rows: {m.shape[0]}\n   cols: {m.shape[1]}\n   dt: d")
        lines.append(f"   data: [ {data} ]")
    return "\n".join(lines) + "\n"


def test_files_saved_by_windows_editors_load(tmp_path):
    """A byte-order mark and CRLF line ends (Notepad's UTF-8) on a FileStorage file and a calib.txt."""
    text = _opencv_storage({"M1": K1, "D1": D1, "M2": K2, "D2": D2, "R": R, "T": T})
    text += f"image_size: [ {SIZE[0]}, {SIZE[1]} ]\n"
    path = tmp_path / "stereo.yml"
    path.write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())
    assert load_stereo_calibration(path).baseline == pytest.approx(np.linalg.norm(T), rel=1e-6)
    mb = tmp_path / "calib"
    mb.write_bytes(
        b"\xef\xbb\xbfcam0=[1000 0 300; 0 1000 200; 0 0 1]\r\ncam1=[1000 0 320; 0 1000 200; 0 0 1]\r\n"
        b"doffs=20\r\nbaseline=150\r\n"
    )
    assert load_stereo_calibration(mb).baseline == pytest.approx(0.15)


def test_a_file_not_in_utf8_is_refused_by_name(tmp_path):
    path = tmp_path / "stereo.yml"
    path.write_bytes(b"%YAML:1.0\n# square size 25 \xb5m\nfx: 1\n")
    with pytest.raises(CalibrationError, match=r"stereo.yml: not UTF-8 text \(byte 0xb5 at offset 27\)"):
        load_stereo_calibration(path)


def test_yaml_document_separators(tmp_path):
    """``---`` after a document (how ``rostopic echo`` ends a message) is not a second calibration;
    documents that differ are refused by name."""
    left, right = _camera_infos(tmp_path)
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
    want = load_stereo_calibration(*_camera_infos(tmp_path))
    left, right = _echoed_camera_infos(tmp_path, ros)
    got = load_stereo_calibration(left, right)
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right", "image_size"):
        assert getattr(got, field) == getattr(want, field)
    with pytest.raises(CalibrationError, match="right camera's too"):
        load_stereo_calibration(left)


def test_opencv_stereo_calib_sample_two_files(tmp_path):
    """OpenCV's stereo_calib sample writes intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml
    (R T R1 R2 P1 P2 Q), and no image size: the pair loads, the size taken from the images."""
    r1, r2, p1, p2, q, *_ = cv2.stereoRectify(K1, D1, K2, D2, SIZE, R, T.reshape(3, 1), alpha=1)
    intrinsics, extrinsics = tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"
    intrinsics.write_text(_opencv_storage({"M1": K1, "D1": D1, "M2": K2, "D2": D2}))
    extrinsics.write_text(
        _opencv_storage({"R": R, "T": T.reshape(3, 1), "R1": r1, "R2": r2, "P1": p1, "P2": p2, "Q": q})
    )
    want = rectify_stereo(K1, D1, K2, D2, R, T, SIZE)
    for pair in ((intrinsics, extrinsics), (extrinsics, intrinsics)):
        got = load_stereo_calibration(*pair, image_size=SIZE)
        for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right", "image_size"):
            assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-9)
        assert any("image_size: not in the file, taken from the images (320x240)" in n for n in got.notes)
    with pytest.raises(CalibrationError, match=r"image_size: required field is missing \(add image_size"):
        load_stereo_calibration(intrinsics, extrinsics)
    with pytest.raises(CalibrationError, match=r"intrinsics.yml: T: required field is missing \(OpenCV"):
        load_stereo_calibration(intrinsics, image_size=SIZE)


def test_stereo_depth_reads_the_two_stereo_calib_files(tmp_path, capsys):
    """``swarm stereo depth --calib intrinsics.yml --calib-right extrinsics.yml``: the size is the images'."""
    from tests.support.stereo_scenes import BASELINE, CX, CY, FX, cli, relative_error, synthetic_pair

    left, right, truth = synthetic_pair(6)
    cv2.imwrite(str(tmp_path / "left.png"), left)
    cv2.imwrite(str(tmp_path / "right.png"), right)
    k = np.array([[FX, 0, CX], [0, FX, CY], [0, 0, 1]])
    (tmp_path / "intrinsics.yml").write_text(
        _opencv_storage({"M1": k, "D1": np.zeros(5), "M2": k, "D2": np.zeros(5)})
    )
    (tmp_path / "extrinsics.yml").write_text(
        _opencv_storage({"R": np.eye(3), "T": np.array([-BASELINE, 0, 0])})
    )
    d = str(tmp_path)
    rc = cli([f"{d}/left.png", f"{d}/right.png", "--calib", f"{d}/intrinsics.yml",
              "--calib-right", f"{d}/extrinsics.yml", "--out", f"{d}/depth.npy"])  # fmt: skip
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert f"taken from the images ({left.shape[1]}x{left.shape[0]})" in out.out
    assert relative_error(np.load(tmp_path / "depth.npy"), truth)[0] < 0.03


@pytest.mark.parametrize(
    ("model", "intrinsics"), [("omni", [0.9, 460, 460, 367, 248]), ("ds", [-0.2, 0.6, 350, 350, 367, 248])]
)
def test_kalibr_camchain_of_another_camera_model_is_refused_naming_it(tmp_path, model, intrinsics):
    """kalibr_calibrate_cameras --models omni-radtan / ds-none: refused for camera_model, not intrinsics."""
    cam = {"camera_model": model, "intrinsics": intrinsics, "distortion_model": "radtan",
           "distortion_coeffs": [0.0] * 4, "resolution": [752, 480], "rostopic": "/cam0"}  # fmt: skip
    pose = np.eye(4)
    pose[0, 3] = -0.11
    chain = {"cam0": cam, "cam1": {**cam, "T_cn_cnm1": pose.tolist(), "cam_overlaps": [0]}}
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.safe_dump(chain))
    with pytest.raises(
        CalibrationError, match=f"camchain.yaml: cam0: camera_model: '{model}' is not supported"
    ):
        load_stereo_calibration(path)


def test_kalibr_forms_name_their_own_extrinsics_field(tmp_path):
    """EuRoC sensor.yaml pairs and camchain.yaml have no ``T``: a swapped pair or a translation in
    millimetres (silently a 110 m baseline before) is refused naming T_BS / cam1.T_cn_cnm1."""
    (tmp_path / "cam0.yaml").write_text(EUROC_CAM0)
    (tmp_path / "cam1.yaml").write_text(EUROC_CAM1)
    with pytest.raises(
        CalibrationError, match=r"cam0.yaml: T_BS: the second camera must be to the right .*swapped"
    ):
        load_stereo_calibration(tmp_path / "cam1.yaml", tmp_path / "cam0.yaml")
    mm = {
        "-0.0216401454975": "-21.6401454975",
        "-0.064676986768": "-64.676986768",
        "0.00981073058949": "9.81073058949",
    }
    text = EUROC_CAM0
    for metres, millimetres in mm.items():
        text = text.replace(metres, millimetres)
    (tmp_path / "cam0_mm.yaml").write_text(text)
    with pytest.raises(CalibrationError, match=r"T_BS: the cameras are [0-9.]+ m apart; must be in metres"):
        load_stereo_calibration(tmp_path / "cam0_mm.yaml", tmp_path / "cam1.yaml")
    pose = np.eye(4)
    pose[:3, 3] = [-110.0, 0.2, 0.9]  # millimetres
    cam = {"camera_model": "pinhole", "intrinsics": [458.6, 457.3, 367, 248], "distortion_model": "radtan",
           "distortion_coeffs": [-0.28, 0.07, 0.0, 0.0], "resolution": [752, 480]}  # fmt: skip
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.safe_dump({"cam0": cam, "cam1": {**cam, "T_cn_cnm1": pose.tolist()}}))
    with pytest.raises(
        CalibrationError, match=r"^\S*camchain.yaml: cam1.T_cn_cnm1: the cameras are 110.004 m apart"
    ):
        load_stereo_calibration(path)


def test_opencv_file_with_image_width_and_height(tmp_path):
    """``image_width`` / ``image_height`` (the names OpenCV's calibration sample writes, and many
    hand-written FileStorage stereo files use) stand for ``image_size``."""
    text = _opencv_storage({"K1": K1, "D1": D1, "K2": K2, "D2": D2, "R": R, "T": T.reshape(3, 1)})
    path = tmp_path / "stereo_calib.yml"
    path.write_text(text.replace("---\n", f"---\nimage_width: {SIZE[0]}\nimage_height: {SIZE[1]}\n"))
    got = load_stereo_calibration(path)
    want = rectify_stereo(K1, D1, K2, D2, R, T, SIZE)
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right", "image_size"):
        assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-9)
    path.write_text(text.replace("---\n", f"---\nimage_width: {SIZE[0]}\n"))
    with pytest.raises(CalibrationError, match="stereo_calib.yml: image_width, image_height: give both"):
        load_stereo_calibration(path)


def test_an_empty_file_is_called_empty(tmp_path):
    left, _right = _camera_infos(tmp_path)
    empty = tmp_path / "right.yaml"
    empty.write_text("# saved before the calibration finished\n---\n")
    for args in ((empty,), (left, empty)):
        with pytest.raises(CalibrationError, match=r"right.yaml: the file is empty"):
            load_stereo_calibration(*args)


def test_a_txt_of_neither_text_form_says_what_was_expected(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("left camera: fx 300, cx 161\n")
    with pytest.raises(
        CalibrationError, match=r"notes.txt: cam0: required field is missing .*Middlebury .* ost.txt"
    ):
        load_stereo_calibration(path)


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
    want = load_stereo_calibration(*_camera_infos(tmp_path))
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


# -- equidistant (fisheye) cameras ----------------------------------------------------------------
FISH_SIZE = (400, 300)
FISH_K = np.array([[190.0, 0, 201.0], [0, 191.0, 148.0], [0, 0, 1]])
FISH_D = np.array([0.02, -0.01, 0.004, -0.001])  # k1..k4 of the equidistant model
FISH_R = cv2.Rodrigues(np.array([0.01, 0.02, -0.01]))[0]
FISH_T = np.array([-0.1, 0.001, 0.002])


def _dots_seen_by(calib, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rectified (u, v) of each 3-D point (left raw camera frame) in the left and right images:
    a dot drawn where cv2.fisheye projects it in each raw image, rectified by ``calib``, found
    again as the brightest spot's centroid."""
    rvec2 = cv2.Rodrigues(FISH_R)[0]
    found = []
    for side, (rvec, tvec) in enumerate(((np.zeros(3), np.zeros(3)), (rvec2.ravel(), FISH_T))):
        raw_uv = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), rvec, tvec, FISH_K, FISH_D)[0].reshape(
            -1, 2
        )
        spots = []
        for u, v in raw_uv:
            image = np.zeros(FISH_SIZE[::-1], np.uint8)
            cv2.circle(image, (round(u * 16), round(v * 16)), 3 * 16, 255, -1, cv2.LINE_AA, shift=4)
            rect = calib.rectify(image, image)[side]
            ys, xs = np.nonzero(rect > 128)
            w = rect[ys, xs].astype(np.float64)
            spots.append((np.sum(xs * w) / w.sum(), np.sum(ys * w) / w.sum()))
        found.append(np.array(spots))
    return found[0], found[1]


def _check_fisheye_rectification(calib) -> None:
    points = np.array([[x, y, z] for z in (1.0, 2.5) for x in (-0.4, 0.0, 0.4) for y in (-0.2, 0.25)])
    left, right = _dots_seen_by(calib, points)
    assert calib.baseline == pytest.approx(np.linalg.norm(FISH_T), rel=1e-6)
    np.testing.assert_allclose(left[:, 1], right[:, 1], atol=0.3)  # same row after rectification
    # depth along the rectified axis: the point turned into the rectified left camera
    z = (points @ calib.left_rotation.T)[:, 2]
    disparity = left[:, 0] - right[:, 0] + (calib.cx_right - calib.cx)
    np.testing.assert_allclose(disparity, calib.fx * calib.baseline / z, rtol=0.02, atol=0.3)


def test_kalibr_equidistant_camchain_rectifies_a_fisheye_pair(tmp_path):
    """Kalibr's equidistant model (TUM-VI, RealSense T265 calibrations): rectified with cv2.fisheye,
    3-D points land on one row in both images at the disparity f b / Z."""
    right_from_left = np.eye(4)
    right_from_left[:3, :3], right_from_left[:3, 3] = FISH_R, FISH_T
    cam = {"camera_model": "pinhole", "distortion_model": "equidistant", "resolution": list(FISH_SIZE)}
    cam |= {"intrinsics": [190.0, 191.0, 201.0, 148.0], "distortion_coeffs": FISH_D.tolist()}
    chain = {"cam0": dict(cam), "cam1": dict(cam, T_cn_cnm1=right_from_left.tolist())}
    (tmp_path / "camchain.yaml").write_text(yaml.safe_dump(chain))
    _check_fisheye_rectification(load_stereo_calibration(tmp_path / "camchain.yaml"))


def test_ros_camera_info_pair_with_the_equidistant_model_rectifies_a_fisheye_pair(tmp_path):
    r1, r2, p1, p2, _q = cv2.fisheye.stereoRectify(
        FISH_K, FISH_D, FISH_K, FISH_D, FISH_SIZE, FISH_R, FISH_T.reshape(3, 1), cv2.CALIB_ZERO_DISPARITY
    )
    paths = []
    for name, r, p in (("left", r1, p1), ("right", r2, p2)):
        info = {"image_width": FISH_SIZE[0], "image_height": FISH_SIZE[1], "distortion_model": "equidistant"}
        info |= {"camera_matrix": _matrix(FISH_K), "distortion_coefficients": _matrix(FISH_D)}
        info |= {"rectification_matrix": _matrix(r), "projection_matrix": _matrix(p)}
        paths.append(tmp_path / f"{name}.yaml")
        paths[-1].write_text(yaml.safe_dump(info))
    _check_fisheye_rectification(load_stereo_calibration(*paths))
    # the RealSense T265 driver's five, the fifth 0 (realsenseai/realsense-ros#1989): the same rig
    info["distortion_coefficients"] = _matrix(np.r_[FISH_D, 0.0])
    paths[1].write_text(yaml.safe_dump(info))
    _check_fisheye_rectification(load_stereo_calibration(*paths))
    info["distortion_coefficients"] = _matrix(np.r_[FISH_D, 0.01])
    paths[1].write_text(yaml.safe_dump(info))
    with pytest.raises(
        CalibrationError,
        match=r"right.yaml: distortion_coefficients: the equidistant \(fisheye\) model has 4 coefficients "
        r"k1..k4, got 5 with non-zero ones past the fourth \(\[0.01\]\)",
    ):
        load_stereo_calibration(*paths)


def test_camera_info_with_the_baseline_alone_in_p03_is_refused(tmp_path):
    """P[0][3] must be -fx * baseline; a driver that writes -baseline (metres) would give 0.4 mm."""
    left, right = _camera_infos(tmp_path)
    info = yaml.safe_load(right.read_text())
    info["projection_matrix"]["data"][3] = -float(np.linalg.norm(T))
    right.write_text(yaml.safe_dump(info))
    with pytest.raises(
        CalibrationError, match=r"right.yaml: projection_matrix: P\[0\]\[3\] = -0.12.* gives a baseline"
    ):
        load_stereo_calibration(left, right)


def test_a_yaml_syntax_error_is_one_line_with_its_place(tmp_path):
    (tmp_path / "bad.yaml").write_text("fx: 1\nfy: [1, 2\ncx: 3\n")
    with pytest.raises(CalibrationError) as info:
        load_stereo_calibration(tmp_path / "bad.yaml")
    assert str(info.value).endswith(
        "bad.yaml: not valid YAML: expected ',' or ']', but got ':', at line 3, column 3"
    )
    assert "\n" not in str(info.value)


def test_a_misspelt_field_of_a_sensor_yaml_is_pointed_at(tmp_path):
    euroc = TEST_DATA / "euroc_mini" / "mav0"
    text = (euroc / "cam0/sensor.yaml").read_text().replace("intrinsics:", "intrinsic:")
    (tmp_path / "sensor.yaml").write_text(text)
    with pytest.raises(
        CalibrationError, match=r"intrinsics: required field is missing \(is intrinsic a misspelling"
    ):
        load_stereo_calibration(tmp_path / "sensor.yaml", euroc / "cam1/sensor.yaml")


def _expected_rectification() -> tuple[float, float]:
    """fx and baseline of the reference rig, from cv2.stereoRectify itself."""
    _r1, _r2, p1, p2, *_ = cv2.stereoRectify(
        K1, D1, K2, D2, SIZE, R, T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    return float(p1[0, 0]), float(-p2[0, 3] / p2[0, 0])


def _write_storage(path: Path, fields: dict) -> Path:
    """A FileStorage file written by OpenCV itself; its encoding follows the name (.yml, .xml, .gz)."""
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in fields.items():
        storage.write(name, value)
    storage.release()
    return path


@pytest.mark.parametrize("name", ["stereo.xml", "stereo.xml.gz", "stereo.yml.gz", "stereo.yml"])
@pytest.mark.parametrize("flat", [False, True])
def test_opencv_writes_any_filestorage_encoding_and_it_loads(tmp_path, name, flat):
    """cv::FileStorage writes XML and gzip as readily as YAML (OpenCV's calibration samples take
    ``-o out.xml``), and a 1-D array as ``!!opencv-nd-matrix`` (opencv/opencv#22118 and #5836 are
    about other readers failing on these files): all load as the YAML form does."""
    shape = (lambda a: np.asarray(a).ravel()) if flat else np.atleast_2d
    fields = {"M1": K1, "D1": shape(D1), "M2": K2, "D2": shape(D2), "R": R, "T": shape(T)}
    fields["image_size"] = np.array(SIZE, np.int32) if flat else np.array([SIZE], np.int32)
    cal = load_stereo_calibration(_write_storage(tmp_path / name, fields))
    fx, baseline = _expected_rectification()
    assert cal.fx == pytest.approx(fx, rel=1e-9) and cal.baseline == pytest.approx(baseline, rel=1e-9)
    assert cal.image_size == SIZE


def test_stereo_calib_sample_in_xml_loads_from_its_two_files(tmp_path):
    intrinsics = _write_storage(tmp_path / "intrinsics.xml", {"M1": K1, "D1": D1, "M2": K2, "D2": D2})
    extrinsics = _write_storage(tmp_path / "extrinsics.xml", {"R": R, "T": T})
    cal = load_stereo_calibration(intrinsics, extrinsics, image_size=SIZE)
    assert cal.baseline == pytest.approx(_expected_rectification()[1], rel=1e-9)


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b'<?xml version="1.0"?>\n<opencv_storage>\n<M1 type_id="opencv-matrix"><rows>3</rows>\n'
         b"</opencv_storage>\n", ["not a readable OpenCV FileStorage XML file", "closing tag"]),
        (b"\x1f\x8b\x08\x00broken", ["a damaged gzip file"]),
    ],
)  # fmt: skip
def test_broken_filestorage_files_are_refused_on_one_line(tmp_path, content, words):
    path = tmp_path / "stereo.xml"
    path.write_bytes(content)
    with pytest.raises(CalibrationError) as info:
        load_stereo_calibration(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    for word in words:
        assert word in message, message


@pytest.mark.parametrize("binning", [2, 4])
def test_camera_info_file_of_a_binned_camera_is_scaled_as_a_topic_is(tmp_path, binning):
    """A CameraInfo saved with ``ros2 topic echo`` from a binning driver keeps the full sensor's size,
    K and P with ``binning_x``, ``binning_y`` (REP-104): the file gives the binned images'
    calibration, as the bag's CameraInfo topic does, instead of a size mismatch on the images."""
    full = load_stereo_calibration(*_camera_infos(tmp_path))
    for path in _camera_infos(tmp_path):
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
    left, right = _camera_infos(tmp_path)
    left.write_text(yaml.safe_dump({**yaml.safe_load(left.read_text()), "roi": roi}))
    if not refused:
        assert load_stereo_calibration(left, right).image_size == SIZE
        return
    with pytest.raises(CalibrationError, match=r"left.yaml: roi: ") as info:
        load_stereo_calibration(left, right)
    assert "\n" not in str(info.value)


def test_camchain_extrinsics_from_the_imu_transforms(tmp_path):
    """Without cam1.T_cn_cnm1 the pair's pose follows from both cameras' IMU transforms: Kalibr's
    T_cam_imu (X_cam = T X_imu) or T_imu_cam, what OpenVINS's kalibr_imucam_chain.yaml holds
    (X_imu = T X_cam). Both were refused as 'cam1: T_cn_cnm1: required field is missing'."""
    right_from_left = np.eye(4)
    right_from_left[:3, :3], right_from_left[:3, 3] = R, T
    cam0_from_imu = np.eye(4)
    cam0_from_imu[:3, :3] = cv2.Rodrigues(np.array([0.3, -0.2, 0.1]))[0]
    cam0_from_imu[:3, 3] = [0.05, -0.02, 0.01]
    cam1_from_imu = right_from_left @ cam0_from_imu
    cams = [{"camera_model": "pinhole", "intrinsics": k[[0, 1, 0, 1], [0, 1, 2, 2]].tolist(),
             "distortion_model": "radtan", "distortion_coeffs": d[:4].tolist(), "resolution": list(SIZE)}
            for k, d in ((K1, D1), (K2, D2))]  # fmt: skip
    want = rectify_stereo(K1, np.r_[D1[:4]], K2, np.r_[D2[:4]], R, T, SIZE)
    forms = {
        "cn_cnm1": ({}, {"T_cn_cnm1": right_from_left.tolist()}),
        "cam_imu": ({"T_cam_imu": cam0_from_imu.tolist()}, {"T_cam_imu": cam1_from_imu.tolist()}),
        "imu_cam": ({"T_imu_cam": np.linalg.inv(cam0_from_imu).tolist()},
                    {"T_imu_cam": np.linalg.inv(cam1_from_imu).tolist()}),
    }  # fmt: skip
    for name, (extra0, extra1) in forms.items():
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump({"cam0": {**cams[0], **extra0}, "cam1": {**cams[1], **extra1}}))
        got = load_stereo_calibration(path)
        for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right"):
            assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-9), (name, field)
    bent = cam1_from_imu.copy()
    bent[0, 0] = 2.0
    path = tmp_path / "bent.yaml"
    path.write_text(
        yaml.safe_dump(
            {"cam0": {**cams[0], **forms["cam_imu"][0]}, "cam1": {**cams[1], "T_cam_imu": bent.tolist()}}
        )
    )
    with pytest.raises(CalibrationError, match=r"bent.yaml: cam1.T_cam_imu: not a rigid transform"):
        load_stereo_calibration(path)


def test_openvins_imucam_chain_of_euroc_equals_its_sensor_yaml_pair(tmp_path):
    """rpng/open_vins's config/euroc_mav/kalibr_imucam_chain.yaml form: %YAML:1.0, each camera's
    T_imu_cam as rows (EuRoC's T_BS: the body is the IMU), no T_cn_cnm1."""
    (tmp_path / "cam0.yaml").write_text(EUROC_CAM0)
    (tmp_path / "cam1.yaml").write_text(EUROC_CAM1)
    want = load_stereo_calibration(tmp_path / "cam0.yaml", tmp_path / "cam1.yaml")
    chain = {}
    for name, text in (("cam0", EUROC_CAM0), ("cam1", EUROC_CAM1)):
        sensor = yaml.safe_load(text.split("\n", 1)[1])
        pose = np.reshape(sensor["T_BS"]["data"], (4, 4)).tolist()
        chain[name] = {"T_imu_cam": pose, "camera_model": "pinhole", "distortion_model": "radtan",
                       "distortion_coeffs": sensor["distortion_coefficients"],
                       "intrinsics": sensor["intrinsics"], "resolution": sensor["resolution"]}  # fmt: skip
    path = tmp_path / "kalibr_imucam_chain.yaml"
    path.write_text("%YAML:1.0\n\n" + yaml.safe_dump(chain, default_flow_style=None))
    got = load_stereo_calibration(path)
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right"):
        assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-9), field


def test_two_single_camera_opencv_calibrations_are_refused_saying_why(tmp_path):
    """OpenCV's calibration sample writes one camera (camera_matrix, distortion_coefficients,
    image_width, no projection or distortion_model; ros-perception/image_common#27): a pair of
    them has no stereo extrinsics."""
    paths = []
    for name, k, d in (("left", K1, D1), ("right", K2, D2)):
        text = _opencv_storage({"camera_matrix": k, "distortion_coefficients": d.reshape(-1, 1)})
        text += 'calibration_time: "Mon Oct 27 20:27:45 2014"\n'
        text += f"image_width: {SIZE[0]}\nimage_height: {SIZE[1]}\navg_reprojection_error: 0.44\n"
        paths.append(tmp_path / f"{name}.yml")
        paths[-1].write_text(text)
    with pytest.raises(CalibrationError, match=r"left.yml: projection_matrix: .* single-camera OpenCV"):
        load_stereo_calibration(*paths)


@pytest.mark.parametrize("model", ["kannala_brandt", "Kannala-Brandt", "FISHEYE", " equidistant"])
def test_the_fisheye_model_s_other_names_and_cases_are_read(tmp_path, model):
    """ros2/common_interfaces#160: the equidistant model is Kalibr's 'equidistant', OpenCV's
    'fisheye', camodocal's 'kannala-brandt'; a driver writing another of them, or capitals, was
    refused as an unsupported model."""
    r1, r2, p1, p2, _q = cv2.fisheye.stereoRectify(
        FISH_K, FISH_D, FISH_K, FISH_D, FISH_SIZE, FISH_R, FISH_T.reshape(3, 1), cv2.CALIB_ZERO_DISPARITY
    )
    paths = []
    for name, r, p in (("left", r1, p1), ("right", r2, p2)):
        info = {"image_width": FISH_SIZE[0], "image_height": FISH_SIZE[1], "distortion_model": model}
        info |= {"camera_matrix": _matrix(FISH_K), "distortion_coefficients": _matrix(FISH_D)}
        info |= {"rectification_matrix": _matrix(r), "projection_matrix": _matrix(p)}
        paths.append(tmp_path / f"{name}.yaml")
        paths[-1].write_text(yaml.safe_dump(info))
    _check_fisheye_rectification(load_stereo_calibration(*paths))
