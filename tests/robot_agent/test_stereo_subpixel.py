"""Sub-pixel refinement of SGBM's disparity (robot_agent.subpixel): the kernel against its numpy
oracle, and a textured plane at known fractional disparities, where it must beat SGBM."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from robot_agent.stereo import StereoMatcher
from robot_agent.subpixel import (
    DEFAULT_MAX_STEP,
    DEFAULT_MIN_GRADIENT_VAR,
    DEFAULT_MIN_SIGNIFICANCE,
    refine_disparity,
)
from tests.support.stereo_oracle import reference_refine_disparity
from tests.support.stereo_scenes import H, W, rig, synthetic_pair, texture


def slanted_plane(seed: int, noise: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(left, right, true disparity) of a textured plane whose disparity runs from 6 to 11 px,
    so that every fraction of a pixel occurs; left(u) = right(u - d(u)) plus camera noise."""
    rng = np.random.default_rng(seed)
    right = texture(rng)
    u, v = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    truth = (6.0 + 4.0 * u / W + 1.0 * v / H).astype(np.float32)
    left = cv2.remap(right, u - truth, v, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    left = np.clip(left + rng.normal(0.0, noise, left.shape), 0, 255).astype(np.uint8)
    return left, right, truth


@pytest.mark.parametrize("seed", [0, 1])
def test_refinement_beats_sgbm_on_known_fractional_disparities(seed: int) -> None:
    left, right, truth = slanted_plane(seed)
    sgbm = StereoMatcher(num_disparities=16).disparity(left, right)
    refined = StereoMatcher(num_disparities=16, refine_subpixel=True).disparity(left, right)
    np.testing.assert_array_equal(np.isnan(refined), np.isnan(sgbm))  # no pixel filled or dropped
    valid = np.isfinite(sgbm)
    valid[:, :12] = False  # the left border, seen by the left camera only
    assert valid.mean() > 0.8
    err_sgbm = np.abs(sgbm - truth)[valid]
    err_refined = np.abs(refined - truth)[valid]
    # SGBM's parabola locks towards whole pixels (median error about 0.08 px here); the image fit
    # must at least take a third off the median and the mean, and never move a pixel by max_step.
    assert np.median(err_refined) < 0.67 * np.median(err_sgbm)
    assert err_refined.mean() < 0.8 * err_sgbm.mean()
    assert np.nanmax(np.abs(refined - sgbm)) < DEFAULT_MAX_STEP


def test_refinement_keeps_depth_on_the_piecewise_planar_scene() -> None:
    """Planes with depth edges: the refined depth is no worse than SGBM's, and nothing is filled."""
    left, right, z = synthetic_pair(0)
    calib = rig()
    plain = StereoMatcher(num_disparities=48).depth(left, right, calib)
    refined = StereoMatcher(num_disparities=48, refine_subpixel=True).depth(left, right, calib)
    np.testing.assert_array_equal(np.isnan(refined), np.isnan(plain))
    valid = np.isfinite(plain)
    err_plain = np.abs(plain - z)[valid] / z[valid]
    err_refined = np.abs(refined - z)[valid] / z[valid]
    assert np.median(err_refined) <= np.median(err_plain)
    assert np.mean(err_refined < 0.05) >= np.mean(err_plain < 0.05) - 0.005


def test_kernel_equals_the_pixel_by_pixel_least_squares() -> None:
    rng = np.random.default_rng(5)
    left, right, truth = slanted_plane(2, noise=2.0)
    left, right = left[:30, :48].copy(), right[:30, :48].copy()
    disp = truth[:30, :48] + rng.uniform(-0.4, 0.4, (30, 48)).astype(np.float32)
    disp[rng.random(disp.shape) < 0.15] = np.nan
    disp[:3, :5] = 60.0  # matches outside the right image stay as they are
    for window, significance in ((5, DEFAULT_MIN_SIGNIFICANCE), (7, 0.0)):
        args = (window, DEFAULT_MAX_STEP, DEFAULT_MIN_GRADIENT_VAR, significance)
        ours = refine_disparity(left, right, disp, *args)
        oracle = reference_refine_disparity(left, right, disp, *args)
        np.testing.assert_allclose(ours, oracle, rtol=0, atol=1e-4)  # NaN where the oracle has NaN
        assert np.sum(ours != disp) > 0.2 * np.isfinite(disp).sum()  # the test reaches the step


def test_refinement_rejects_bad_input() -> None:
    image = np.zeros((8, 10), np.uint8)
    with pytest.raises(ValueError, match="one \\(H, W\\) shape"):
        refine_disparity(image, image, np.zeros((8, 9), np.float32))
    with pytest.raises(ValueError, match="window must be odd"):
        refine_disparity(image, image, np.zeros((8, 10), np.float32), window=4)
