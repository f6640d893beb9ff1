"""``python -m swarm.bench.stereo_pairs``: stereo quality on real pairs with ground truth, and time per pair.

Quality: for each pair folder (Middlebury layout: ``im0.png``, ``im1.png``, ``calib.txt`` and the
ground-truth disparity ``disp0.pfm`` (the 2014 scenes) or ``disp0GT.pfm`` (the MiddEval3 training
folders) with inf for unknown, or ``disp0.tif``/``disp0.png`` with 0 for unknown; optionally
``mask0nocc.png``, 255 where the pixel is seen by both cameras), the
valid fraction (pixels with ground truth that get a depth) and the share of valid pixels within
5 % of the true depth Z = f b / (d + doffs), for the default matcher and for variants that change
one setting each, and OpenCV's SGBM as the issue names it (5 paths, no padding, no texture
filter), side by side. The matcher is sized from the file's ``ndisp``, as ``swarm stereo depth``
does.

Time: best and median of ``--repeat`` runs of disparity + depth for a real EuRoC pair, rectified, at
752x480 and resized to 640x480, for each SGBM mode and the default (3way), at scale 1 and 0.5,
and the default with the sub-pixel refinement (``refine_subpixel``), with the disparity range from
``--min-depth`` (0.35 m, the agent's default ``rig.min_depth``).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from robot_agent.stereo import StereoMatcher, to_gray
from robot_agent.subpixel import refine_disparity
from swarm.bench import timed_seconds
from swarm.config.models import DEFAULT_MIN_DEPTH
from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.middlebury_calib import load_middlebury
from swarm.formats.stereo_calibration import StereoCalibration

#: The issue's quality target: valid fraction and share of valid pixels within 5 % of the true depth.
TARGET_VALID = 0.80
TARGET_WITHIN = 0.93
RELATIVE_DEPTH_TOLERANCE = 0.05

#: Matcher settings compared with the defaults, each changing one ``StereoMatcher`` argument.
VARIANTS: dict[str, dict] = {
    "default": {},
    "texture 0": {"min_texture": 0.0},
    "texture 1": {"min_texture": 1.0},
    "texture 4": {"min_texture": 4.0},
    "uniqueness 5": {"uniqueness_ratio": 5},
    "uniqueness 15": {"uniqueness_ratio": 15},
    "speckle 50": {"speckle_window_size": 50},
    "speckle 200": {"speckle_window_size": 200},
    "mode sgbm": {"mode": "sgbm"},
    "mode hh": {"mode": "hh"},
    "block 3": {"block_size": 3},
    "block 7": {"block_size": 7},
    "scale 0.5": {"scale": 0.5},
    "refine": {"refine_subpixel": True},
    # The peer: plain OpenCV SGBM with the settings of OpenCV's stereo_match sample (P1/P2 = 8/32 x
    # block^2, uniqueness 10, speckle filter, left-right check 1) at block 5, without our padding or
    # texture filter.
    "opencv sgbm": {"mode": "sgbm", "pad_border": False, "min_texture": 0.0},
}


def read_pfm(path: Path) -> np.ndarray:
    """A grey PFM image (Middlebury 2014 ``disp0.pfm``) as float32, top row first."""
    with path.open("rb") as fh:
        kind = fh.readline().strip()
        if kind != b"Pf":
            raise ValueError(f"{path}: only grey PFM (Pf) is read, got {kind!r}")
        w, h = (int(v) for v in fh.readline().split())
        scale = float(fh.readline())
        data = np.fromfile(fh, "<f4" if scale < 0 else ">f4", w * h)
    if data.size != w * h:
        raise ValueError(f"{path}: truncated, {data.size} of {w * h} values")
    return np.flipud(data.reshape(h, w)).astype(np.float32)


def read_disparity(folder: Path) -> np.ndarray:
    """Ground-truth disparity (float32 pixels, NaN unknown) of a Middlebury-style folder.

    Read from the first of ``disp0.pfm``, ``disp0GT.pfm`` (inf unknown), ``disp0.tif`` and
    ``disp0.png`` (0 unknown) that is there; FileNotFoundError when none is.
    """
    for name in ("disp0.pfm", "disp0GT.pfm"):
        if (folder / name).is_file():
            disp = read_pfm(folder / name)
            disp[~np.isfinite(disp)] = np.nan
            return disp
    for name in ("disp0.tif", "disp0.png"):
        if (folder / name).is_file():
            disp = cv2.imread(str(folder / name), cv2.IMREAD_UNCHANGED).astype(np.float32)
            disp[disp <= 0] = np.nan
            return disp
    raise FileNotFoundError(f"{folder}: no disp0.pfm, disp0GT.pfm, disp0.tif or disp0.png")


@dataclass(frozen=True)
class Pair:
    """A rectified pair with ground truth: gray images, calibration, disparity (NaN unknown)."""

    name: str
    calib: StereoCalibration
    left: np.ndarray
    right: np.ndarray
    truth: np.ndarray
    visible: np.ndarray | None  # True where seen by both cameras (mask0nocc.png == 255), if given


def load_pair(folder: Path) -> Pair:
    """Read a pair folder; FileNotFoundError or ValueError name the file at fault."""
    calib = load_middlebury(folder / "calib.txt")
    images = []
    for name in ("im0.png", "im1.png"):
        image = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise FileNotFoundError(f"{folder / name}: missing or not an image")
        images.append(image)
    truth = read_disparity(folder)
    if truth.shape != images[0].shape or images[1].shape != images[0].shape:
        raise ValueError(f"{folder}: im0, im1 and the ground truth differ in size")
    visible = None
    if (folder / "mask0nocc.png").is_file():
        visible = cv2.imread(str(folder / "mask0nocc.png"), cv2.IMREAD_GRAYSCALE) == 255
    return Pair(folder.name, calib, images[0], images[1], truth, visible)


@dataclass(frozen=True)
class Score:
    valid: float  # fraction of ground-truth pixels with a depth
    within: float  # share of those within 5 % of the true depth
    valid_visible: float  # valid fraction over ground-truth pixels seen by both cameras (NaN: no mask)
    ms: float  # disparity + depth, best of the repeats

    @property
    def passes(self) -> bool:
        return self.valid >= TARGET_VALID and self.within >= TARGET_WITHIN


def score(pair: Pair, repeat: int = 1, **options) -> Score:
    """Quality of ``StereoMatcher.for_rig(calib, min_depth, **options)`` on one pair.

    The range reaches the file's ``ndisp`` (else 0.3 m). Ground truth counts where it is finite
    and in front of the camera (d + doffs > 0); a depth is right when
    ``|Z - Z_true| / Z_true < 0.05`` with ``Z = f b / (d + doffs)``.
    """
    calib = pair.calib
    doffs = calib.disparity_offset
    fb = calib.fx * calib.baseline
    min_depth = fb / (calib.ndisp + doffs) if calib.ndisp else DEFAULT_MIN_DEPTH
    matcher = StereoMatcher.for_rig(calib, min_depth, **options)
    best, depth = np.inf, None
    for _ in range(max(repeat, 1)):
        start = time.perf_counter()
        depth = matcher.depth(pair.left, pair.right, calib)
        best = min(best, time.perf_counter() - start)
    with np.errstate(invalid="ignore"):
        known = np.isfinite(pair.truth) & (pair.truth + doffs > 0)
    z_true = fb / (pair.truth[known] + doffs)
    z = depth[known]
    valid = np.isfinite(z)
    within = np.abs(z[valid] - z_true[valid]) / z_true[valid] < RELATIVE_DEPTH_TOLERANCE
    valid_visible = np.nan
    if pair.visible is not None and pair.visible[known].any():
        valid_visible = float(valid[pair.visible[known]].mean())
    return Score(float(valid.mean()), float(within.mean()) if valid.any() else 0.0, valid_visible, best * 1e3)


def pair_folders(pairs: list[Path], pair_roots: list[Path]) -> list[Path]:
    """The ``--pair`` folders, then every subfolder holding a ``calib.txt`` of each ``--pairs`` root."""
    folders = list(pairs)
    for root in pair_roots:
        if not root.is_dir():
            raise FileNotFoundError(f"{root}: not a folder")
        found = sorted(p.parent for p in root.glob("*/calib.txt"))
        if not found:
            raise FileNotFoundError(f"{root}: no <pair>/calib.txt below it")
        folders += found
    return folders


def quality_tables(pairs: list[Pair], variants: list[str], repeat: int) -> dict[str, list[Score]]:
    """Print one block per variant (a line per pair and the mean), then a summary; return the scores."""
    scores: dict[str, list[Score]] = {}
    width = max(len(p.name) for p in pairs)
    for label in variants:
        print(f"\n{label} ({_describe(VARIANTS[label])})")
        print(f"  {'pair':{width}s}  {'valid':>6s} {'within5%':>8s} {'valid(vis)':>10s} {'ms':>7s}")
        rows = []
        for pair in pairs:
            s = score(pair, repeat, **VARIANTS[label])
            rows.append(s)
            mark = "" if s.passes else "  < target"
            line = f"{s.valid:6.3f} {s.within:8.3f} {s.valid_visible:10.3f} {s.ms:7.1f}"
            print(f"  {pair.name:{width}s}  {line}{mark}")
        mean = _mean(rows)
        print(f"  {'mean':{width}s}  {mean[0]:6.3f} {mean[1]:8.3f} {mean[2]:10.3f} {mean[3]:7.1f}")
        scores[label] = rows
    print(
        f"\nsummary over {len(pairs)} pairs (target: valid >= {TARGET_VALID:.2f} and within 5 % >= "
        f"{TARGET_WITHIN:.2f} on every pair)"
    )
    print(
        f"  {'variant':14s} {'mean valid':>10s} {'mean within':>11s} {'min valid':>9s} {'min within':>10s} "
        f"{'pass':>5s} {'ms':>7s}"
    )
    for label, rows in scores.items():
        mean = _mean(rows)
        n_pass = sum(s.passes for s in rows)
        print(
            f"  {label:14s} {mean[0]:10.3f} {mean[1]:11.3f} {min(s.valid for s in rows):9.3f} "
            f"{min(s.within for s in rows):10.3f} {n_pass:>2d}/{len(rows):<2d} {mean[3]:7.1f}"
        )
    return scores


def _mean(rows: list[Score]) -> tuple[float, float, float, float]:
    vis = [s.valid_visible for s in rows if np.isfinite(s.valid_visible)]
    return (
        float(np.mean([s.valid for s in rows])),
        float(np.mean([s.within for s in rows])),
        float(np.mean(vis)) if vis else float("nan"),
        float(np.mean([s.ms for s in rows])),
    )


def _describe(options: dict) -> str:
    if not options:
        return "3way, block 5, uniqueness 10, speckle 100/2, texture 0.5, scale 1"
    return ", ".join(f"{k}={v}" for k, v in options.items())


def timing(
    euroc: Path, repeat: int, min_depth: float = DEFAULT_MIN_DEPTH
) -> list[tuple[str, str, float, float, float]]:
    """Rows (size, matcher, best ms, median ms, valid) of disparity + depth on a rectified EuRoC pair."""
    calib = load_stereo_calibration(euroc / "mav0/cam0/sensor.yaml", euroc / "mav0/cam1/sensor.yaml")
    images = sorted((euroc / "mav0/cam0/data").glob("*.png"))
    if not images:
        raise FileNotFoundError(f"{euroc / 'mav0/cam0/data'}: no PNG images")
    name = images[min(20, len(images) - 1)].name  # the 21st pair of the 74-pair excerpt, else the last
    raw_l = cv2.imread(str(euroc / "mav0/cam0/data" / name), cv2.IMREAD_GRAYSCALE)
    raw_r = cv2.imread(str(euroc / "mav0/cam1/data" / name), cv2.IMREAD_GRAYSCALE)
    left, right = calib.rectify(raw_l, raw_r)
    rows = []
    settings = [(mode, scale, False) for mode in ("hh", "sgbm", "3way") for scale in (1.0, 0.5)]
    settings = [s for s in settings if s[:2] != ("hh", 0.5)] + [("3way", 1.0, True)]
    for mode, scale, refine in settings:
        for w, h in ((640, 480), (752, 480)):
            img_l, img_r = cv2.resize(left, (w, h)), cv2.resize(right, (w, h))
            sx = w / left.shape[1]
            rig = type("Rig", (), {"fx": calib.fx * sx, "cx": calib.cx * sx, "baseline": calib.baseline})
            m = StereoMatcher.for_rig(rig, min_depth, mode=mode, scale=scale, refine_subpixel=refine)
            best, median = timed_seconds(lambda m=m, a=img_l, b=img_r, c=rig: m.depth(a, b, c), repeat)
            valid = float(np.isfinite(m.disparity(img_l, img_r)).mean())
            label = f"{mode} scale {scale:g} ({m.num_disparities} disp.)" + (" refine" if refine else "")
            rows.append((f"{w}x{h}", label, best * 1e3, median * 1e3, valid))
            if refine:  # the refinement's own share, apart from SGBM's varying time, on SGBM's disparity
                m.refine_subpixel = False
                gl, gr, disp = to_gray(img_l), to_gray(img_r), m.disparity(img_l, img_r)
                best, median = timed_seconds(lambda a=gl, b=gr, d=disp: refine_disparity(a, b, d), repeat)
                rows.append((f"{w}x{h}", "  of which the refinement", best * 1e3, median * 1e3, valid))
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m swarm.bench.stereo_pairs",
        description=__doc__.split("\n\n")[0],
        epilog="Variants: " + "; ".join(f"'{k}' ({_describe(v)})" for k, v in VARIANTS.items()),
    )
    parser.add_argument(
        "--pair", type=Path, action="append", default=[], help="a Middlebury-style pair folder"
    )
    parser.add_argument(
        "--pairs", type=Path, action="append", default=[], help="a folder of pair folders (<pair>/calib.txt)"
    )
    parser.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help="comma-separated matcher variants to compare (default: all; 'default' alone for the defaults)",
    )
    parser.add_argument(
        "--quality-repeat", type=int, default=1, help="runs per pair and variant; the best time is printed"
    )
    parser.add_argument("--euroc", type=Path, help="EuRoC/ASL folder for the timing (the shared excerpt)")
    parser.add_argument(
        "--repeat", type=int, default=5, help="runs per timing row (the best and the median are printed)"
    )
    parser.add_argument(
        "--min-depth",
        type=float,
        default=DEFAULT_MIN_DEPTH,
        help="nearest depth (m) the timing's disparity range reaches (default "
        f"{DEFAULT_MIN_DEPTH:g}, the agent's default rig.min_depth)",
    )
    args = parser.parse_args(argv)
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        parser.error(f"--variants: unknown {unknown}; choose from {list(VARIANTS)}")
    try:
        pairs = [load_pair(folder) for folder in pair_folders(args.pair, args.pairs)]
    except (OSError, ValueError) as exc:
        parser.error(str(exc))
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads")
    if pairs:
        print(f"{len(pairs)} pairs: {', '.join(p.name for p in pairs)}")
        print("valid = share of ground-truth pixels with a depth; within5% = share of those within 5 % of")
        print("f b / (d + doffs); valid(vis) = valid share of the pixels seen by both cameras (mask0nocc)")
        quality_tables(pairs, variants, args.quality_repeat)
    if args.euroc is not None:
        print(f"\ndisparity + depth of a rectified EuRoC pair, nearest depth {args.min_depth:g} m")
        print(f"{'size':9s} {'matcher':32s} {'best ms':>8s} {'median':>8s} {'valid':>6s}")
        for size, label, best, median, valid in timing(args.euroc, args.repeat, args.min_depth):
            print(f"{size:9s} {label:32s} {best:8.1f} {median:8.1f} {valid:6.3f}")


if __name__ == "__main__":
    main()
