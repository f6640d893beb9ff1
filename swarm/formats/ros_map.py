"""ROS map_server maps: a ``map.yaml`` and its image, classified into occupied / free / unknown cells.

``map.yaml`` keys (as map_server reads them)::

    image: site.pgm          # relative to the map.yaml's folder; '~' is expanded (map_server does not)
    resolution: 0.05         # metres per cell
    origin: [-10.0, -5.0, 0.0]   # x, y (m) of the lower-left cell, yaw (rad)
    negate: 0                # 1 (or true): dark is free
    occupied_thresh: 0.65
    free_thresh: 0.196
    mode: trinary            # trinary | scale | raw (any case, as Nav2 reads it)

A pixel's shade s in [0, 1] is the mean of its colour channels, scaled as its format
defines (:mod:`swarm.formats.map_image`). Its occupancy is p = 1 - s (p = s with ``negate``).
``trinary``: p > occupied_thresh is occupied, else p < free_thresh is free, else unknown; an
alpha channel is averaged in with the colour channels (as map_server does, so transparent
pixels read darker). ``scale``: a pixel that is not fully opaque is unknown, the rest as
trinary. ``raw``: the value round(255 s) is the occupancy in percent (0..100; above 100
unknown), occupied above occupied_thresh x 100, free below free_thresh x 100.

map_saver's trinary images hold three shades: 0 occupied, 205 unknown (p = 0.196), 254 free.
Nav2's saver wrote its ``free_thresh_default`` 0.25 beside them, which reads every unknown
cell as free (SteveMacenski/slam_toolbox#587; navigation2#5278 made the saver write 0.196).
A ``trinary`` image (not ``negate``, no alpha) whose pixels are those three shades, 205 among
them, with at most 1% of other shades (touch-ups), is read with free_thresh 0.196 when the
file's would read 205 as free; the file's occupied_thresh is kept. Other images keep the
file's thresholds. One warning line names the file and ``free_thresh`` when the file's value
reads the grey 205 as free (in other images: when 205 covers 1% of the image or more).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, ValidationError, field_validator

from swarm.formats.errors import FloorPlanError, user_path
from swarm.formats.map_image import read_map_image
from swarm.formats.validation_errors import describe_validation_error
from swarm.formats.yaml_file import read_yaml

log = logging.getLogger(__name__)

#: map_saver's trinary shades (of 255): occupied, unknown, free.
SAVER_SHADES = (0, 205, 254)
#: The free_thresh map_saver writes for them (navigation2#5278): grey 205 (p = 0.19608) lies above it.
SAVER_FREE_THRESH = 0.196
#: The share of other shades a map_saver image may hold (hand touch-ups) and still be one.
SAVER_OTHER_SHADES = 0.01
_UNKNOWN_P = 1.0 - 205 / 255
_warned: set[tuple[Path, float]] = set()


@dataclass(frozen=True)
class RosMap:
    """A ROS map_server map classified into occupied / free / unknown cells.

    Arrays are indexed ``[row, col]`` with row 0 the lowest y (the image flipped), so cell
    (r, c) spans ``origin + R(yaw) @ ([c, r] .. [c+1, r+1]) * resolution``.
    """

    occupied: np.ndarray
    free: np.ndarray
    resolution: float
    origin: tuple[float, float, float]
    source: Path

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupied.shape

    def to_world(self, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """World (x, y) of map coordinates given in cells (fractional allowed), shape (..., 2)."""
        ox, oy, yaw = self.origin
        u = np.asarray(cols, dtype=np.float64) * self.resolution
        v = np.asarray(rows, dtype=np.float64) * self.resolution
        c, s = np.cos(yaw), np.sin(yaw)
        return np.stack([ox + c * u - s * v, oy + s * u + c * v], axis=-1)

    def clearance(self) -> np.ndarray:
        """Clearance (m) of every cell, shape (rows, cols) like ``free``; 0 where not free.

        The distance from a free cell's centre to the nearest cell that is not free (occupied,
        unknown, or beyond the image's edge, which counts as unknown), measured to that cell's
        near edge: the centre-to-centre distance less half a cell. That is exact along rows
        and columns (a robot between straight walls) and at most 0.21 cell more than the exact
        distance to a cell that lies diagonally. Every test of where a robot's body fits on a
        ROS map (starts of ``--map`` missions, the hint of a refused start, confined robots)
        uses this one field.
        """
        from scipy import ndimage

        centre = ndimage.distance_transform_edt(np.pad(self.free, 1))[1:-1, 1:-1]
        return np.where(self.free, (centre - 0.5) * self.resolution, 0.0)

    def free_ray_lengths(self, xy: np.ndarray, yaws: np.ndarray, reach: float) -> np.ndarray:
        """How far (m) a ray from the point ``xy`` (2,) runs through free cells along each of
        ``yaws`` (A,) (radians from +x, counter-clockwise), up to ``reach`` metres; shape (A,).

        The ray is sampled every half cell and stops before its first sample in a cell that
        is not free (occupied, unknown or beyond the image's edge); 0 when ``xy`` itself is not
        on a free cell.
        """
        yaws = np.asarray(yaws, dtype=np.float64).reshape(-1)
        step = 0.5 * self.resolution
        s = np.arange(0, int(np.ceil(reach / step)) + 1) * step  # (S,), from the point itself
        s = np.minimum(s, reach)
        points = (
            np.asarray(xy, dtype=np.float64)[:2]
            + s[None, :, None] * np.stack([np.cos(yaws), np.sin(yaws)], axis=-1)[:, None, :]
        )  # (A, S, 2)
        cells = self.to_cell(points)
        rows, cols = cells[..., 0], cells[..., 1]
        inside = (rows >= 0) & (rows < self.shape[0]) & (cols >= 0) & (cols < self.shape[1])
        free = np.zeros(inside.shape, dtype=bool)
        free[inside] = self.free[rows[inside], cols[inside]]
        blocked = ~free
        first = np.where(blocked.any(axis=1), np.argmax(blocked, axis=1), len(s))  # (A,)
        return np.where(first > 0, s[np.maximum(first - 1, 0)], 0.0)

    def to_cell(self, xy: np.ndarray) -> np.ndarray:
        """Cell (row, col) indices (..., 2) of world points (may be outside the map)."""
        ox, oy, yaw = self.origin
        xy = np.asarray(xy, dtype=np.float64)
        dx, dy = xy[..., 0] - ox, xy[..., 1] - oy
        c, s = np.cos(yaw), np.sin(yaw)
        u, v = c * dx + s * dy, -s * dx + c * dy
        return np.floor(np.stack([v, u], axis=-1) / self.resolution).astype(np.int64)


class RosMapSpec(BaseModel):
    """The keys of a ``map.yaml``; unknown keys are ignored, as map_server ignores them."""

    model_config = ConfigDict(extra="ignore")

    image: str = Field(min_length=1)
    resolution: FiniteFloat = Field(gt=0)
    origin: tuple[FiniteFloat, FiniteFloat, FiniteFloat]
    negate: bool = False
    occupied_thresh: FiniteFloat = Field(default=0.65, ge=0, le=1)
    free_thresh: FiniteFloat = Field(default=0.196, ge=0, le=1)
    mode: Literal["trinary", "scale", "raw"] = "trinary"

    @field_validator("origin", mode="before")
    @classmethod
    def _three_numbers(cls, value: object) -> object:
        if isinstance(value, list | tuple) and len(value) == 3:
            return value
        raise ValueError(f"must be [x, y, yaw], 3 numbers (got {value!r})")

    @field_validator("mode", mode="before")
    @classmethod
    def _any_case(cls, value: object) -> object:
        return value.lower() if isinstance(value, str) else value  # Nav2's map_mode_from_string does so

    @field_validator("negate", mode="before")
    @classmethod
    def _zero_or_one(cls, value: object) -> object:
        if isinstance(value, bool) or value in (0, 1):
            return bool(value)
        raise ValueError(f"must be 0, 1, true or false (got {value!r})")


def _saver_free_thresh(path: Path, spec: RosMapSpec, shade: np.ndarray) -> float:
    """The free_thresh to read a trinary image (shades in [0, 1], any shape) with: 0.196 for a
    map_saver image whose file's thresholds read its unknown grey 205 as free, else the file's.
    Logs one warning line (once per file and process) when the file's value reads 205 as free."""
    reads_free = spec.free_thresh > _UNKNOWN_P and spec.occupied_thresh >= _UNKNOWN_P
    if not reads_free:
        return spec.free_thresh
    levels = np.round(shade * 255)
    grey = int(np.count_nonzero(levels == 205))
    if grey == 0:
        return spec.free_thresh
    other = int(np.count_nonzero(~np.isin(levels, SAVER_SHADES)))
    saver = other <= SAVER_OTHER_SHADES * levels.size
    if saver:
        others = f" (and {other:,} pixels of other shades)" if other else ""
        note = (
            f"read as unknown with free_thresh {SAVER_FREE_THRESH}, as map_saver writes since "
            f"navigation2#5278: the image holds map_saver's shades 0, 205, 254{others}; "
            f"free_thresh: {SAVER_FREE_THRESH} in the file makes Nav2 read it so too"
        )
    elif grey >= SAVER_OTHER_SHADES * levels.size:
        note = (
            f"kept free: the image also holds {other:,} pixels of other shades, so it is not "
            f"taken for map_saver's; write free_thresh: {SAVER_FREE_THRESH} if 205 means unknown"
        )
    else:
        return spec.free_thresh
    key = (path.resolve(), path.stat().st_mtime)
    if key not in _warned:
        _warned.add(key)
        log.warning(
            "warning: %s: free_thresh: %g reads the grey 205 (map_saver's unknown, p = 0.196) as free; "
            "its %s cells are %s",
            path,
            spec.free_thresh,
            f"{grey:,}",
            note,
        )
    return SAVER_FREE_THRESH if saver else spec.free_thresh


def is_ros_map(data: object) -> bool:
    """True when a parsed YAML document looks like a ROS map_server map description."""
    return isinstance(data, dict) and "image" in data and "resolution" in data


def load_ros_map(path: str | Path) -> RosMap:
    """Read a ``map.yaml`` and its image and classify the cells as map_server does (module doc).

    Raises FloorPlanError naming the file and the key (``origin[2]``, ``image``, ...).
    """
    path = Path(path)
    data = read_yaml(path, FloorPlanError)
    if not isinstance(data, dict):
        raise FloorPlanError(f"{path}: (top level): must be a mapping of map.yaml keys")
    try:
        spec = RosMapSpec.model_validate(data)
    except ValidationError as e:
        raise FloorPlanError(describe_validation_error(e, path, RosMapSpec)) from e
    image_path = user_path(spec.image, path.parent)
    if not image_path.exists():
        where = "" if Path(spec.image).expanduser().is_absolute() else " (taken from the map.yaml's folder)"
        beside = path.parent / Path(spec.image).name
        if beside.is_file():  # a map saved with a full path on another machine, copied with its image
            where += f"; {beside.name} lies beside the map.yaml: write 'image: {beside.name}'"
        raise FloorPlanError(f"{path}: image: file not found: {image_path}{where}")
    try:
        image = read_map_image(image_path)
    except FloorPlanError as e:
        raise FloorPlanError(f"{path}: image: {e}") from e
    if image.alpha is not None and spec.mode == "trinary":
        shade = (3 * image.shade + image.alpha) / 4
    else:
        shade = image.shade
    if spec.mode == "raw":
        percent = np.round(shade * 255)
        known = percent <= 100
        occupied = known & (percent > spec.occupied_thresh * 100)
        free = known & ~occupied & (percent < spec.free_thresh * 100)
    else:
        free_thresh = spec.free_thresh
        if spec.mode == "trinary" and image.alpha is None and not spec.negate:
            free_thresh = _saver_free_thresh(path, spec, shade)
        p = shade if spec.negate else 1.0 - shade
        occupied = p > spec.occupied_thresh
        free = ~occupied & (p < free_thresh)
        if spec.mode == "scale" and image.alpha is not None:
            opaque = image.alpha >= 1.0
            occupied &= opaque
            free &= opaque
    return RosMap(
        occupied=np.ascontiguousarray(occupied[::-1]),
        free=np.ascontiguousarray(free[::-1]),
        resolution=spec.resolution,
        origin=tuple(float(v) for v in spec.origin),
        source=path,
    )
