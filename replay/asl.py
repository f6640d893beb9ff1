"""ASL / EuRoC dataset folders: ``mav0/cam0``, ``mav0/cam1`` (``data.csv``, ``data/*.png``,
``sensor.yaml``) and the left camera's poses.

Poses, first found wins:

* ``mav0/cam0_groundtruth/data.csv``: the pose of cam0 per image, ``p_RS_R`` (m) and a
  quaternion (w, x, y, z) of the rotation **from world to camera** (the convention of the
  published EuRoC camera trajectories, as the shared excerpt's README states);
* ``mav0/state_groundtruth_estimate0/data.csv``: EuRoC's body ground truth, ``p_RS_R`` and
  ``q_RS`` (w, x, y, z) **from body to world**, combined with cam0's ``T_BS``.

Timestamps are nanoseconds; right images are matched to each left image within a tolerance,
and the pose at each left image's stamp follows ``replay.trajectory``'s rule (as in bags).
"""

from __future__ import annotations

import csv
import re
from collections.abc import Iterator
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path

import cv2
import numpy as np

from swarm.formats.calibration_formats import KalibrCamera, stereo_from_kalibr
from swarm.formats.errors import RecordingError
from swarm.formats.pixel_bits import SignificantBits, to_8_bits
from swarm.formats.stereo_calibration import StereoCalibration
from swarm.streams.frames import RecordedPair, fit_image_size
from swarm.streams.matching import Matched, match_stamps
from swarm.streams.poses import camera_from_body, quaternion_matrix
from swarm.streams.trajectory import MAX_GAP_S, Trajectory

NS = 1e-9
#: how pose rows left out are counted (``AslRecording.matched.dropped``)
UNUSABLE_POSE_ROW = "unusable pose row (NaN, inf or a zero quaternion)"


@dataclass
class CsvTable:
    """A data.csv's rows (cells stripped) and the first cell of its header line ('' if none)."""

    rows: list[list[str]]
    header: str


def _rows(path: Path, columns: int) -> CsvTable:
    """The rows of an ASL ``data.csv``: ``#`` lines are comments, the first of them the header;
    a first row whose first cell is not a number is a header written without ``#`` (pandas' and
    spreadsheets' ``timestamp,filename``)."""
    if not path.is_file():
        raise RecordingError(f"{path}: file not found")
    rows: list[list[str]] = []
    header = None
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:  # a byte-order mark: saved by Excel
            for n, row in enumerate(csv.reader(fh), 1):
                if not row or not "".join(row).strip():
                    continue
                if row[0].lstrip().startswith("#"):
                    header = row[0].strip().lstrip("#").strip() if header is None else header
                    continue
                if not rows and header is None and not _is_number(row[0]):
                    header = row[0].strip()
                    continue
                if len(row) < columns:
                    raise RecordingError(f"{path}: line {n}: expected {columns} columns, got {len(row)}")
                rows.append([c.strip() for c in row])
    except UnicodeDecodeError as exc:
        raise RecordingError(f"{path}: not UTF-8 text (byte offset {exc.start})") from None
    if not rows:
        raise RecordingError(f"{path}: no data rows")
    return CsvTable(rows, header or "")


def _is_number(text: str) -> bool:
    try:
        return Decimal(text.strip()).is_finite()
    except InvalidOperation:
        return False


#: the timestamp units a header may name (``#timestamp [ns]``, ``timestamp [s]``, ``time(us)``):
#: nanoseconds per unit, as a power of ten
_NS_EXPONENT = {"ns": 0, "us": 3, "µs": 3, "ms": 6, "s": 9, "sec": 9}


def _stamp_unit(table: CsvTable) -> str:
    """The unit of the timestamp column: the one its header names, else seconds when a stamp
    has a fraction of a unit (nanoseconds have none; EuRoC writes ``...104.0000000000``), else
    nanoseconds, the ASL format's unit."""
    named = re.search(r"[\[(]\s*(ns|us|µs|ms|s|sec)\s*[\])]", table.header.lower())
    if named:
        return named.group(1)
    fractional = any("." in r[0] and Decimal(r[0]) != Decimal(r[0]).to_integral_value() for r in table.rows
                     if _is_number(r[0]))  # fmt: skip
    return "s" if fractional else "ns"


