"""Any calibration file: Middlebury calib.txt, text encodings (UTF-8, Windows editors' BOM and
line ends), empty files, a .txt of neither text form, YAML syntax errors."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError
from tests.support.calibration_files import (
    D1,
    D2,
    K1,
    K2,
    SIZE,
    R,
    T,
    camera_infos,
    opencv_storage,
)


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


def test_files_saved_by_windows_editors_load(tmp_path):
    """A byte-order mark and CRLF line ends (Notepad's UTF-8) on a FileStorage file and a calib.txt."""
    text = opencv_storage({"M1": K1, "D1": D1, "M2": K2, "D2": D2, "R": R, "T": T})
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


def test_an_empty_file_is_called_empty(tmp_path):
    left, _right = camera_infos(tmp_path)
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


def test_a_yaml_syntax_error_is_one_line_with_its_place(tmp_path):
    (tmp_path / "bad.yaml").write_text("fx: 1\nfy: [1, 2\ncx: 3\n")
    with pytest.raises(CalibrationError) as info:
        load_stereo_calibration(tmp_path / "bad.yaml")
    assert str(info.value).endswith(
        "bad.yaml: not valid YAML: expected ',' or ']', but got ':', at line 3, column 3"
    )
    assert "\n" not in str(info.value)
