"""A Middlebury ``calib.txt`` describes rectified views; one written from two raw cameras' own
matrices (decadenza/SimpleStereo#26, gengshan-y/high-res-stereo#5) was read as a rectified rig
with cam0's focal length, silently."""

import pytest

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError


def test_a_calib_txt_of_two_raw_cameras_is_refused_naming_what_differs(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(
        "cam0=[579.24 0 502.40; 0 579.51 510.58; 0 0 1]\ncam1=[581.02 0 498.13; 0 581.30 507.91; 0 0 1]\n"
        "doffs=-4.27\nbaseline=79.69\nwidth=1016\nheight=1016\n"
    )
    words = r"calib.txt: cam0, cam1: fx 579.24 vs 581.02, fy .*, cy 510.58 vs 507.91; a calib.txt describes"
    with pytest.raises(CalibrationError, match=words):
        load_stereo_calibration(path)


def test_a_rectified_calib_txt_still_reads(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(
        "cam0=[1038.018 0 322.037; 0 1038.018 243.393; 0 0 1]\n"
        "cam1=[1038.018 0 375.308; 0 1038.018 243.393; 0 0 1]\ndoffs=53.271\nbaseline=176.252\n"
    )
    calib = load_stereo_calibration(path)
    assert (calib.fx, calib.disparity_offset) == (1038.018, pytest.approx(53.271))
