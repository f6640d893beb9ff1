"""Stereo to range: SGBM disparity, depth, and world points (docs/design.md section 4, robot_agent).

Conventions
-----------
* Images are rectified, the left one is the reference. Pixel (u, v) is column u, row v,
  with pixel centres at integer coordinates (so a centred principal point is (w-1)/2).
* Disparity d = u_left - u_right in pixels; NaN where the matcher found no reliable match.
* Depth is the distance along the optical axis (not the ray length), in metres:
  Z = fx * baseline / (d + cx_right - cx). NaN where unknown.
* Camera frame (the robot's body axes, REP-103): the camera looks along +x (forward),
  image u to the right is -y, image v down is -z. A pixel at depth Z is the camera-frame
  point (Z, -(u - cx) Z / fx, -(v - cy) Z / fy).
* Pose: camera position ``pose_xyz`` in the world and ``pose_ypr`` = (yaw, pitch, roll) in
  radians, world_R_camera = Rz(yaw) Ry(pitch) Rx(roll) (so positive pitch looks down),
  the convention of ``swarm.protocol.wire.Pose``.
"""

from __future__ import annotations

import math
from typing import Any, Literal, Protocol

import cv2
import numba
import numpy as np

from robot_agent.disparity_kernels import depth_of_disparity, valid_disparity
from robot_agent.subpixel import refine_disparity
from swarm.config.rig_defaults import DEFAULT_MIN_DEPTH, SGBM_MODE_NAMES
from swarm.map.rotation import rotation_zyx

#: OpenCV's SGBM variants by the names of ``swarm.config.rig_defaults.SGBM_MODE_NAMES``, in its order.
SGBM_MODES = dict(
    zip(
        SGBM_MODE_NAMES,
        (
            cv2.STEREO_SGBM_MODE_SGBM,
            cv2.STEREO_SGBM_MODE_HH,
            cv2.STEREO_SGBM_MODE_SGBM_3WAY,
            cv2.STEREO_SGBM_MODE_HH4,
        ),
        strict=True,
    )
)


#: The texture filter's default threshold (grey levels): on seven real Middlebury pairs it
#: blanks flat (clipped or synthetic) areas only (docs/stereo.md).
DEFAULT_MIN_TEXTURE = 0.5

#: With image noise of standard deviation n, a blank area's block standard deviation is about
#: n (25 pixels: 1.0 n +- 0.14 n), so the filter must sit above it to blank it: 1.5 n.
NOISE_TEXTURE_FACTOR = 1.5

_NO_TEXTURE = np.zeros((0, 0), np.float32)  # valid_disparity's "no texture filter"


def texture_threshold(noise_std: float) -> float:
    """The texture filter (grey levels) for images with noise of ``noise_std`` grey levels.

    ``max(DEFAULT_MIN_TEXTURE, NOISE_TEXTURE_FACTOR * noise_std)``: a blank area seen by a
    noisy camera is noise only, which SGBM would match at random disparities.
    """
    return max(DEFAULT_MIN_TEXTURE, NOISE_TEXTURE_FACTOR * float(noise_std))


def matcher_for_rig(rig: Any) -> StereoMatcher:
    """The matcher an agent uses for a mission rig (``swarm.config.RigConfig``): the disparity
    range of its camera (``rig.camera()``) down to its ``min_depth``, the texture filter above
    its image noise (``texture_threshold(rig.noise_std)``), the other settings at their defaults."""
    return StereoMatcher.for_rig(rig.camera(), rig.min_depth, min_texture=texture_threshold(rig.noise_std))


class RectifiedRig(Protocol):
    """Anything with rectified intrinsics: ``fx``, ``cx``, ``baseline`` and optionally ``cx_right``.

    ``swarm.formats.stereo_calibration.StereoCalibration`` and ``swarm.protocol.wire.Camera`` both qualify.
    """

    fx: float
    cx: float
    baseline: float


def _disparity_offset(calib: RectifiedRig) -> float:
    cx_right = getattr(calib, "cx_right", None)
    return 0.0 if cx_right is None else float(cx_right) - float(calib.cx)


