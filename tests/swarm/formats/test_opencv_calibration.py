"""OpenCV calibration files: stereoRectify's extra outputs, what calibration tools add beside
the calibration, the stereo_calib sample's two files, every FileStorage encoding (YAML, XML,
gzip), and what is refused on one line."""

from __future__ import annotations

from pathlib import Path

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
    opencv_storage,
)


def test_an_opencv_matrix_whose_rows_and_cols_miss_its_data_is_refused_naming_both(tmp_path):
    text = opencv_storage({"M1": K1, "D1": D1, "M2": K2, "D2": D2, "R": R, "T": T})
    text = text.replace("rows: 3\n   cols: 3", "rows: 3\n   cols: 2", 1) + f"image_size: {list(SIZE)}\n"
    (tmp_path / "stereo.yml").write_text(text)
    with pytest.raises(
        CalibrationError, match=r"stereo.yml: M1: rows x cols is 3 x 2 but data holds 9 numbers"
    ):
        load_stereo_calibration(tmp_path / "stereo.yml")


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


def test_opencv_stereo_calib_sample_two_files(tmp_path):
    """OpenCV's stereo_calib sample writes intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml
    (R T R1 R2 P1 P2 Q), and no image size: the pair loads, the size taken from the images."""
    r1, r2, p1, p2, q, *_ = cv2.stereoRectify(K1, D1, K2, D2, SIZE, R, T.reshape(3, 1), alpha=1)
    intrinsics, extrinsics = tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"
    intrinsics.write_text(opencv_storage({"M1": K1, "D1": D1, "M2": K2, "D2": D2}))
    extrinsics.write_text(
        opencv_storage({"R": R, "T": T.reshape(3, 1), "R1": r1, "R2": r2, "P1": p1, "P2": p2, "Q": q})
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
        opencv_storage({"M1": k, "D1": np.zeros(5), "M2": k, "D2": np.zeros(5)})
    )
    (tmp_path / "extrinsics.yml").write_text(
        opencv_storage({"R": np.eye(3), "T": np.array([-BASELINE, 0, 0])})
    )
    d = str(tmp_path)
    rc = cli([f"{d}/left.png", f"{d}/right.png", "--calib", f"{d}/intrinsics.yml",
              "--calib-right", f"{d}/extrinsics.yml", "--out", f"{d}/depth.npy"])  # fmt: skip
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert f"taken from the images ({left.shape[1]}x{left.shape[0]})" in out.out
    assert relative_error(np.load(tmp_path / "depth.npy"), truth)[0] < 0.03


def test_opencv_file_with_image_width_and_height(tmp_path):
    """``image_width`` / ``image_height`` (the names OpenCV's calibration sample writes, and many
    hand-written FileStorage stereo files use) stand for ``image_size``."""
    text = opencv_storage({"K1": K1, "D1": D1, "K2": K2, "D2": D2, "R": R, "T": T.reshape(3, 1)})
    path = tmp_path / "stereo_calib.yml"
    path.write_text(text.replace("---\n", f"---\nimage_width: {SIZE[0]}\nimage_height: {SIZE[1]}\n"))
    got = load_stereo_calibration(path)
    want = rectify_stereo(K1, D1, K2, D2, R, T, SIZE)
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right", "image_size"):
        assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-9)
    path.write_text(text.replace("---\n", f"---\nimage_width: {SIZE[0]}\n"))
    with pytest.raises(CalibrationError, match="stereo_calib.yml: image_width, image_height: give both"):
        load_stereo_calibration(path)


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


def test_two_single_camera_opencv_calibrations_are_refused_saying_why(tmp_path):
    """OpenCV's calibration sample writes one camera (camera_matrix, distortion_coefficients,
    image_width, no projection or distortion_model; ros-perception/image_common#27): a pair of
    them has no stereo extrinsics."""
    paths = []
    for name, k, d in (("left", K1, D1), ("right", K2, D2)):
        text = opencv_storage({"camera_matrix": k, "distortion_coefficients": d.reshape(-1, 1)})
        text += 'calibration_time: "Mon Oct 27 20:27:45 2014"\n'
        text += f"image_width: {SIZE[0]}\nimage_height: {SIZE[1]}\navg_reprojection_error: 0.44\n"
        paths.append(tmp_path / f"{name}.yml")
        paths[-1].write_text(text)
    with pytest.raises(CalibrationError, match=r"left.yml: projection_matrix: .* single-camera OpenCV"):
        load_stereo_calibration(*paths)
