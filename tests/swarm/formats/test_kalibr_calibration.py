"""EuRoC/Kalibr calibrations: sensor.yaml pairs, camchains (their extrinsics from the IMU's
transforms), OpenVINS imucam chains, and what is refused naming the field."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError, rectify_stereo
from tests.support.calibration_files import D1, D2, EUROC_CAM0, EUROC_CAM1, K1, K2, SIZE, R, T
from tests.support.paths import TEST_DATA


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


def test_a_misspelt_field_of_a_sensor_yaml_is_pointed_at(tmp_path):
    euroc = TEST_DATA / "euroc_mini" / "mav0"
    text = (euroc / "cam0/sensor.yaml").read_text().replace("intrinsics:", "intrinsic:")
    (tmp_path / "sensor.yaml").write_text(text)
    with pytest.raises(
        CalibrationError, match=r"intrinsics: required field is missing \(is intrinsic a misspelling"
    ):
        load_stereo_calibration(tmp_path / "sensor.yaml", euroc / "cam1/sensor.yaml")


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
