"""``swarm stereo depth`` of 16-bit PNGs from a 10- or 12-bit camera (values in the low bits, as
aiff22/PyNET-PyTorch#6 and dpschreiner/icb#27 describe them). Before, the top 8 bits were kept:
a 12-bit pair became values 0..15 and its depth was mostly wrong or missing, silently."""

import cv2
import numpy as np
import pytest

from tests.support.stereo_scenes import BASELINE, CX, CY, FX, cli, relative_error, synthetic_pair, write_yaml


@pytest.mark.parametrize("bits", [10, 12, 16])
def test_a_16_bit_pair_keeps_its_significant_bits(tmp_path, capsys, bits):
    left, right, truth = synthetic_pair(6)
    for name, image in (("left", left), ("right", right)):  # 8-bit values into the top of `bits`
        cv2.imwrite(str(tmp_path / f"{name}.png"), image.astype(np.uint16) << (bits - 8))
    write_yaml(tmp_path / "calib.yaml", f"fx: {FX}\nfy: {FX}\ncx: {CX}\ncy: {CY}\nbaseline: {BASELINE}\n")
    d = str(tmp_path)
    argv = [f"{d}/left.png", f"{d}/right.png", "--calib", f"{d}/calib.yaml", "--out", f"{d}/depth.npy"]
    assert cli(argv) == 0
    assert f"16-bit images: {bits} significant bits" in capsys.readouterr().out
    median_error, valid = relative_error(np.load(tmp_path / "depth.npy"), truth)
    assert median_error < 0.03 and valid > 0.6, (median_error, valid)
