"""The numpy renderer as it was before the compiled one (sim2d/render.py at 82e2908): the oracle.

Kept verbatim (only this docstring is new) so that tests can check that the compiled
renderer gives the same hits and the same images. Slow: about 0.3 s per 640x480 image.
Its original description follows.

Exact, vectorised ray casting of a floor plan: rectified stereo pairs and depth images.

Every obstacle is a convex quad extruded from the floor (``FloorPlan``). A pixel ray
c + s d is split into its direction on the floor plane u = d_xy / |d_xy| and its slope
m = d_z / |d_xy|, so at horizontal distance r it is at height c_z + m r. Clipping u against
each quad (Cyrus-Beck) gives the interval [r_in, r_out] where the ray is above the quad;
the ray hits the quad's side at r_in when 0 <= c_z + m r_in <= h, or its top at
r = (h - c_z) / m when it enters above it and comes down before r_out; otherwise it hits
the floor at r = -c_z / m (or nothing). All distances are analytic: no marching.

For a level camera (no pitch, no roll) every image column is one floor-plane ray, so the
clipping costs columns x quads and only the rows differ in slope; crossings that a nearer
crossing hides from every row are pruned before the per-pixel step. A pitched camera casts
one floor-plane ray per pixel.

Images are grey (uint8): walls, box sides and tops and the floor carry a procedural
multi-scale texture (filtered noise, mip-mapped so it does not alias) under a fixed
directional light, so both cameras of a pair see the same surface pattern and block
matching (OpenCV SGBM) works. Pixels with no return are flat dark grey.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from swarm.formats.floor_plan import FloorPlan
from swarm.protocol.wire import Camera, Pose

FACE_NONE, FACE_FLOOR, FACE_SIDE, FACE_TOP = 0, 1, 2, 3
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
    """

    def __init__(self, plan: FloorPlan, camera: Camera, *, seed: int = 0, max_distance: float = 60.0):
        self.plan = plan
        self.camera = camera
        self.max_distance = float(max_distance)
        self.texture = _texture_pyramid(seed)
        u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
        self._optical = np.stack(
            [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(u.shape)], axis=-1
        )
        self._edge_a, self._edge_n = plan.edge_normals()
        self._centres = plan.quads.mean(axis=1)
        self._radii = np.linalg.norm(plan.quads - self._centres[:, None], axis=-1).max(axis=1)
        # Each wall segment or box gets its own albedo and texture offset; the cells of a
        # ROS map share one, so that a wall made of many cells looks like one surface.
        rng = np.random.default_rng([seed, 7])
        self._albedo = rng.uniform(0.65, 1.0, size=plan.count)
        self._offsets = rng.uniform(0, 4096, size=(plan.count, 5, 2))  # 4 sides + top
        cells = np.array([kind == "cell" for kind in plan.kinds], dtype=bool)
        self._albedo[cells] = 0.85
        self._offsets[cells] = 0.0

    # -- geometry ----------------------------------------------------------------------
    def cast(self, pose: Pose, surface: bool = True) -> Hits:
        """Cast every pixel ray of a camera at ``pose`` (``surface``: also points, footprints)."""
        h_img, w_img = self.camera.height, self.camera.width
        dirs = self._optical @ pose.optical_rotation().T  # (H, W, 3) world, optical z = 1
        level = abs(pose.ypr[1]) < 1e-12 and abs(pose.ypr[2]) < 1e-12
        if not level:
            dirs = dirs.reshape(1, -1, 3)
        ray_xy = dirs[0, :, :2]
        norm_h = np.maximum(np.linalg.norm(ray_xy, axis=-1), 1e-12)  # (R,)
        unit = ray_xy / norm_h[:, None]
        slope = dirs[..., 2] / norm_h  # (rows, R)
        origin = np.asarray(pose.xyz, dtype=np.float64)
        cam_z = origin[2]

        # Sort the floor-plane rays by azimuth; each block of neighbours only meets the quads
        # inside its narrow wedge.
        mid = math.atan2(unit[:, 1].mean(), unit[:, 0].mean())
        angle = _wrap(np.arctan2(unit[:, 1], unit[:, 0]) - mid)
        perm = np.argsort(angle, kind="stable")
        angle, s_unit, s_slope = angle[perm], unit[perm], slope[:, perm]
        q_lo, q_hi, in_range = self._quad_wedges(origin, mid)

        distance = np.where(s_slope < 0, -cam_z / np.where(s_slope < 0, s_slope, -1.0), np.inf)
        face = np.where(s_slope < 0, FACE_FLOOR, FACE_NONE).astype(np.int8)
        obstacle = np.full(s_slope.shape, -1, dtype=np.int32)
        edge = np.full(s_slope.shape, -1, dtype=np.int8)
        block = max(16, 8192 // s_slope.shape[0]) if level else 1024
        for r0 in range(0, len(angle), block):
            rays = slice(r0, r0 + block)
            a_lo, a_hi = angle[rays][0] - 1e-9, angle[rays][-1] + 1e-9
            overlap = np.zeros_like(in_range)
            for shift in (-2 * np.pi, 0.0, 2 * np.pi):
                overlap |= (q_lo + shift <= a_hi) & (q_hi + shift >= a_lo)
            quads = np.flatnonzero(in_range & overlap)
            if quads.size:
                self._hit_quads(
                    origin[:2], cam_z, s_unit[rays], s_slope[:, rays], quads, level,
                    distance[:, rays], face[:, rays], obstacle[:, rays], edge[:, rays],
                )  # fmt: skip
        unsort = np.argsort(perm)
        distance, face = distance[:, unsort], face[:, unsort]
        obstacle, edge = obstacle[:, unsort], edge[:, unsort]
        far = distance > self.max_distance
        distance[far], face[far], obstacle[far], edge[far] = np.inf, FACE_NONE, -1, -1

        hit = np.isfinite(distance)
        r = np.where(hit, distance, 0.0)
        shape = (h_img, w_img)
        hits = Hits(
            distance=distance.reshape(shape),
            depth=np.where(hit, r / norm_h, np.nan).reshape(shape),
            face=face.reshape(shape),
            obstacle=obstacle.reshape(shape),
            edge=edge.reshape(shape),
        )
        if surface:
            points = np.stack(
                [origin[0] + r * unit[:, 0], origin[1] + r * unit[:, 1], cam_z + r * slope],
                axis=-1,
            )
            # Pixel footprint on the surface: range / f, widened at grazing incidence.
            cos_inc = self._incidence(face, obstacle, edge, unit, slope)
            ray_len = r * np.sqrt(1 + slope**2)
            footprint = ray_len / self.camera.fx / np.maximum(cos_inc, 0.2)
            hits.points = points.reshape(*shape, 3)
            hits.footprint = footprint.reshape(shape)
        return hits

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

    def _hit_quads(
        self,
        origin: np.ndarray,
        cam_z: float,
        unit: np.ndarray,
        slope: np.ndarray,
        quads: np.ndarray,
        level: bool,
        distance: np.ndarray,
        face: np.ndarray,
        obstacle: np.ndarray,
        edge: np.ndarray,
    ) -> None:
        """Nearest obstacle hit of rays ``unit`` (R, 2) with slopes (rows, R); updates in place."""
        r_in, r_out, enter, valid = _clip_rays(origin, unit, self._edge_a[quads], self._edge_n[quads])
        height = self.plan.heights[quads][None, :]
        valid &= r_in < self.max_distance
        if level:
            valid &= ~_hidden(r_in, r_out, height, valid, cam_z)
        keep = valid.sum(axis=1)
        layers = int(keep.max()) if keep.size else 0
        if layers == 0:
            return
        order = np.argsort(~valid, axis=1, kind="stable")[:, :layers]  # (R, L)
        take = functools.partial(np.take_along_axis, indices=order, axis=1)
        r_in, r_out, enter, valid = take(r_in), take(r_out), take(enter), take(valid)
        h = self.plan.heights[quads][order]
        m = slope[..., None]  # (rows, R, 1)
        z_in = cam_z + m * r_in
        side = valid & (z_in >= 0) & (z_in <= h)
        with np.errstate(divide="ignore", invalid="ignore"):
            r_top = np.where(m < 0, (h - cam_z) / m, np.inf)
        top = valid & (z_in > h) & (m < 0) & (r_top <= r_out)
        cand = np.where(side, r_in, np.where(top, r_top, np.inf))  # (rows, R, L)
        best = np.argmin(cand, axis=-1)
        best_r = np.take_along_axis(cand, best[..., None], axis=-1)[..., 0]
        better = best_r < distance
        rows_idx, ray_idx = np.nonzero(better)
        layer = best[rows_idx, ray_idx]
        distance[better] = best_r[better]
        is_side = side[rows_idx, ray_idx, layer]
        face[better] = np.where(is_side, FACE_SIDE, FACE_TOP)
        obstacle[better] = quads[order[ray_idx, layer]]
        edge[better] = np.where(is_side, enter[ray_idx, layer], -1)

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
    def shade(self, hits: Hits) -> np.ndarray:
        """Grey levels (float, 0-255) of what ``hits`` sees: texture x albedo x light."""
        face, obs, edge = hits.face, hits.obstacle, hits.edge
        p = hits.points
        su = np.zeros(face.shape)
        sv = np.zeros(face.shape)
        albedo = np.ones(face.shape)
        light = np.full(face.shape, _AMBIENT + (1 - _AMBIENT) * _LIGHT[2])

        floor = face == FACE_FLOOR
        su[floor], sv[floor] = p[floor, 0] * 0.8, p[floor, 1] * 0.8
        albedo[floor] = 0.8

        top = face == FACE_TOP
        off = self._offsets[obs[top], 4]
        su[top], sv[top] = p[top, 0] + off[:, 0], p[top, 1] + off[:, 1]
        albedo[top] = self._albedo[obs[top]]

        side = face == FACE_SIDE
        n = self._edge_n[obs[side], edge[side]]
        along = np.stack([-n[:, 1], n[:, 0]], axis=-1)
        off = self._offsets[obs[side], edge[side]]
        su[side] = np.sum(p[side, :2] * along, axis=-1) + off[:, 0]
        sv[side] = p[side, 2] + off[:, 1]
        albedo[side] = self._albedo[obs[side]]
        light[side] = _AMBIENT + (1 - _AMBIENT) * np.maximum(0.0, n @ _LIGHT[:2])

        tex = self.texture.sample(su, sv, hits.footprint)
        grey = 255.0 * albedo * light * (0.25 + 0.75 * tex)
        grey[face == FACE_NONE] = SKY_GREY
        return grey

    def image(self, pose: Pose, noise_std: float = 0.0, rng=None) -> np.ndarray:
        """One grey image (uint8 H x W) seen from ``pose``, with optional Gaussian noise."""
        grey = self.shade(self.cast(pose))
        if noise_std > 0:
            rng = rng if rng is not None else np.random.default_rng()
            grey = grey + rng.normal(0.0, noise_std, grey.shape)
        return np.clip(np.rint(grey), 0, 255).astype(np.uint8)

    def stereo_pair(self, pose: Pose, noise_std: float = 0.0, rng=None) -> tuple[np.ndarray, np.ndarray]:
        """Rectified (left, right) uint8 images; ``pose`` is the left camera's."""
        right = right_camera_pose(pose, self.camera.baseline)
        return self.image(pose, noise_std, rng), self.image(right, noise_std, rng)

    def depth_image(
        self,
        pose: Pose,
        noise_per_m: float = 0.0,
        max_range: float | None = None,
        rng=None,
    ) -> np.ndarray:
        """Optical-z depth (float32 m, NaN = no return); noise std = ``noise_per_m`` x depth."""
        depth = self.cast(pose, surface=False).depth
        if noise_per_m > 0:
            rng = rng if rng is not None else np.random.default_rng()
            depth = depth + rng.normal(0.0, 1.0, depth.shape) * noise_per_m * depth
        if max_range is not None:
            depth = np.where(depth <= max_range, depth, np.nan)
        depth = np.where(depth > 0, depth, np.nan)
        return depth.astype(np.float32)


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def _clip_rays(
    origin: np.ndarray, unit: np.ndarray, edge_a: np.ndarray, edge_n: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cyrus-Beck: distances where rays (R, 2) from ``origin`` enter and leave quads (Q, 4, 2).

    Returns r_in, r_out (R, Q), the entering edge (R, Q) and whether the ray crosses the
    quad ahead of the origin. A quad side is ``n . (p - a) <= 0``.
    """
    num = np.sum(edge_n * (origin - edge_a), axis=-1)  # (Q, 4): > 0 outside that side
    den = np.einsum("rk,qek->rqe", unit, edge_n)  # (R, Q, 4)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -num / den
    t_enter = np.where(den < 0, t, -np.inf)
    t_exit = np.where(den > 0, t, np.inf)
    enter = np.argmax(t_enter, axis=-1).astype(np.int8)
    r_in = np.take_along_axis(t_enter, enter[..., None].astype(np.int64), axis=-1)[..., 0]
    r_out = t_exit.min(axis=-1)
    parallel_out = np.any((den == 0) & (num > 0), axis=-1)
    valid = (r_in < r_out) & (r_out > 0) & ~parallel_out
    return np.maximum(r_in, 0.0), r_out, enter, valid


def _hidden(
    r_in: np.ndarray, r_out: np.ndarray, height: np.ndarray, valid: np.ndarray, cam_z: float
) -> np.ndarray:
    """Crossings (R, Q) that no pixel of their column can see.

    Every pixel whose slope is at most g_j = max((h_j - c_z) / r_in_j, (h_j - c_z) / r_out_j)
    is stopped (by crossing j or the floor before it) no farther than r_out_j. So crossing k
    is hidden when some crossing j with r_out_j <= r_in_k has g_j >= g_k. Computed with one
    sort per column: the running maximum of g over exits, read at each entry.
    """
    n_rays, n_q = r_in.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.maximum((height - cam_z) / r_in, (height - cam_z) / r_out)
    g = np.where(valid, np.nan_to_num(g, nan=np.inf, posinf=np.inf), -np.inf)
    # Events: exits (value g, at r_out) sorted before entries at the same distance.
    pos = np.concatenate([np.where(valid, r_out, np.inf), np.where(valid, r_in, np.inf)], axis=1)
    kind = np.concatenate([np.zeros((n_rays, n_q)), np.ones((n_rays, n_q))], axis=1)
    order = np.lexsort((kind, pos), axis=1)
    exit_g = np.concatenate([g, np.full((n_rays, n_q), -np.inf)], axis=1)
    running = np.maximum.accumulate(np.take_along_axis(exit_g, order, axis=1), axis=1)
    seen_before = np.empty_like(running)
    np.put_along_axis(seen_before, order, running, axis=1)
    return valid & (seen_before[:, n_q:] >= g)


# -- texture -----------------------------------------------------------------------------


class TexturePyramid:
    """A periodic square grey texture tile (values 0-1, side a power of two) with mip levels.

    All levels live in one flat array so that a lookup is a few vectorised gathers, each
    pixel at its own level. Coordinates are in metres; ``texel`` is the finest texel's size.
    """

    def __init__(self, tile: np.ndarray, texel: float):
        self.texel = texel
        levels = [tile.astype(np.float32)]
        while levels[-1].shape[0] > 1:
            t = levels[-1]
            levels.append(0.25 * (t[::2, ::2] + t[1::2, ::2] + t[::2, 1::2] + t[1::2, 1::2]))
        self.count = len(levels)
        self.sizes = np.array([lvl.shape[0] for lvl in levels], dtype=np.int64)
        self.starts = np.concatenate([[0], np.cumsum(self.sizes**2)[:-1]]).astype(np.int64)
        self.texels = np.concatenate([lvl.ravel() for lvl in levels])

    def sample(self, u: np.ndarray, v: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        """Trilinear lookup at (u, v) metres for pixels covering ``footprint`` metres."""
        lod = np.clip(np.log2(np.maximum(footprint, 1e-9) / self.texel), 0, self.count - 1)
        fine = np.floor(lod).astype(np.int64)
        coarse = np.minimum(fine + 1, self.count - 1)
        a = self._bilinear(fine, u, v)
        return a + (self._bilinear(coarse, u, v) - a) * (lod - fine)

    def _bilinear(self, level: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        n = self.sizes[level]
        scale = self.texel * np.exp2(level)
        x = u / scale - 0.5
        y = v / scale - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = x - x0, y - y0
        wrap = n - 1
        i0 = x0.astype(np.int64) & wrap
        j0 = y0.astype(np.int64) & wrap
        i1, j1 = (i0 + 1) & wrap, (j0 + 1) & wrap
        row0 = self.starts[level] + j0 * n
        row1 = self.starts[level] + j1 * n
        t = self.texels
        top = t[row0 + i0] * (1 - fx) + t[row0 + i1] * fx
        bottom = t[row1 + i0] * (1 - fx) + t[row1 + i1] * fx
        return top * (1 - fy) + bottom * fy


@functools.lru_cache(maxsize=4)
def _texture_pyramid(seed: int, size: int = 1024, texel: float = 0.004) -> TexturePyramid:
    """Band-limited 1/f noise on a periodic tile, squashed to 0-1."""
    rng = np.random.default_rng([seed, 1])
    freq = np.fft.fftfreq(size)
    radius = np.hypot(freq[:, None], freq[None, :])
    amplitude = np.where(radius > 0, 1.0 / np.maximum(radius, 1.0 / size) ** 0.9, 0.0)
    amplitude *= np.exp(-((radius / 0.35) ** 4))  # gentle roll-off near Nyquist
    spectrum = np.fft.fft2(rng.standard_normal((size, size))) * amplitude
    tile = np.real(np.fft.ifft2(spectrum))
    tile = (tile - tile.mean()) / tile.std()
    tile = 0.5 + 0.5 * np.tanh(0.8 * tile)
    return TexturePyramid(tile, texel)


def vertical_fov(camera: Camera) -> float:
    """Vertical field of view (radians) of a camera."""
    return 2 * math.atan(0.5 * camera.height / camera.fy)
