"""Occupancy-map images as their formats define them: Netpbm (PGM/PPM/PBM/PAM) and what OpenCV reads.

A map image becomes two arrays in [0, 1], indexed ``[row, col]`` with row 0 the top of the
image: ``shade``, the mean of the colour channels (0 black, 1 white; a grey image is its
one channel), and ``alpha`` (1 opaque) when the image has an alpha channel.

Samples are scaled by what the format says full intensity is: Netpbm's ``maxval`` (any of
1..65535, so ``maxval 100`` makes 100 white), 255 for 8-bit and 65535 for 16-bit images.
Netpbm files are read here (OpenCV scales some Netpbm variants and not others); header
comments (``#`` to the end of a line) are skipped; a file holding several images gives the
first. PNG, BMP, TIFF, JPEG and the rest go through OpenCV. Errors raise
:class:`~swarm.formats.errors.FloorPlanError` naming the image and the cause.

Source: the Netpbm format pages (pbm, pgm, ppm, pam); map_server's loaders average the
colour channels of a pixel the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from swarm.formats.errors import FloorPlanError

#: More pixels than this in one map image is taken for a corrupt header.
MAX_PIXELS = 400_000_000

_NETPBM = {b"P1", b"P2", b"P3", b"P4", b"P5", b"P6", b"P7"}
_WHITESPACE = b" \t\n\r\v\f"


@dataclass(frozen=True)
class MapImage:
    """``shade`` (rows, cols) mean colour in [0, 1]; ``alpha`` (rows, cols) in [0, 1] or None."""

    shade: np.ndarray
    alpha: np.ndarray | None


def read_map_image(path: str | Path) -> MapImage:
    """Read a map image; errors read ``<image>: <cause>`` (FloorPlanError)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FloorPlanError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise FloorPlanError(f"{path}: is a folder, not an image") from None
    except OSError as exc:
        raise FloorPlanError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not data:
        raise FloorPlanError(f"{path}: the file is empty")
    if data[:2] in _NETPBM:
        return _read_netpbm(data, path)
    return _read_with_opencv(data, path)


# -- Netpbm --------------------------------------------------------------------------------


class _Header:
    """Tokens of a Netpbm header, skipping whitespace and ``#`` comments."""

    def __init__(self, data: bytes, path: Path) -> None:
        self.data, self.path, self.pos = data, path, 2

    def fail(self, what: str) -> FloorPlanError:
        return FloorPlanError(f"{self.path}: {self.data[:2].decode()} header: {what}")

    def token(self, name: str) -> bytes:
        data, n = self.data, len(self.data)
        while self.pos < n:
            if data[self.pos] in _WHITESPACE:
                self.pos += 1
            elif data[self.pos] == ord("#"):
                end = data.find(b"\n", self.pos)
                self.pos = n if end < 0 else end + 1
            else:
                break
        start = self.pos
        while self.pos < n and data[self.pos] not in _WHITESPACE and data[self.pos] != ord("#"):
            self.pos += 1
        if start == self.pos:
            raise self.fail(f"the file ends before the {name}")
        return data[start : self.pos]

    def number(self, name: str, lo: int, hi: int) -> int:
        text = self.token(name)
        if not text.isdigit():
            raise self.fail(f"{name} must be a whole number, got {text[:20].decode(errors='replace')!r}")
        value = int(text)
        if not lo <= value <= hi:
            raise self.fail(f"{name} must be in [{lo}, {hi}], got {value}")
        return value

    def raster_start(self, size: int) -> int:
        """Offset of a binary raster of ``size`` bytes: one whitespace byte after the last token.

        A header whose lines end in CR LF (written in text mode on Windows, or by an editor)
        has its raster after the LF when the file holds exactly ``size`` bytes from there.
        When every LF byte of the raster became CR LF too (the whole file written in text
        mode), the samples cannot be told apart and the file is refused.
        """
        start = min(self.pos + 1, len(self.data))
        if self.data[self.pos : self.pos + 2] != b"\r\n":
            return start
        rest = len(self.data) - (start + 1)
        if rest == size:
            return start + 1
        crlf = self.data.count(b"\r\n", start + 1)
        if rest > size and rest - crlf == size:
            raise self.fail(
                "the file was written in text mode: its line ends and every byte 10 of the raster "
                "became CR LF, which shifts the samples; write it again in binary mode"
            )
        return start


def _read_netpbm(data: bytes, path: Path) -> MapImage:
    magic = data[:2]
    head = _Header(data, path)
    if magic == b"P7":
        return _read_pam(head)
    width = head.number("width", 1, MAX_PIXELS)
    height = head.number("height", 1, MAX_PIXELS)
    if width * height > MAX_PIXELS:
        raise head.fail(f"{width} x {height} pixels is more than a map image holds ({MAX_PIXELS:,})")
    bitmap = magic in (b"P1", b"P4")
    maxval = 1 if bitmap else head.number("maxval", 1, 65535)
    channels = 3 if magic in (b"P3", b"P6") else 1
    count = width * height * channels
    if magic in (b"P1", b"P2", b"P3"):
        samples = _ascii_samples(data[head.pos :], count, maxval, path, magic, bitmap)
    elif magic == b"P4":
        row_bytes = (width + 7) // 8
        raster = _take(
            data,
            head.raster_start(row_bytes * height),
            row_bytes * height,
            path,
            magic,
            f"{height} rows of {row_bytes} bytes",
        )
        bits = np.unpackbits(np.frombuffer(raster, np.uint8).reshape(height, row_bytes), axis=1)
        samples = bits[:, :width].reshape(-1)
    else:
        size = 1 if maxval < 256 else 2
        raster = _take(
            data,
            head.raster_start(count * size),
            count * size,
            path,
            magic,
            f"{count:,} samples of {size} byte(s)",
        )
        samples = np.frombuffer(raster, np.uint8 if size == 1 else ">u2")
        _check_maxval(samples, maxval, path, magic)
    value = samples.astype(np.float64).reshape(height, width, channels) / maxval
    if bitmap:
        value = 1.0 - value  # PBM: 1 is black
    return MapImage(shade=value.mean(axis=2), alpha=None)


