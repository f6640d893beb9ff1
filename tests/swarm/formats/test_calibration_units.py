"""The unit of a calibration's translation: ``units=`` / ``--calib-units m|cm|mm``.

A stereo calibration is in the unit its target's squares were measured in: an OpenCV file in
centimetres with a 4.5 cm baseline (``T = [-4.5, 0, 0]``) reads as cameras 4.5 m apart, which
is below the 5 m bound that catches millimetres. The user declares the unit; without it such a
reading (1 to 5 m) carries a warning naming the file.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError
from tests.support.calibration_files import D1, D2, EUROC_CAM0, EUROC_CAM1, K1, K2, SIZE, R, _matrix

T_M = np.array([-0.045, 0.0004, 0.0002])  # a 4.5 cm rig
SCALE = {"m": 1.0, "cm": 100.0, "mm": 1000.0}  # file units per metre


def _opencv_file(tmp_path, units: str):
    data = {"K1": K1.tolist(), "D1": D1.tolist(), "K2": K2.tolist(), "D2": D2.tolist(), "R": R.tolist()}
    data |= {"T": (T_M * SCALE[units]).tolist(), "image_size": list(SIZE)}
    path = tmp_path / f"stereo_{units}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _warnings(calib) -> list[str]:
    return [note for note in calib.notes if note.startswith("warning:")]


@pytest.mark.parametrize("units", ["cm", "mm", "m"])
def test_a_declared_unit_gives_the_metres_rig(tmp_path, units):
    reference = load_stereo_calibration(_opencv_file(tmp_path, "m"))
    calib = load_stereo_calibration(_opencv_file(tmp_path, units), units=units)
    assert calib.baseline == pytest.approx(np.linalg.norm(T_M), rel=1e-6)
    for field in ("fx", "fy", "cx", "cy", "cx_right"):
        assert getattr(calib, field) == pytest.approx(getattr(reference, field), rel=1e-9)
    assert not _warnings(calib)


def test_a_centimetre_file_read_as_metres_is_warned_of_naming_the_file(tmp_path):
    path = _opencv_file(tmp_path, "cm")
    calib = load_stereo_calibration(path)  # undeclared: 4.5 m, as before, but not silently
    assert calib.baseline == pytest.approx(4.5, rel=1e-3)
    (warning,) = _warnings(calib)
    assert str(path) in warning and "--calib-units cm" in warning and "4.5 m apart" in warning
    # a common rig in metres (12 cm; KITTI's 0.54 m) is read without a warning
    assert not _warnings(load_stereo_calibration(_opencv_file(tmp_path, "m")))


def test_a_declared_unit_still_refuses_an_implausible_rig(tmp_path):
    path = tmp_path / "far.yaml"
    path.write_text(_opencv_file(tmp_path, "mm").read_text().replace("- -45.0", "- -12000.0"))
    with pytest.raises(CalibrationError, match=r"far.yaml: T: \|T\|: 12000 mm = 12 m is implausible"):
        load_stereo_calibration(path, units="mm")
    with pytest.raises(CalibrationError, match="calibration units 'inch': must be one of m, cm, mm"):
        load_stereo_calibration(path, units="inch")


def _scaled_t_bs(text: str, factor: float) -> str:
    data = yaml.safe_load(text.replace("%YAML:1.0\n", ""))
    t_bs = np.asarray(data["T_BS"]["data"], dtype=float).reshape(4, 4)
    t_bs[:3, 3] *= factor
    data["T_BS"]["data"] = t_bs.ravel().tolist()
    return yaml.safe_dump(data)


def test_every_form_reads_its_translation_in_the_declared_unit(tmp_path):
    """camera_info (P[0][3]), EuRoC sensor.yaml (T_BS), Kalibr camchain (T_cn_cnm1), a rectified
    rig (baseline), Middlebury (millimetres unless declared)."""
    r1, r2, p1, p2, *_ = cv2.stereoRectify(
        K1, D1, K2, D2, SIZE, R, T_M.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY
    )
    for name, k, d, r, p in (("left", K1, D1, r1, p1), ("right", K2, D2, r2, p2)):
        p = p.copy()
        p[0, 3] *= 100.0  # pixels x centimetres
        info = {"image_width": SIZE[0], "image_height": SIZE[1], "camera_matrix": _matrix(k),
                "distortion_model": "plumb_bob", "distortion_coefficients": _matrix(d),
                "rectification_matrix": _matrix(r), "projection_matrix": _matrix(p)}  # fmt: skip
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(info))
    info_pair = load_stereo_calibration(tmp_path / "left.yaml", tmp_path / "right.yaml", units="cm")
    assert info_pair.baseline == pytest.approx(np.linalg.norm(T_M), rel=1e-6)

    metres = load_stereo_calibration(*_euroc(tmp_path, "m", 1.0))
    millimetres = load_stereo_calibration(*_euroc(tmp_path, "mm", 1000.0), units="mm")
    assert millimetres.baseline == pytest.approx(metres.baseline, rel=1e-9)
    assert millimetres.fx == pytest.approx(metres.fx, rel=1e-9)

    right_from_left = np.eye(4)
    right_from_left[:3, :3], right_from_left[:3, 3] = R, T_M * 100.0
    camera = {"camera_model": "pinhole", "distortion_model": "radtan", "resolution": list(SIZE)}
    chain = {
        "cam0": camera | {"intrinsics": [300.0, 301.0, 161.0, 118.0], "distortion_coeffs": D1[:4].tolist()},
        "cam1": camera | {"intrinsics": [302.0, 300.0, 158.0, 121.0], "distortion_coeffs": D2[:4].tolist(),
                          "T_cn_cnm1": right_from_left.tolist()},
    }  # fmt: skip
    (tmp_path / "camchain.yaml").write_text(yaml.safe_dump(chain))
    camchain = load_stereo_calibration(tmp_path / "camchain.yaml", units="cm")
    assert camchain.baseline == pytest.approx(np.linalg.norm(T_M), rel=1e-6)

    (tmp_path / "rig.yaml").write_text("fx: 300\nfy: 300\ncx: 160\ncy: 120\nbaseline: 4.5\n")
    assert load_stereo_calibration(tmp_path / "rig.yaml", units="cm").baseline == pytest.approx(0.045)

    camera = "[300 0 160; 0 300 120; 0 0 1]"
    (tmp_path / "calib.txt").write_text(f"cam0={camera}\ncam1={camera}\nbaseline=45\n")
    assert load_stereo_calibration(tmp_path / "calib.txt").baseline == pytest.approx(0.045)
    declared = load_stereo_calibration(tmp_path / "calib.txt", units="cm")
    assert declared.baseline == pytest.approx(0.45)
    assert declared.notes == (f"{tmp_path / 'calib.txt'}: baseline 45 cm read as 0.45 m",)


def _euroc(tmp_path, units: str, factor: float):
    paths = []
    for name, text in (("cam0", EUROC_CAM0), ("cam1", EUROC_CAM1)):
        path = tmp_path / f"{name}_{units}.yaml"
        path.write_text(_scaled_t_bs(text, factor))
        paths.append(path)
    return paths


def test_stereo_depth_takes_calib_units_and_warns_without_it(tmp_path, capsys):
    from tests.support.stereo_scenes import BASELINE, CX, CY, FX, cli, relative_error, synthetic_pair

    left, right, truth = synthetic_pair(6)
    cv2.imwrite(str(tmp_path / "left.png"), left)
    cv2.imwrite(str(tmp_path / "right.png"), right)
    k = [[FX, 0, CX], [0, FX, CY], [0, 0, 1]]
    calib = tmp_path / "rig_cm.yaml"
    calib.write_text(
        yaml.safe_dump({"K1": k, "D1": [], "K2": k, "D2": [], "R": np.eye(3).tolist(),
                        "T": [-BASELINE * 100, 0, 0], "image_size": [left.shape[1], left.shape[0]]})
    )  # fmt: skip
    d = str(tmp_path)
    argv = [f"{d}/left.png", f"{d}/right.png", "--calib", str(calib), "--out", f"{d}/depth.npy"]
    assert cli([*argv, "--calib-units", "cm"]) == 0
    out = capsys.readouterr()
    assert "warning" not in out.err
    assert relative_error(np.load(tmp_path / "depth.npy"), truth)[0] < 0.03
    assert cli(argv) == 2  # undeclared, 9 cm reads as 9 m: refused, saying how to declare the unit
    err = capsys.readouterr().err
    assert f"{calib}: T: |T|: must be in metres, 9 m is implausible" in err and "--calib-units" in err
    calib.write_text(calib.read_text().replace("- -9.0", "- -4.5"))  # 4.5 cm reads as 4.5 m: warned of
    assert cli(argv) == 0
    err = capsys.readouterr().err
    assert f"warning: {calib}: the cameras come out 4.5 m apart" in err


def test_replay_bag_refuses_a_unit_with_no_calibration_file_to_apply_it_to():
    import argparse

    from swarm.cli.replay import _open_bag

    args = argparse.Namespace(
        calib_units="cm", calib_left=None, calib_right=None, left_info="/l", right_info="/r"
    )
    with pytest.raises(CalibrationError, match="--calib-units cm: declares the unit of a --calib-left file"):
        _open_bag(args)
