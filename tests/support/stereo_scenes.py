"""Synthetic stereo pairs with a known depth, their rig (FX, CX, CY, BASELINE), calibration files
and the CLI runner the stereo tests share."""

from __future__ import annotations

import argparse
import math

import cv2
import numpy as np
import pytest

from robot_agent.stereo_command import add_arguments, run
from swarm.formats.stereo_calibration import (
    StereoCalibration,
)

W, H = 160, 120


FX = 0.5 * W / math.tan(math.radians(30))  # 60 deg horizontal field of view


CX, CY = (W - 1) / 2, (H - 1) / 2


BASELINE = 0.09


def rig(**kw) -> StereoCalibration:
    args = dict(fx=FX, fy=FX, cx=CX, cy=CY, baseline=BASELINE)
    args.update(kw)
    return StereoCalibration(**args)


def texture(rng: np.random.Generator, h: int = H, w: int = W) -> np.ndarray:
    """Smoothed noise at several scales, uint8."""
    img = np.zeros((h, w))
    for s in (1, 2, 4, 8):
        n = rng.standard_normal((h // s + 3, w // s + 3))
        img += cv2.resize(n, ((w // s + 3) * s, (h // s + 3) * s), interpolation=cv2.INTER_CUBIC)[:h, :w]
    img = cv2.GaussianBlur(img, (0, 0), 1.2)
    img = (img - img.mean()) / img.std() * 40 + 128
    return np.clip(img, 0, 255).astype(np.uint8)


def scene_depth(h: int = H, w: int = W) -> np.ndarray:
    """Planes at 1-3 m: a wall at 2.8 m, a box face at 1.2 m, a slanted plane 1 -> 2 m on the left."""
    u = np.arange(w)[None, :].repeat(h, 0)
    z = np.full((h, w), 2.8)
    z[h // 4 : 3 * h // 4, 5 * w // 16 : 11 * w // 16] = 1.2
    slant = u < w // 4
    z[slant] = 1.0 + u[slant] / (w / 4)
    return z


def synthetic_pair(seed: int = 0, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(left, right, true depth): left(u, v) = right(u - d(u, v), v), d = fx b / Z - offset."""
    rng = np.random.default_rng(seed)
    right = texture(rng)
    z = scene_depth()
    d = (FX * BASELINE / z - offset).astype(np.float32)
    u, v = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    left = cv2.remap(right, u - d, v, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return left, right, z


def relative_error(depth: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    valid = np.isfinite(depth)
    return float(np.median(np.abs(depth[valid] - truth[valid]) / truth[valid])), float(valid.mean())


def write_yaml(path, text: str):
    path.write_text(text)
    return path


def cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return run(parser.parse_args(argv))


@pytest.fixture
def pair_files(tmp_path):
    left, right, truth = synthetic_pair(6)
    cv2.imwrite(str(tmp_path / "left.png"), left)
    cv2.imwrite(str(tmp_path / "right.png"), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR))
    write_yaml(tmp_path / "calib.yaml", f"fx: {FX}\nfy: {FX}\ncx: {CX}\ncy: {CY}\nbaseline: {BASELINE}\n")
    return tmp_path, truth
