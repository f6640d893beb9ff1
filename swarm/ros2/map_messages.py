"""The team map as ROS 2 messages: ``nav_msgs/OccupancyGrid``, ``map_msgs/OccupancyGridUpdate``
and ``sensor_msgs/PointCloud2``, built from the arrays of ``swarm.map.projection`` and back.

Layouts (the messages' own definitions, ros2/common_interfaces and ros-planning/navigation_msgs):

* OccupancyGrid: ``info.resolution`` the voxel edge (m), ``info.width`` cells along x (nx),
  ``info.height`` along y (ny), ``info.origin`` the pose of cell (0, 0)'s lower corner in
  ``header.frame_id`` (here the map box's x, y and the height band's bottom z, no rotation);
  ``data`` row-major from that corner, x fastest: ``data[j * width + i]`` is cell (i, j);
  values 0..100 occupancy, -1 unknown.
* OccupancyGridUpdate: the cells of the box x in [x, x + width), y in [y, y + height) of the last
  OccupancyGrid on the same frame, row-major likewise (RViz's map display and Nav2's static
  layer apply them to the grid they hold).
* PointCloud2: one row (``height`` 1) of ``width`` points, ``point_step`` 24 bytes, fields
  x, y, z, mu, sigma, entropy (FLOAT32, count 1, at offsets 0, 4, ..., 20), little-endian,
  ``is_dense`` (no NaN).

``map_msgs`` is not among rosbags' bundled definitions: :func:`register_map_msgs` adds
OccupancyGridUpdate to a distribution's type store from its definition below.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from rosbags.typesys import get_types_from_msg

from swarm.map.projection import CLOUD_DTYPE, CLOUD_FIELDS
from swarm.ros2.types import Ros2Types, header, time_fields

OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
OCCUPANCY_GRID_UPDATE = "map_msgs/msg/OccupancyGridUpdate"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"

#: map_msgs/msg/OccupancyGridUpdate (ros-planning/navigation_msgs), its fields
OCCUPANCY_GRID_UPDATE_MSG = """std_msgs/Header header
int32 x
int32 y
uint32 width
uint32 height
int8[] data
"""

#: sensor_msgs/msg/PointField.FLOAT32
POINT_FIELD_FLOAT32 = 7


def register_map_msgs(types: Ros2Types) -> None:
    """Add ``map_msgs/msg/OccupancyGridUpdate`` to ``types``' store (once; a no-op after)."""
    if OCCUPANCY_GRID_UPDATE not in types.store.types:
        types.store.register(get_types_from_msg(OCCUPANCY_GRID_UPDATE_MSG, OCCUPANCY_GRID_UPDATE))


def _pose(types: Ros2Types, xyz: tuple[float, float, float]) -> Any:
    point = types.new("geometry_msgs/msg/Point", x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))
    rotation = types.new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)
    return types.new("geometry_msgs/msg/Pose", position=point, orientation=rotation)


def _rows(cells: np.ndarray) -> np.ndarray:
    """(nx, ny) cells as the row-major, x-fastest int8 data of a ROS grid."""
    return np.ascontiguousarray(np.asarray(cells, np.int8).T).reshape(-1)


def occupancy_grid(
    types: Ros2Types,
    cells: np.ndarray,
    origin: tuple[float, float, float],
    resolution: float,
    frame_id: str,
    stamp: float,
) -> Any:
    """A ``nav_msgs/OccupancyGrid`` of int8 ``cells`` (nx, ny) whose cell (0, 0) has its lower
    corner at ``origin`` (m, in ``frame_id``), stamped ``stamp`` (s since the UNIX epoch)."""
    nx, ny = np.shape(cells)
    info = types.new(
        "nav_msgs/msg/MapMetaData",
        map_load_time=types.new("builtin_interfaces/msg/Time", **time_fields(stamp)),
        resolution=float(resolution),
        width=int(nx),
        height=int(ny),
        origin=_pose(types, origin),
    )
    return types.new(OCCUPANCY_GRID, header=header(types, stamp, frame_id), info=info, data=_rows(cells))


def occupancy_grid_update(
    types: Ros2Types, cells: np.ndarray, box: tuple[slice, slice], frame_id: str, stamp: float
) -> Any:
    """A ``map_msgs/OccupancyGridUpdate`` of the box (i slice, j slice) of ``cells`` (nx, ny)."""
    register_map_msgs(types)
    i, j = box
    patch = np.asarray(cells)[i, j]
    return types.new(
        OCCUPANCY_GRID_UPDATE,
        header=header(types, stamp, frame_id),
        x=int(i.start),
        y=int(j.start),
        width=int(patch.shape[0]),
        height=int(patch.shape[1]),
        data=_rows(patch),
    )


def grid_cells(message: Any) -> np.ndarray:
    """The (nx, ny) int8 cells of an OccupancyGrid or OccupancyGridUpdate; ValueError when its
    data does not hold width x height cells."""
    size = message.info if hasattr(message, "info") else message
    width, height = int(size.width), int(size.height)
    data = np.asarray(message.data, np.int8)
    if data.size != width * height:
        raise ValueError(f"grid of {width} x {height} cells carries {data.size} values")
    return data.reshape(height, width).T


def point_cloud(types: Ros2Types, points: np.ndarray, frame_id: str, stamp: float) -> Any:
    """A ``sensor_msgs/PointCloud2`` of a ``CLOUD_DTYPE`` structured array (N,)."""
    points = np.ascontiguousarray(points, CLOUD_DTYPE)
    fields = [
        types.new(
            "sensor_msgs/msg/PointField",
            name=name,
            offset=int(CLOUD_DTYPE.fields[name][1]),
            datatype=POINT_FIELD_FLOAT32,
            count=1,
        )
        for name in CLOUD_FIELDS
    ]
    return types.new(
        POINT_CLOUD2,
        header=header(types, stamp, frame_id),
        height=1,
        width=int(points.size),
        fields=fields,
        is_bigendian=False,
        point_step=CLOUD_DTYPE.itemsize,
        row_step=CLOUD_DTYPE.itemsize * int(points.size),
        data=points.view(np.uint8).reshape(-1),
        is_dense=True,
    )


def cloud_points(message: Any) -> np.ndarray:
    """The points of a PointCloud2 as a structured array with one float32 column per FLOAT32
    field (any field order and offsets, little-endian); ValueError for other layouts."""
    if message.is_bigendian:
        raise ValueError("a big-endian point cloud")
    fields = {f.name: int(f.offset) for f in message.fields if f.datatype == POINT_FIELD_FLOAT32}
    n = int(message.width) * int(message.height)
    step = int(message.point_step)
    data = np.asarray(message.data, np.uint8)
    if data.size != n * step or any(off + 4 > step for off in fields.values()):
        raise ValueError(f"{n} points of {step} bytes do not fit {data.size} bytes of data")
    dtype = np.dtype({"names": list(fields), "formats": ["<f4"] * len(fields),
                      "offsets": list(fields.values()), "itemsize": step})  # fmt: skip
    return data.view(dtype) if n else np.empty(0, dtype)
