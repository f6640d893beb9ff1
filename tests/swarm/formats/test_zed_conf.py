"""Stereolabs ZED factory calibration files (``SN<serial>.conf``), read as Stereolabs' own OpenCV
sample reads them (stereolabs/zed-opencv-native: T = [-Baseline, TY, TZ] in mm, R = Rodrigues of
RX, CV, RZ of the resolution, the images' size picking the section). Before, such a file was
refused as "not valid YAML"."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError

CONF = """[LEFT_CAM_2K]
fx=1400.42
fy=1400.42
cx=1109.25
cy=624.617
k1=-0.172131
k2=0.0267744
p1=0
p2=0
k3=0

[RIGHT_CAM_2K]
fx=1399.83
fy=1399.83
cx=1103.71
cy=644.103
k1=-0.172441
k2=0.0265652
p1=0.0001
p2=0
k3=0

[LEFT_CAM_HD]
fx=700.21
fy=700.21
cx=634.625
cy=363.308
k1=-0.172131
k2=0.0267744
p1=0
p2=0
k3=0

[RIGHT_CAM_HD]
fx=699.915
fy=699.915
cx=631.855
cy=373.052
k1=-0.172441
k2=0.0265652
p1=0
p2=0
k3=0

[STEREO]
Baseline=119.975
TY=0.0201866
TZ=0.263489
CV_2K=0.0100812
CV_HD=0.0100812
RX_2K=0.00390148
RX_HD=0.00390148
RZ_2K=-0.000924063
RZ_HD=-0.000924063

[MISC]
Sensor_ID=1
"""


def _expected(size: tuple[int, int], res: str) -> tuple[float, float, float, float]:
    """fx, cx, cx_right, baseline (m) from cv2.stereoRectify as Stereolabs' sample calls it."""
    left = {"2K": (1400.42, 1400.42, 1109.25, 624.617), "HD": (700.21, 700.21, 634.625, 363.308)}[res]
    right = {"2K": (1399.83, 1399.83, 1103.71, 644.103), "HD": (699.915, 699.915, 631.855, 373.052)}[res]
    k1, k2 = (np.array([[f, 0, cx], [0, g, cy], [0, 0, 1]]) for f, g, cx, cy in (left, right))
    d1 = np.array([-0.172131, 0.0267744, 0, 0, 0])
    d2 = np.array([-0.172441, 0.0265652, 0.0001 if res == "2K" else 0, 0, 0])
    r = cv2.Rodrigues(np.array([0.00390148, 0.0100812, -0.000924063]))[0]
    t = (np.array([-119.975, 0.0201866, 0.263489]) / 1000.0).reshape(3, 1)
    _r1, _r2, p1, p2, *_ = cv2.stereoRectify(
        k1, d1, k2, d2, size, r, t, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    return p1[0, 0], p1[0, 2], p2[0, 2], -p2[0, 3] / p2[0, 0]


@pytest.mark.parametrize(("size", "res"), [((2208, 1242), "2K"), ((1280, 720), "HD")])
def test_a_zed_conf_gives_the_rig_of_the_images_resolution(tmp_path, size, res):
    path = tmp_path / "SN12345.conf"
    path.write_text(CONF)
    calib = load_stereo_calibration(path, image_size=size)
    assert (calib.fx, calib.cx, calib.cx_right, calib.baseline) == pytest.approx(
        _expected(size, res), rel=1e-9
    )
    assert calib.image_size == size and calib.maps is not None
    assert f"Baseline 119.975 mm read as 0.119975 m (resolution {res})" in calib.notes[0]


def test_a_zed_conf_without_the_images_resolution_is_refused_naming_what_it_holds(tmp_path):
    path = tmp_path / "SN12345.conf"
    path.write_text(CONF)
    with pytest.raises(
        CalibrationError, match=r"no calibration for 672x376 images \(the file holds 2K 2208x1242, HD"
    ):
        load_stereo_calibration(path, image_size=(672, 376))
    path.write_text(CONF.replace("fx=700.21", "fx=seven"))
    with pytest.raises(CalibrationError, match=r"SN12345.conf: \[LEFT_CAM_HD\] fx: not a number \('seven'\)"):
        load_stereo_calibration(path, image_size=(1280, 720))


def test_swarm_stereo_depth_reads_a_zed_conf(tmp_path: Path, capsys):
    from tests.support.stereo_scenes import cli

    left = np.random.default_rng(0).integers(0, 255, (720, 1280), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "l.png"), left)
    cv2.imwrite(str(tmp_path / "r.png"), left)
    (tmp_path / "SN1.conf").write_text(CONF)
    d = str(tmp_path)
    rc = cli(
        [f"{d}/l.png", f"{d}/r.png", "--calib", f"{d}/SN1.conf", "--out", f"{d}/o.npy", "--scale", "0.25"]
    )
    assert rc == 0, capsys.readouterr().err
    assert "resolution HD" in capsys.readouterr().out
