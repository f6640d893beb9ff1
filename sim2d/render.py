"""Exact, vectorised ray casting of a floor plan: rectified stereo pairs and depth images.

Every obstacle is a convex quad extruded from the floor (``FloorPlan``). A pixel ray
c + s d is split into its direction on the floor plane u = d_xy / |d_xy| and its slope
m = d_z / |d_xy|, so at horizontal distance r it is at height c_z + m r. Clipping u against
each quad (Cyrus-Beck) gives the interval [r_in, r_out] where the ray is above the quad;
the ray hits the quad's side at r_in when 0 <= c_z + m r_in <= h, or its top at
r = (h - c_z) / m when it enters above it and comes down before r_out; otherwise it hits
the floor at r = -c_z / m (or nothing). All distances are analytic: no marching.

For a level camera (no pitch, no roll) every image column is one floor-plane ray, so the
clipping costs columns x quads and only the rows differ in slope; each pixel walks its
column's crossings nearest first and stops at the first that cannot beat its best hit. A
pitched camera casts one floor-plane ray per pixel.

Images are grey (uint8): walls, box sides and tops and the floor carry a procedural
multi-scale texture (filtered noise, mip-mapped so it does not alias) under a fixed
directional light, so both cameras of a pair see the same surface pattern and block
matching (OpenCV SGBM) works. Pixels with no return are flat dark grey.

The per-pixel work (nearest hit, shading, texture lookup) is compiled with Numba
(``sim2d.render_kernels``, ``sim2d.texture_sampling``); this module sets up the rays and the
culling of quads by azimuth, in numpy.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from sim2d.render_kernels import (
    FACE_FLOOR,
    FACE_NONE,
    FACE_SIDE,
    FACE_TOP,
    cast_rays,
    grey_levels,
    shade_pixels,
)
from sim2d.texture_sampling import TexturePyramid, texture_pyramid
from swarm.formats.floor_plan import FloorPlan
from swarm.protocol.wire import Camera, Pose

__all__ = [
    "FACE_FLOOR", "FACE_NONE", "FACE_SIDE", "FACE_TOP", "SKY_GREY", "Hits", "Renderer", "TexturePyramid",
    "camera_pose", "right_camera_pose", "vertical_fov",
]  # fmt: skip

SKY_GREY = 30.0
_AMBIENT = 0.55
_LIGHT = np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])


@dataclass
class Hits:
    """What each pixel of one camera sees (arrays H x W).

    ``distance``: along the floor plane (m, inf = no return); ``depth``: optical z (m,
    NaN = no return); ``face``: FACE_* code; ``obstacle``: index in the floor plan (-1 for
    floor / none); ``edge``: side index 0-3 (-1 if not a side). With ``surface``:
    ``points``, the world hit points (H, W, 3), and ``footprint``, the size (m) of each
    pixel on the surface.
    """

    distance: np.ndarray
    depth: np.ndarray
    face: np.ndarray
    obstacle: np.ndarray
    edge: np.ndarray
    points: np.ndarray | None = None
    footprint: np.ndarray | None = None


@dataclass
class _Rays:
    """Floor-plane rays of one view and their nearest hits.

    ``unit`` (R, 2) ray directions on the floor, ``norm_h`` (R,) |d_xy| of the pixel rays
    (optical z = 1), ``slope`` (R, rows); a level camera has one ray per column (rows = H),
    a pitched one a ray per pixel (rows = 1). Hits as in ``Hits``, shaped (R, rows): ray-major,
    so that the kernels walk each ray's pixels in memory order (the image is the transpose).
    """

    origin: np.ndarray
    unit: np.ndarray
    norm_h: np.ndarray
    slope: np.ndarray
    distance: np.ndarray
    face: np.ndarray
    obstacle: np.ndarray
    edge: np.ndarray


def camera_pose(x: float, y: float, yaw: float, height: float, pitch: float = 0.0) -> Pose:
    """The pose of a camera on a robot at (x, y, yaw) and ``height``, tilted by ``pitch``."""
    return Pose((float(x), float(y), float(height)), (float(yaw), float(pitch), 0.0))


def right_camera_pose(left: Pose, baseline: float) -> Pose:
    """The right camera of a rectified pair: ``baseline`` metres along the left camera's x axis."""
    offset = left.optical_rotation()[:, 0] * baseline
    return Pose(tuple(np.asarray(left.xyz) + offset), left.ypr)