def _stamps_ns(table: CsvTable, path: Path) -> np.ndarray:
    """The timestamp column in ns (int64), read in its unit (``_stamp_unit``). Raises
    RecordingError naming the file."""
    unit = _stamp_unit(table)
    try:
        return np.array([_nanoseconds(r[0], _NS_EXPONENT[unit]) for r in table.rows], dtype=np.int64)
    except ValueError as exc:
        raise RecordingError(f"{path}: timestamp column: {exc}") from None


def _nanoseconds(text: str, exponent: int = 0) -> int:
    """A timestamp in ns from its text in units of ``10**exponent`` ns (0: ns, 9: s),
    as written (``1403715274312143104``, ``1403715274312143104.0000``, ``1403715274.312143``),
    read exactly: a float64 keeps only 256 ns at today's epoch in ns. Raises ValueError."""
    try:
        value = Decimal(text)
    except InvalidOperation:
        raise ValueError(f"could not convert {text!r} to a timestamp") from None
    if not value.is_finite():
        raise ValueError(f"timestamp {text!r} is not a number")
    return int(value.scaleb(exponent).to_integral_value())


def _images(cam: Path) -> tuple[np.ndarray, list[Path], int]:
    """(stamps in ns, sorted; their image files; how many rows named a file that is not there)."""
    table = _rows(cam / "data.csv", 2)
    stamps, rows = _stamps_ns(table, cam / "data.csv"), table.rows
    files = [cam / "data" / r[1] for r in rows]
    present = np.array([f.is_file() for f in files], dtype=bool)
    if not present.any():
        raise RecordingError(f"{cam / 'data.csv'}: none of its {len(files)} image files is in {cam / 'data'}")
    order = [i for i in np.argsort(stamps) if present[i]]
    return stamps[order], [files[i] for i in order], int((~present).sum())


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise RecordingError(f"{path}: missing or not a readable image")
    return image


#: 16-bit images: how many of each camera's, spread over the recording, set the significant bits
BIT_SAMPLES = 30


def _significant_bits(left: list[Path], right: list[Path]) -> int | None:
    """The significant bits of 16-bit PNGs (a 10- or 12-bit camera's values sit in the low bits,
    as TUM-VI's ``_16`` and industrial cameras' folders hold them), from the brightest of up to
    ``BIT_SAMPLES`` images of each camera; None for 8-bit images (``swarm.formats.pixel_bits``)."""
    if _read_image(left[0]).dtype != np.uint16:
        return None
    bits = SignificantBits({"left": len(left), "right": len(right)}, BIT_SAMPLES)
    for name, files in (("left", left), ("right", right)):
        for index, path in enumerate(files):
            if bits.wants(name, index):
                bits.add(_read_image(path))
    return bits.bits


@dataclass
class PoseTrack:
    """Left camera poses: times (ns, sorted), positions (N, 3), world_R_optical (N, 3, 3)."""

    stamps: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    source: str
    unusable: int = 0  # rows left out: NaN, inf or a zero quaternion


