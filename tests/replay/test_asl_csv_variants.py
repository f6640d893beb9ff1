"""ASL/EuRoC ``data.csv`` files as other tools write them (public reports: UZ-SLAMLab/ORB_SLAM3#73
and MichaelGrupp/evo#12, timestamps in seconds beside nanoseconds; MichaelGrupp/evo#159 and #627,
rows ending in a comma; a header without ``#``, as pandas writes it). Each folder must read as
the bundled one does: the same pairs, stamps (to the microsecond) and positions."""

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from replay.asl import AslRecording, RecordingError
from tests.support.paths import TEST_DATA

MINI = TEST_DATA / "euroc_mini"
CSVS = ("cam0/data.csv", "cam1/data.csv", "cam0_groundtruth/data.csv")


def _copy(tmp_path: Path, rewrite: Callable[[str, list[str]], list[str]]) -> Path:
    """euroc_mini with each data.csv's lines (header first) rewritten by ``rewrite(name, lines)``."""
    folder = tmp_path / "rec"
    shutil.copytree(MINI, folder)
    for name in CSVS:
        path = folder / "mav0" / name
        lines = path.read_text().splitlines()
        path.write_text("\n".join(rewrite(name, lines)) + "\n")
    return folder


def _seconds(line: str) -> str:
    stamp, rest = line.split(",", 1)
    ns = int(stamp.split(".")[0])
    return f"{ns // 10**9}.{ns % 10**9 // 1000:06d},{rest}"


def _assert_reads_as_the_bundled_one(folder: Path) -> None:
    want, got = AslRecording(MINI, 0.01), AslRecording(folder, 0.01)
    assert len(got) == len(want) == 4
    np.testing.assert_allclose(got.left_stamps, want.left_stamps, atol=1000)  # ns: microseconds kept
    np.testing.assert_allclose(got.positions(), want.positions(), atol=1e-9)


@pytest.mark.parametrize(
    "header",
    ["#timestamp [s],filename", "#timestamp,filename", "timestamp,filename", "time (s),filename", None],
)
def test_timestamps_in_seconds_are_read_as_seconds(tmp_path, header):
    def rewrite(name: str, lines: list[str]) -> list[str]:
        rows = [_seconds(line) for line in lines[1:]]
        if header is None:
            return rows
        return [header.split(",")[0] + "," + lines[0].split(",", 1)[1]] + rows  # the file's columns

    _assert_reads_as_the_bundled_one(_copy(tmp_path, rewrite))


def test_poses_in_seconds_beside_images_in_nanoseconds(tmp_path):
    """ORB_SLAM3#73's mix: before, no image found a pose ("no pair left")."""

    def rewrite(name: str, lines: list[str]) -> list[str]:
        if not name.startswith("cam0_"):
            return lines
        return ["#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z"] + [_seconds(line) for line in lines[1:]]

    _assert_reads_as_the_bundled_one(_copy(tmp_path, rewrite))


def test_header_without_hash_trailing_commas_and_crlf(tmp_path):
    def rewrite(name: str, lines: list[str]) -> list[str]:
        return [lines[0].lstrip("#")] + [f"{line},\r" for line in lines[1:]]

    _assert_reads_as_the_bundled_one(_copy(tmp_path, rewrite))


def test_a_header_naming_nanoseconds_wins_and_bad_stamps_are_named(tmp_path):
    folder = _copy(tmp_path, lambda name, lines: lines)
    _assert_reads_as_the_bundled_one(folder)
    path = folder / "mav0" / "cam0" / "data.csv"
    path.write_text("#timestamp [ns],filename\n1403715274312143104,a.png\nsoon,b.png\n")
    with pytest.raises(RecordingError, match=r"cam0/data.csv: timestamp column: could not convert 'soon'"):
        AslRecording(folder, 0.01)


@pytest.mark.parametrize("bits", [10, 12])
def test_16_bit_images_of_a_10_or_12_bit_camera_keep_their_bits(tmp_path, bits):
    """TUM-VI's ``_16`` folders and industrial cameras save 16-bit PNGs whose values sit in the low
    bits; before, their top 8 bits were kept (a 10-bit image became 0..3, near black), silently."""
    import cv2

    folder = _copy(tmp_path, lambda name, lines: lines)
    for png in (folder / "mav0").glob("cam*/data/*.png"):
        image = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png), image.astype(np.uint16) << (bits - 8))
    got, want = AslRecording(folder, 0.01), AslRecording(MINI, 0.01)
    assert got.pixel_bits == bits and want.pixel_bits is None
    for a, b in zip(got.pairs(), want.pairs(), strict=True):
        assert (
            a.left.dtype == np.uint8 and np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
        )