class Renderer:
    """Renders views of one floor plan with one camera model.

    ``seed`` picks the texture; ``max_distance`` (m) bounds what is cast (farther is no return).
    ``threads``: 2 renders the right view of a stereo pair and draws its noise in a second
    thread while this one does the left view (the compiled kernels and numpy's generator
    release the GIL; the left view's noise is drawn first, so ``rng`` gives the same draws);
    1 renders everything in the calling thread. Images are the same either way. A renderer
    is not meant to be shared by threads that render at the same time.
    """

    def __init__(
        self, plan: FloorPlan, camera: Camera, *, seed: int = 0, max_distance: float = 60.0, threads: int = 2
    ):
        if threads not in (1, 2):
            raise ValueError(f"Renderer: threads must be 1 or 2 (got {threads})")
        self.plan = plan
        self.camera = camera
        self.max_distance = float(max_distance)
        self.threads = threads
        self._worker: ThreadPoolExecutor | None = None
        self.texture = texture_pyramid(seed)
        u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
        self._optical = np.stack(
            [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(u.shape)], axis=-1
        )
        self._edge_a, self._edge_n = plan.edge_normals()
        self._centres = plan.quads.mean(axis=1)
        self._radii = np.linalg.norm(plan.quads - self._centres[:, None], axis=-1).max(axis=1)
        self._heights = np.ascontiguousarray(plan.heights, dtype=np.float64)
        # Each wall segment or box gets its own albedo and texture offset; the cells of a
        # ROS map share one, so that a wall made of many cells looks like one surface.
        rng = np.random.default_rng([seed, 7])
        self._albedo = rng.uniform(0.65, 1.0, size=plan.count)
        self._offsets = rng.uniform(0, 4096, size=(plan.count, 5, 2))  # 4 sides + top
        cells = np.array([kind == "cell" for kind in plan.kinds], dtype=bool)
        self._albedo[cells] = 0.85
        self._offsets[cells] = 0.0
        # Lambert light on each quad side (normal n, light l): ambient + (1 - ambient) max(0, n . l).
        n = self._edge_n.reshape(-1, 2)
        side = n[:, 0] * _LIGHT[0] + n[:, 1] * _LIGHT[1]
        self._side_light = (_AMBIENT + (1 - _AMBIENT) * np.maximum(0.0, side)).reshape(plan.count, 4)
        self._flat_light = _AMBIENT + (1 - _AMBIENT) * _LIGHT[2]

    # -- geometry ----------------------------------------------------------------------
    def cast(self, pose: Pose, surface: bool = True) -> Hits:
        """Cast every pixel ray of a camera at ``pose`` (``surface``: also points, footprints)."""
        rays = self._trace(pose)
        # Image order: (rows, R), row-major.
        distance, face, obstacle, edge = (
            np.ascontiguousarray(a.T) for a in (rays.distance, rays.face, rays.obstacle, rays.edge)
        )
        r, depth = self._depth(rays, distance)
        shape = (self.camera.height, self.camera.width)
        hits = Hits(
            distance=distance.reshape(shape),
            depth=depth.reshape(shape),
            face=face.reshape(shape),
            obstacle=obstacle.reshape(shape),
            edge=edge.reshape(shape),
        )
        if surface:
            unit, slope, origin = rays.unit, np.ascontiguousarray(rays.slope.T), rays.origin
            points = np.stack(
                [origin[0] + r * unit[:, 0], origin[1] + r * unit[:, 1], origin[2] + r * slope], axis=-1
            )
            # Pixel footprint on the surface: range / f, widened at grazing incidence.
            cos_inc = self._incidence(face, obstacle, edge, unit, slope)
            ray_len = r * np.sqrt(1 + slope**2)
            footprint = ray_len / self.camera.fx / np.maximum(cos_inc, 0.2)
            hits.points = points.reshape(*shape, 3)
            hits.footprint = footprint.reshape(shape)
        return hits

    @staticmethod
    def _depth(rays: _Rays, distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Floor-plane distance (0 = no return) and optical z (NaN = no return) of ``distance`` (rows, R)."""
        hit = np.isfinite(distance)
        r = np.where(hit, distance, 0.0)
        return r, np.where(hit, r / rays.norm_h, np.nan)

    def _trace(self, pose: Pose) -> _Rays:
        """The floor-plane rays of a camera at ``pose`` and the nearest hit of each pixel."""
        rotation = pose.optical_rotation()
        yaw_only = pose.ypr[1] == 0 and pose.ypr[2] == 0
        level = abs(pose.ypr[1]) < 1e-12 and abs(pose.ypr[2]) < 1e-12
        if yaw_only:  # d_xy is the same down a column and d_z the same along a row
            ray_xy = (self._optical[0] @ rotation.T)[:, :2]
            dirs_z = (self._optical[:, :1] @ rotation.T)[..., 2]  # (H, 1)
        else:
            dirs = self._optical @ rotation.T  # (H, W, 3) world, optical z = 1
            if not level:
                dirs = dirs.reshape(1, -1, 3)
            ray_xy, dirs_z = dirs[0, :, :2], dirs[..., 2]
        norm_h = np.maximum(np.linalg.norm(ray_xy, axis=-1), 1e-12)  # (R,)
        unit = ray_xy / norm_h[:, None]
        slope = dirs_z.T / norm_h[:, None]  # (R, rows): slope[ray, row] = dirs_z[row, ray] / norm_h[ray]
        origin = np.asarray(pose.xyz, dtype=np.float64)

        # Sort the floor-plane rays by azimuth; each block of neighbours only meets the quads
        # inside its narrow wedge.
        mid = math.atan2(unit[:, 1].mean(), unit[:, 0].mean())
        angle = _wrap(np.arctan2(unit[:, 1], unit[:, 0]) - mid)
        perm = np.argsort(angle, kind="stable")
        q_lo, q_hi, in_range = self._quad_wedges(origin, mid)
        block = max(16, 8192 // slope.shape[1]) if level else 1024
        distance = np.empty(slope.shape)
        face = np.empty(slope.shape, dtype=np.int8)
        obstacle = np.empty(slope.shape, dtype=np.int32)
        edge = np.empty(slope.shape, dtype=np.int8)
        cast_rays(
            origin[:2], origin[2], unit, slope, perm, angle[perm], block, q_lo, q_hi, in_range,
            self._edge_a, self._edge_n, self._heights, self.max_distance, distance, face, obstacle, edge,
        )  # fmt: skip
        return _Rays(origin, unit, norm_h, slope, distance, face, obstacle, edge)

    def _quad_wedges(self, origin: np.ndarray, mid: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Azimuth interval (relative to ``mid``) each quad covers from ``origin``, and range mask.

        A convex quad not containing the camera spans less than pi, around the direction of
        its centre; one containing the camera spans everything.
        """
        xy = origin[:2]
        to_centre = self._centres - xy
        centre_angle = np.arctan2(to_centre[:, 1], to_centre[:, 0])
        to_corner = self.plan.quads - xy
        corner_angle = np.arctan2(to_corner[..., 1], to_corner[..., 0])
        rel = _wrap(corner_angle - centre_angle[:, None])
        base = _wrap(centre_angle - mid)
        lo, hi = base + rel.min(axis=1), base + rel.max(axis=1)
        inside = np.all(np.sum(self._edge_n * (xy - self._edge_a), axis=-1) < 1e-9, axis=1)
        lo[inside], hi[inside] = -np.inf, np.inf
        in_range = np.linalg.norm(to_centre, axis=1) - self._radii < self.max_distance
        return lo, hi, in_range

    def _incidence(self, face, obstacle, edge, unit, slope) -> np.ndarray:
        """|cos| of the angle between each pixel ray and the surface normal it hits."""
        norm = np.sqrt(1 + slope**2)
        cos = np.abs(slope) / norm  # floor and tops: normal (0, 0, 1)
        side = face == FACE_SIDE
        if side.any():
            normals = self._edge_n[obstacle[side], edge[side]]
            ray_idx = np.nonzero(side)[1]
            cos_side = np.abs(np.sum(normals * unit[ray_idx], axis=-1)) / norm[side]
            cos = cos.copy()
            cos[side] = cos_side
        return cos

    # -- images ------------------------------------------------------------------------
    def grey(self, pose: Pose) -> np.ndarray:
        """Grey levels (float64 H x W, 0-255) seen from ``pose``: texture x albedo x light."""
        rays = self._trace(pose)
        grey = np.empty(rays.slope.shape[::-1])  # (rows, R): image order
        tex = self.texture
        shade_pixels(
            rays.distance, rays.face, rays.obstacle, rays.edge, rays.unit, rays.slope, rays.origin[:2],
            rays.origin[2], self.camera.fx, self._edge_n, self._albedo, self._offsets, self._side_light,
            self._flat_light, SKY_GREY, tex.texels, tex.starts, tex.sizes, tex.shrink, tex.texel, grey,
        )  # fmt: skip
        return grey.reshape(self.camera.height, self.camera.width)

    def image(self, pose: Pose, noise_std: float = 0.0, rng=None) -> np.ndarray:
        """One grey image (uint8 H x W) seen from ``pose``, with optional Gaussian noise.

        ``noise_std``: grey levels; ``rng``: a numpy Generator (default: a fresh one).
        """
        grey = self.grey(pose)
        return _grey_levels(grey, self._noise(noise_std, rng), noise_std)

    def stereo_pair(self, pose: Pose, noise_std: float = 0.0, rng=None) -> tuple[np.ndarray, np.ndarray]:
        """Rectified (left, right) uint8 images; ``pose`` is the left camera's.

        The same images and the same draws from ``rng`` (left noise, then right) as
        ``image(pose)`` followed by ``image(right camera pose)``.
        """
        right = right_camera_pose(pose, self.camera.baseline)
        if self.threads == 1:
            return self.image(pose, noise_std, rng), self.image(right, noise_std, rng)
        if self._worker is None:
            self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim2d-render")
        # Each thread renders one view and draws its noise: the left noise first, here, while the
        # worker renders the right view; the worker draws the right noise once the left is drawn.
        left_noise_drawn = threading.Event()
        right_image = self._worker.submit(self._image_after, right, noise_std, rng, left_noise_drawn)
        try:
            left_noise = self._noise(noise_std, rng)
        finally:
            left_noise_drawn.set()
        left_image = _grey_levels(self.grey(pose), left_noise, noise_std)
        return left_image, right_image.result()

    def _image_after(self, pose: Pose, noise_std: float, rng, drawn: threading.Event) -> np.ndarray:
        """``image(pose, noise_std, rng)``, its noise drawn only once ``drawn`` is set."""
        grey = self.grey(pose)
        drawn.wait()
        return _grey_levels(grey, self._noise(noise_std, rng), noise_std)

    def _noise(self, noise_std: float, rng) -> np.ndarray:
        """Standard normal draws (H x W) for image noise; an empty array when ``noise_std`` is 0.

        ``rng.normal(0, s)`` is ``0 + s z`` with z from ``rng.standard_normal``, draw for draw
        (numpy's Generator), and the faster fill loop of ``standard_normal`` gives the same z:
        ``grey_levels`` forms 0 + s z, so images equal those of ``grey + rng.normal(0, s)``.
        """
        if noise_std > 0:
            rng = rng if rng is not None else np.random.default_rng()
            return rng.standard_normal((self.camera.height, self.camera.width))
        return np.empty(0)

    def depth_image(
        self,
        pose: Pose,
        noise_per_m: float = 0.0,
        max_range: float | None = None,
        rng=None,
    ) -> np.ndarray:
        """Optical-z depth (float32 m, NaN = no return); noise std = ``noise_per_m`` x depth."""
        rays = self._trace(pose)
        depth = self._depth(rays, np.ascontiguousarray(rays.distance.T))[1]
        depth = depth.reshape(self.camera.height, self.camera.width)
        if noise_per_m > 0:
            rng = rng if rng is not None else np.random.default_rng()
            depth = depth + rng.standard_normal(depth.shape) * noise_per_m * depth  # = rng.normal(0, 1)
        if max_range is not None:
            depth = np.where(depth <= max_range, depth, np.nan)
        depth = np.where(depth > 0, depth, np.nan)
        return depth.astype(np.float32)


def _grey_levels(grey: np.ndarray, normal: np.ndarray, noise_std: float) -> np.ndarray:
    """uint8 image of clip(rint(grey + (0 + noise_std normal)), 0, 255) (``normal`` empty: no noise)."""
    image = np.empty(grey.shape, dtype=np.uint8)
    grey_levels(grey, normal, float(noise_std), image)
    return image


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def vertical_fov(camera: Camera) -> float:
    """Vertical field of view (radians) of a camera."""
    return 2 * math.atan(0.5 * camera.height / camera.fy)


def warm_up_kernels() -> tuple:
    """The compiled kernels a first frame compiles on a first run (stereo and range frames alike)."""
    return (cast_rays, shade_pixels, grey_levels)
