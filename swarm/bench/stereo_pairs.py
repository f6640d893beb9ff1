"""``python -m swarm.bench.stereo_pairs``: stereo quality on real pairs with ground truth, and time per pair.

Quality: for each ``--pair DIR`` (Middlebury layout: ``im0.png``, ``im1.png``, ``calib.txt`` and
the ground-truth disparity ``disp0.pfm``, or ``disp0.tif``/``disp0.png`` with 0 = unknown), the
valid fraction (pixels with finite ground truth that get a depth) and the share of valid
pixels within 5 % of the true depth, Z = f b / (d + doffs). The matcher is sized from the
file's ``ndisp``, as ``swarm stereo depth`` does.

Time: best of ``--repeat`` runs of disparity + depth for a real EuRoC pair, rectified, at
752x480 and resized to 640x480, for each SGBM mode and the default (3way), at scale 1 and 0.5.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from robot_agent.stereo import StereoMatcher
from swarm.formats.calibration_formats import load_middlebury, load_stereo_calibration


def read_disparity(folder: Path) -> np.ndarray:
    """Ground-truth disparity (float32, NaN unknown) of a Middlebury-style folder."""
    pfm = folder / "disp0.pfm"
    if pfm.is_file():
        with pfm.open("rb") as fh:
            kind = fh.readline().strip()
            w, h = (int(v) for v in fh.readline().split())
            scale = float(fh.readline())
            data = np.fromfile(fh, "<f4" if scale < 0 else ">f4", w * h).reshape(h, w)
        if kind != b"Pf":
            raise ValueError(f"{pfm}: only grey PFM (Pf) is read")
        disp = np.flipud(data).astype(np.float32)
        disp[~np.isfinite(disp)] = np.nan
        return disp
    for name in ("disp0.tif", "disp0.png"):
        if (folder / name).is_file():
            disp = cv2.imread(str(folder / name), cv2.IMREAD_UNCHANGED).astype(np.float32)
            disp[disp <= 0] = np.nan
            return disp
    raise FileNotFoundError(f"{folder}: no disp0.pfm, disp0.tif or disp0.png")


def quality(folder: Path, **options) -> tuple[float, float]:
    """(valid fraction, share within 5 %) of the default matcher on one pair."""
    calib = load_middlebury(folder / "calib.txt")
    left = cv2.imread(str(folder / "im0.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(folder / "im1.png"), cv2.IMREAD_GRAYSCALE)
    truth = read_disparity(folder)
    min_depth = calib.fx * calib.baseline / (calib.ndisp + calib.disparity_offset) if calib.ndisp else 0.3
    depth = StereoMatcher.for_rig(calib, min_depth, **options).depth(left, right, calib)
    known = np.isfinite(truth)
    z_true = calib.fx * calib.baseline / (truth[known] + calib.disparity_offset)
    z = depth[known]
    valid = np.isfinite(z)
    within = np.abs(z[valid] / z_true[valid] - 1) < 0.05
    return float(valid.mean()), float(within.mean()) if valid.any() else 0.0


def best_ms(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best * 1e3


def timing(euroc: Path, repeat: int) -> list[tuple[str, str, float, float]]:
    calib = load_stereo_calibration(euroc / "mav0/cam0/sensor.yaml", euroc / "mav0/cam1/sensor.yaml")
    name = sorted((euroc / "mav0/cam0/data").glob("*.png"))[20].name
    raw_l = cv2.imread(str(euroc / "mav0/cam0/data" / name), cv2.IMREAD_GRAYSCALE)
    raw_r = cv2.imread(str(euroc / "mav0/cam1/data" / name), cv2.IMREAD_GRAYSCALE)
    left, right = calib.rectify(raw_l, raw_r)
    rows = []
    for mode in ("hh", "sgbm", "3way"):
        for scale in (1.0, 0.5):
            if mode == "hh" and scale == 0.5:
                continue
            for w, h in ((640, 480), (752, 480)):
                img_l, img_r = cv2.resize(left, (w, h)), cv2.resize(right, (w, h))
                sx = w / left.shape[1]
                rig = type("Rig", (), {"fx": calib.fx * sx, "cx": calib.cx * sx, "baseline": calib.baseline})
                m = StereoMatcher.for_rig(rig, 0.3, mode=mode, scale=scale)
                ms = best_ms(lambda m=m, a=img_l, b=img_r: m.disparity(a, b), repeat)
                valid = float(np.isfinite(m.disparity(img_l, img_r)).mean())
                rows.append((f"{w}x{h}", f"{mode} scale {scale:g} ({m.num_disparities} disp.)", ms, valid))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(
        prog="python -m swarm.bench.stereo_pairs", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--pair", type=Path, action="append", default=[], help="Middlebury-style pair folder")
    parser.add_argument(
        "--euroc", type=Path, help="EuRoC/ASL folder for the timing (e.g. the shared excerpt)"
    )
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads")
    for folder in args.pair:
        for label, opts in (("default (3way, scale 1)", {}), ("scale 0.5", {"scale": 0.5})):
            valid, within = quality(folder, **opts)
            print(f"{folder.name}: {label}: valid {valid:.3f}, within 5 % {within:.3f}")
    if args.euroc is not None:
        print(f"{'size':9s} {'matcher':32s} {'ms/pair':>8s} {'valid':>6s}")
        for size, label, ms, valid in timing(args.euroc, args.repeat):
            print(f"{size:9s} {label:32s} {ms:8.1f} {valid:6.3f}")


if __name__ == "__main__":
    main()