def _pose_rows(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(stamps ns, positions (N, 3), quaternions (N, 4) w x y z, rows left out): a row whose
    numbers are not a pose (NaN or inf, a zero quaternion: a tracker that lost itself) is left
    out and counted, as the bag reader does."""
    table = _rows(path, 8)
    stamps, rows = _stamps_ns(table, path), table.rows
    try:
        values = np.array([[float(c) for c in r[1:8]] for r in rows])
    except ValueError as exc:
        raise RecordingError(f"{path}: {exc}") from None
    usable = np.isfinite(values).all(axis=1) & (np.linalg.norm(values[:, 3:7], axis=1) > 0)
    if not usable.any():
        raise RecordingError(
            f"{path}: none of its {len(values)} poses is usable (NaN, inf or a zero quaternion)"
        )
    stamps, values = stamps[usable], values[usable]
    order = np.argsort(stamps, kind="stable")
    return stamps[order], values[order, 0:3], values[order, 3:7], int((~usable).sum())


def load_poses(mav0: Path, left: KalibrCamera) -> PoseTrack:
    """The left camera's poses from the camera ground truth or the body ground truth + T_BS."""
    cam_file = mav0 / "cam0_groundtruth" / "data.csv"
    body_file = mav0 / "state_groundtruth_estimate0" / "data.csv"
    if cam_file.is_file():
        stamps, pos, quat, unusable = _pose_rows(cam_file)
        rot = np.stack([quaternion_matrix(*q).T for q in quat])  # world->camera: transpose
        return PoseTrack(stamps, pos, rot, str(cam_file), unusable)
    if body_file.is_file():
        stamps, pos, quat, unusable = _pose_rows(body_file)
        cams = [
            camera_from_body(p, quaternion_matrix(*q), left.body_from_camera)
            for p, q in zip(pos, quat, strict=True)
        ]
        return PoseTrack(
            stamps, np.array([c[0] for c in cams]), np.array([c[1] for c in cams]), str(body_file), unusable
        )
    raise RecordingError(
        f"{mav0}: no poses: expected cam0_groundtruth/data.csv or state_groundtruth_estimate0/data.csv"
    )


class AslRecording:
    """An ASL-format stereo recording, rectification ready; iterate ``pairs()``."""

    def __init__(self, folder: str | Path, tolerance_s: float = 0.005) -> None:
        folder = Path(folder)
        mav0 = folder / "mav0" if (folder / "mav0").is_dir() else folder
        for cam in ("cam0", "cam1"):
            if not (mav0 / cam).is_dir():
                raise RecordingError(
                    f"{mav0}: no {cam} folder (expected the ASL layout mav0/cam0, mav0/cam1)"
                )
        self.folder = mav0
        left = KalibrCamera.load(mav0 / "cam0" / "sensor.yaml")
        right = KalibrCamera.load(mav0 / "cam1" / "sensor.yaml")
        self.calibration: StereoCalibration = stereo_from_kalibr(left, right)
        self.poses = load_poses(mav0, left)
        self.left_stamps, self.left_files, left_missing = _images(mav0 / "cam0")
        right_stamps, self.right_files, right_missing = _images(mav0 / "cam1")
        for first in (self.left_files[0], self.right_files[0]):  # before anything starts
            shape = _read_image(first).shape
            self.calibration = fit_image_size(self.calibration, shape[1], shape[0], str(first))
        self.pixel_bits = _significant_bits(self.left_files, self.right_files)
        # in seconds (float64 keeps 0.3 us at today's epoch), so counts read "within 0.005"; the
        # pose at each left stamp by replay.trajectory's rule (a body ground truth at 200 Hz is
        # interpolated between its samples around the image), in seconds from the first image so
        # that the fraction of the way between two samples keeps its digits
        origin = self.left_stamps[0]
        track = Trajectory((self.poses.stamps - origin) * NS, self.poses.positions, self.poses.rotations)
        rows, self.pose_positions, self.pose_rotations, self.interpolated_poses = track.poses_at(
            (self.left_stamps - origin) * NS, tolerance_s, MAX_GAP_S
        )
        others = {"cam1 image": right_stamps * NS, "pose": self.left_stamps[rows] * NS}
        self.matched: Matched = match_stamps(self.left_stamps * NS, others, tolerance_s)
        # rows of data.csv whose image file is not there (a partial copy) are left out and counted
        for cam, missing in (("cam0", left_missing), ("cam1", right_missing)):
            if missing:
                self.matched.dropped[f"{cam} image file missing"] += missing
        if self.poses.unusable:
            self.matched.dropped[UNUSABLE_POSE_ROW] += self.poses.unusable

    def __len__(self) -> int:
        return len(self.matched.reference)

    def positions(self) -> np.ndarray:
        """(N, 3) left camera positions of the kept pairs."""
        return self.pose_positions[self.matched.others["pose"]]

    def pairs(self, start: int = 0, count: int | None = None) -> Iterator[RecordedPair]:
        stop = len(self) if count is None else min(len(self), start + count)
        for k in range(start, stop):
            i = self.matched.reference[k]
            j = self.matched.others["cam1 image"][k]
            p = self.matched.others["pose"][k]
            left, right = _read_image(self.left_files[i]), _read_image(self.right_files[j])
            if self.pixel_bits is not None:
                left, right = to_8_bits(left, self.pixel_bits), to_8_bits(right, self.pixel_bits)
            yield RecordedPair(
                float(self.left_stamps[i]) * NS, left, right, self.pose_positions[p], self.pose_rotations[p]
            )