def disparity_range(
    calib: RectifiedRig, min_depth: float = DEFAULT_MIN_DEPTH, max_depth: float = math.inf, scale: float = 1.0
) -> tuple[int, int]:
    """(min_disparity, num_disparities) for SGBM covering depths [min_depth, max_depth] of a rig.

    ``scale`` is the matching scale (disparities shrink with the image). num_disparities is
    rounded up to a multiple of 16 as OpenCV requires.
    """
    if not (min_depth > 0 and max_depth > min_depth):
        raise ValueError(f"need 0 < min_depth < max_depth, got {min_depth}, {max_depth}")
    fb = float(calib.fx) * float(calib.baseline) * scale
    offset = _disparity_offset(calib) * scale
    d_hi = fb / min_depth - offset
    d_lo = (fb / max_depth if math.isfinite(max_depth) else 0.0) - offset
    min_disp = math.floor(d_lo)
    num = max(16, 16 * math.ceil((math.ceil(d_hi) + 1 - min_disp) / 16))
    return min_disp, num


def to_gray(image: np.ndarray, name: str = "image") -> np.ndarray:
    """A uint8 single-channel view of a gray, BGR or BGRA uint8 image."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ValueError(f"{name}: expected uint8 pixels, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 2:
        return np.ascontiguousarray(image)
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    raise ValueError(f"{name}: expected a gray (H, W) or BGR (H, W, 3) image, got shape {image.shape}")


class StereoMatcher:
    """OpenCV semi-global block matching; defaults chosen on real pairs with ground truth.

    ``num_disparities=48`` suits the default rig (160x120, 60 deg HFOV, 0.09 m baseline:
    fx*b = 12.5 px m, reaching 0.26 m); use ``for_rig`` to size it for another camera.
    ``block_size=5``; P1 = 8 * block^2 and P2 = 32 * block^2 (one gray channel) are OpenCV's
    usual smoothness weights; ``pre_filter_cap=63`` keeps the most of the x-gradient;
    ``uniqueness_ratio=10``, ``speckle_window_size=100`` and ``speckle_range=2`` remove
    ambiguous matches and small blobs; ``disp12_max_diff=1`` is the left-right check.
    ``mode="3way"``: on a real Middlebury pair 3-way, 5-path and 8-path SGBM are equally
    good (about 88 % valid, 94-95 % within 5 % of the true depth) and 3-way is 2-3x faster.
    With ``pad_border`` the images are padded on the left so that SGBM's invalid left border
    (num_disparities wide) costs only the pixels whose match really leaves the right image.
    ``min_texture`` (grey levels) is a texture filter, as in SRI's Small Vision System (the
    paper's stereo engine): pixels whose left-image standard deviation over the block is
    below it get no disparity, so SGBM's smoothness does not spread disparities into blank
    areas; 0 turns it off. 0.5 blanks flat (clipped or synthetic) areas only: on seven real
    Middlebury pairs 1.0 also blanked smooth wood and paper that SGBM matches right.
    ``scale`` < 1 matches a downsized pair (about 1/scale^3 faster) and brings the disparity
    back to full size (docs/stereo.md gives the accuracy cost).
    ``refine_subpixel`` adds one Lucas-Kanade step on the images to SGBM's disparity
    (``robot_agent.subpixel``): it halves the sub-pixel error on known fractional shifts but is
    off by default, as on real pairs whose ground truth is whole pixels it scores worse
    (docs/stereo.md).
    """

    def __init__(
        self,
        num_disparities: int = 48,
        block_size: int = 5,
        min_disparity: int = 0,
        uniqueness_ratio: int = 10,
        speckle_window_size: int = 100,
        speckle_range: int = 2,
        disp12_max_diff: int = 1,
        pre_filter_cap: int = 63,
        mode: Literal["sgbm", "hh", "3way", "hh4"] = "3way",
        pad_border: bool = True,
        min_texture: float = DEFAULT_MIN_TEXTURE,
        scale: float = 1.0,
        refine_subpixel: bool = False,
    ) -> None:
        if num_disparities < 16 or num_disparities % 16:
            raise ValueError(f"num_disparities must be a positive multiple of 16, got {num_disparities}")
        if block_size < 1 or block_size % 2 == 0:
            raise ValueError(f"block_size must be odd and >= 1, got {block_size}")
        if mode not in SGBM_MODES:
            raise ValueError(f"mode must be one of {sorted(SGBM_MODES)}, got {mode!r}")
        self.num_disparities = int(num_disparities)
        self.min_disparity = int(min_disparity)
        self.block_size = int(block_size)
        self.mode = mode
        if not 0 < scale <= 1:
            raise ValueError(f"scale must be in (0, 1], got {scale}")
        self.scale = float(scale)
        if not min_texture >= 0:
            raise ValueError(f"min_texture must be >= 0, got {min_texture}")
        self.min_texture = float(min_texture)
        self.refine_subpixel = bool(refine_subpixel)
        if self.refine_subpixel:  # load (or compile) its kernel now, not on the first pair
            pixels = np.zeros((1, 1), np.uint8)
            refine_disparity(pixels, pixels, np.zeros((1, 1), np.float32))
        self._sgbm = cv2.StereoSGBM_create(
            minDisparity=self.min_disparity,
            numDisparities=self.num_disparities,
            blockSize=self.block_size,
            P1=8 * self.block_size**2,
            P2=32 * self.block_size**2,
            disp12MaxDiff=int(disp12_max_diff),
            preFilterCap=int(pre_filter_cap),
            uniquenessRatio=int(uniqueness_ratio),
            speckleWindowSize=int(speckle_window_size),
            speckleRange=int(speckle_range),
            mode=SGBM_MODES[mode],
        )
        # SGBM leaves the first min_disparity + num_disparities columns invalid (and the last
        # -min_disparity ones when it is negative); padding moves that border off the image.
        self._pad_left = max(self.min_disparity + self.num_disparities, 0) if pad_border else 0
        self._pad_right = max(-self.min_disparity, 0) if pad_border else 0

    @classmethod
    def for_rig(
        cls,
        calib: RectifiedRig,
        min_depth: float = DEFAULT_MIN_DEPTH,
        max_depth: float = math.inf,
        **kwargs: Any,
    ) -> StereoMatcher:
        """A matcher whose disparity range covers depths [min_depth, max_depth] of ``calib``."""
        scale = float(kwargs.get("scale", 1.0))
        min_disp, num = disparity_range(calib, min_depth, max_depth, scale)
        return cls(num_disparities=num, min_disparity=min_disp, **kwargs)

    def disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """Float32 disparity (pixels) of a rectified pair, NaN where invalid; left is the reference.

        With ``scale`` < 1 the pair is matched at that scale (INTER_AREA) and the disparity is
        brought back to full size (nearest neighbour, values divided by ``scale``).
        """
        gl = to_gray(left, "left image")
        gr = to_gray(right, "right image")
        if gl.shape != gr.shape:
            raise ValueError(
                f"left image is {gl.shape[1]}x{gl.shape[0]}, right is {gr.shape[1]}x{gr.shape[0]}"
            )
        if self.scale == 1.0:
            return self._disparity(gl, gr)
        h, w = gl.shape
        size = (max(round(w * self.scale), 1), max(round(h * self.scale), 1))
        small = self._disparity(
            cv2.resize(gl, size, interpolation=cv2.INTER_AREA),
            cv2.resize(gr, size, interpolation=cv2.INTER_AREA),
        )
        small *= np.float32(w / size[0])
        return cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST)

    def _disparity(self, gl: np.ndarray, gr: np.ndarray) -> np.ndarray:
        h, w = gl.shape
        pl, pr = self._pad_left, self._pad_right
        if pl or pr:
            raw = self._sgbm.compute(
                cv2.copyMakeBorder(gl, 0, 0, pl, pr, cv2.BORDER_CONSTANT, value=0),
                cv2.copyMakeBorder(gr, 0, 0, pl, pr, cv2.BORDER_CONSTANT, value=0),
            )
        else:
            raw = self._sgbm.compute(gl, gr)
        texture = _NO_TEXTURE
        if self.min_texture > 0:
            texture = texture_variance(gl, self.block_size)
        # A match that lands in the padding is outside the right image: not a measurement.
        disp = valid_disparity(raw, pl, w, self.min_disparity, texture, np.float32(self.min_texture**2))
        if self.refine_subpixel:
            disp = refine_disparity(gl, gr, disp)
        return disp

    def depth(self, left: np.ndarray, right: np.ndarray, calib: RectifiedRig) -> np.ndarray:
        """Depth (m, NaN unknown) of a pair, rectifying it first when ``calib`` carries maps."""
        rectify = getattr(calib, "rectify", None)
        if rectify is not None:
            left, right = rectify(left, right)
        return depth_from_disparity(self.disparity(left, right), calib)


def texture_variance(gray: np.ndarray, window: int) -> np.ndarray:
    """Grey-level variance (grey levels squared, float32) over a ``window`` x ``window`` box.

    The texture filter compares it with ``min_texture**2``, so no square root is taken;
    OpenCV's box and squared-box filters read the uint8 image directly.
    """
    size = (window, window)
    mean = cv2.boxFilter(gray, cv2.CV_32F, size, borderType=cv2.BORDER_REFLECT)
    mean_sq = cv2.sqrBoxFilter(gray, cv2.CV_32F, size, borderType=cv2.BORDER_REFLECT)
    mean *= mean
    mean_sq -= mean
    return mean_sq


def depth_from_disparity(disp: np.ndarray, calib: RectifiedRig) -> np.ndarray:
    """Depth Z = fx * baseline / (disp + cx_right - cx) in metres (float32); NaN where unknown.

    Disparities that give a non-positive denominator (points at or beyond infinity) are NaN.
    """
    disp = np.ascontiguousarray(disp, dtype=np.float32)
    return depth_of_disparity(disp, float(calib.fx) * float(calib.baseline), _disparity_offset(calib))


def rotation_ypr(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """world_R_body = Rz(yaw) Ry(pitch) Rx(roll) (body x forward, y left, z up)."""
    return rotation_zyx(yaw, pitch, roll)


def points_from_depth(
    depth: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    pose_xyz: np.ndarray | tuple[float, float, float],
    pose_ypr: np.ndarray | tuple[float, float, float],
    max_range: float | None = None,
) -> np.ndarray:
    """World points (N, 3) float64 of the valid pixels of a depth image, in row-major pixel order.

    NaN, inf and non-positive depths are dropped, and so are points farther than
    ``max_range`` metres from the camera (ray length) when it is given. Use None to keep
    them, e.g. to let the fusion turn over-long rays into free space.
    """
    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth must be a 2-D image, got shape {depth.shape}")
    rot = rotation_ypr(*(float(angle) for angle in pose_ypr))
    origin = np.asarray(pose_xyz, dtype=np.float64)
    limit = np.inf if max_range is None else float(max_range) ** 2
    return _camera_points(depth, float(fx), float(fy), float(cx), float(cy), rot, origin, limit)


@numba.njit(cache=True, nogil=True)
def _camera_points(
    depth: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    rot: np.ndarray,
    origin: np.ndarray,
    max_range_sq: float,
) -> np.ndarray:
    h, w = depth.shape
    out = np.empty((h * w, 3))
    n = 0
    for v in range(h):
        b = -(v - cy) / fy
        for u in range(w):
            z = np.float64(depth[v, u])
            if not (z > 0.0 and z < np.inf):
                continue
            # Camera frame: z * (1, a, b); the squared ray length is z^2 (1 + a^2 + b^2).
            a = -(u - cx) / fx
            if z * z * (1.0 + a * a + b * b) > max_range_sq:
                continue
            for k in range(3):
                out[n, k] = z * (rot[k, 0] + rot[k, 1] * a + rot[k, 2] * b) + origin[k]
            n += 1
    return out[:n].copy()


def warm_up_kernels() -> tuple:
    """The compiled kernels :func:`warm_up` loads (a first run: compiles), for its progress lines."""
    return (_camera_points, valid_disparity, depth_of_disparity)


def warm_up() -> None:
    """Load (or compile, on a fresh install) the compiled stereo kernels before the first frame."""
    points_from_depth(np.ones((1, 1), np.float32), 1.0, 1.0, 0.0, 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    raw = np.zeros((1, 1), np.int16)
    depth_of_disparity(valid_disparity(raw, 0, 1, 0, _NO_TEXTURE, np.float32(0.0)), 1.0, 0.0)