def _read_pam(head: _Header) -> MapImage:
    fields: dict[bytes, bytes] = {}
    while True:
        key = head.token("ENDHDR")
        if key == b"ENDHDR":
            break
        if key == b"TUPLTYPE":  # the rest of the line; only the first word matters here
            fields[key] = head.token("TUPLTYPE")
            continue
        fields[key] = head.token(key.decode(errors="replace"))
    for key in (b"WIDTH", b"HEIGHT", b"DEPTH", b"MAXVAL"):
        if key not in fields:
            raise head.fail(f"{key.decode()} is missing")
    try:
        width, height, depth, maxval = (int(fields[k]) for k in (b"WIDTH", b"HEIGHT", b"DEPTH", b"MAXVAL"))
    except ValueError:
        raise head.fail("WIDTH, HEIGHT, DEPTH and MAXVAL must be whole numbers") from None
    if not (width >= 1 and height >= 1 and 1 <= depth <= 4 and 1 <= maxval <= 65535):
        raise head.fail(f"WIDTH {width}, HEIGHT {height}, DEPTH {depth} (1-4), MAXVAL {maxval} (1-65535)")
    if width * height > MAX_PIXELS:
        raise head.fail(f"{width} x {height} pixels is more than a map image holds ({MAX_PIXELS:,})")
    size = 1 if maxval < 256 else 2
    count = width * height * depth
    raster = _take(
        head.data, head.raster_start(count * size), count * size, head.path, b"P7", f"{count:,} samples"
    )
    samples = np.frombuffer(raster, np.uint8 if size == 1 else ">u2")
    _check_maxval(samples, maxval, head.path, b"P7")
    value = samples.astype(np.float64).reshape(height, width, depth) / maxval
    tupltype = fields.get(b"TUPLTYPE", b"")
    has_alpha = tupltype.endswith(b"_ALPHA") or (not tupltype and depth in (2, 4))
    colour = value[..., :-1] if has_alpha and depth > 1 else value
    return MapImage(shade=colour.mean(axis=2), alpha=value[..., -1] if has_alpha and depth > 1 else None)


def _take(data: bytes, start: int, size: int, path: Path, magic: bytes, what: str) -> bytes:
    got = len(data) - start
    if got < size:
        raise FloorPlanError(
            f"{path}: {magic.decode()} raster: the header announces {what} ({size:,} bytes), the file "
            f"holds {max(got, 0):,}; the file is truncated"
        )
    return data[start : start + size]


def _check_maxval(samples: np.ndarray, maxval: int, path: Path, magic: bytes) -> None:
    if samples.size and int(samples.min()) < 0:
        raise FloorPlanError(f"{path}: {magic.decode()} raster: a sample is {int(samples.min())}, below 0")
    if samples.size and int(samples.max()) > maxval:
        raise FloorPlanError(
            f"{path}: {magic.decode()} raster: a sample is {int(samples.max())}, above maxval {maxval}"
        )


def _ascii_samples(
    text: bytes, count: int, maxval: int, path: Path, magic: bytes, bitmap: bool
) -> np.ndarray:
    lines = [line.split(b"#", 1)[0] for line in text.splitlines()]
    body = b" ".join(lines)
    if bitmap:  # P1 digits need no separating space
        words = [bytes([c]) for c in body if c in b"01"]
        stray = [w for w in body.split() if w.strip(b"01")]
        if stray:
            raise FloorPlanError(f"{path}: P1 raster: only 0 and 1 may appear, got {stray[0][:20]!r}")
    else:
        words = body.split()
    if len(words) < count:
        raise FloorPlanError(
            f"{path}: {magic.decode()} raster: the header announces {count:,} samples, the file holds "
            f"{len(words):,}; the file is truncated"
        )
    try:
        samples = np.array(words[:count]).astype(np.int64)
    except ValueError:
        bad = next(w for w in words[:count] if not w.isdigit())
        raise FloorPlanError(
            f"{path}: {magic.decode()} raster: samples must be whole numbers, got {bad[:20]!r}"
        ) from None
    _check_maxval(samples, maxval, path, magic)
    return samples


# -- everything else, through OpenCV ---------------------------------------------------------


def _read_with_opencv(data: bytes, path: Path) -> MapImage:
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None:
        raise FloorPlanError(
            f"{path}: not a readable image (unknown format or a damaged file; "
            "PGM, PNG, BMP and TIFF are supported)"
        )
    if image.dtype == np.uint8:
        full = 255.0
    elif image.dtype == np.uint16:
        full = 65535.0
    else:
        raise FloorPlanError(f"{path}: {image.dtype} pixels; map images hold 8- or 16-bit samples")
    value = image.astype(np.float64) / full
    if value.ndim == 2:
        return MapImage(shade=value, alpha=None)
    if value.shape[2] in (2, 4):
        return MapImage(shade=value[..., :-1].mean(axis=2), alpha=value[..., -1])
    return MapImage(shade=value.mean(axis=2), alpha=None)
