"""``swarm stereo depth LEFT RIGHT --calib CALIB.yaml --out depth.npy [--png depth.png]``.

Computes a depth image (metres, float32, NaN where unknown, the size of the input) from a
stereo pair with OpenCV SGBM; a full calibration rectifies the pair first (the depth is
then in the rectified left camera). ``--png`` writes a colour-mapped view with a colour
bar in metres: near is red, far is blue, unknown is black.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from swarm.config.rig_defaults import DEFAULT_MIN_DEPTH, SGBM_MODE_NAMES

# OpenCV, the matcher and the calibration readers are imported where they are used: the
# arguments are built for `swarm stereo depth --help` too, which must stay fast.


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``stereo depth`` arguments to ``parser`` and set ``run`` as its handler."""
    parser.add_argument("left", type=Path, help="left (reference) image, PNG/JPEG/..., gray or colour")
    parser.add_argument("right", type=Path, help="right image, same size as the left")
    parser.add_argument(
        "--calib",
        "--calib-left",
        dest="calib",
        type=Path,
        required=True,
        help="stereo calibration: OpenCV/rig YAML, Middlebury calib.txt, Kalibr camchain.yaml, ZED SN*.conf, "
        "or the left camera's ROS camera_info / EuRoC sensor.yaml (docs/stereo.md)",
    )
    parser.add_argument(
        "--calib-right",
        type=Path,
        help="the second file of two-file forms: the right camera's (ROS camera_info, EuRoC sensor.yaml), "
        "or extrinsics.yml beside --calib intrinsics.yml (OpenCV's stereo_calib sample)",
    )
    parser.add_argument(
        "--calib-units",
        choices=("m", "cm", "mm"),
        help="the unit of the calibration's translation or baseline (T, T_BS, T_cn_cnm1, P[0][3], "
        "baseline), when it is not the form's own (metres; Middlebury's millimetres): a rig of a few "
        "centimetres written in centimetres cannot be told from one a few metres wide (docs/stereo.md)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        required=True,
        help="depth image to write: a NumPy .npy file of float32 metres, NaN = unknown "
        "(the name must end in .npy)",
    )
    parser.add_argument(
        "--png",
        type=Path,
        help="also write a picture of the depth (.png): near red, far blue, unknown black, with a colour bar "
        "in metres from the 2nd percentile of the depths found to --max-depth (or the 98th percentile); "
        "nearer and farther pixels take the end colours",
    )
    parser.add_argument(
        "--min-depth",
        type=float,
        default=None,
        help="nearest depth to search for, in metres; sets the disparity range (default: the "
        "calibration's ndisp when it states one, as Middlebury's calib.txt does, else "
        f"{DEFAULT_MIN_DEPTH:g}, the agent's default rig.min_depth)",
    )
    parser.add_argument(
        "--max-depth",
        type=float,
        default=float("inf"),
        help="farthest depth to search for, in metres (default: infinity); also the far end of the PNG scale",
    )
    parser.add_argument("--block-size", type=int, default=5, help="SGBM block size, odd (default 5)")
    parser.add_argument(
        "--mode",
        choices=sorted(SGBM_MODE_NAMES),
        default="3way",
        help="SGBM variant (default 3way: fastest, as good as hh on real images)",
    )
    parser.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help="match at this fraction of the image size (default 1: full size; 0.5: about 4-5x faster, "
        "fewer edge pixels right)",
    )
    parser.add_argument(
        "--refine-subpixel",
        action="store_true",
        help="refine SGBM's sub-pixel disparity with one Lucas-Kanade step on the images (halves the "
        "sub-pixel error on textured surfaces; a few ms at 640x480; see docs/stereo.md)",
    )
    parser.set_defaults(run=run)


def _fail(message: str) -> int:
    for line in str(message).splitlines() or [""]:  # one prefixed line per problem
        print(f"swarm stereo depth: error: {line}", file=sys.stderr)
    return 2


def _read_image(path: Path, role: str) -> np.ndarray:
    import cv2

    if not path.exists():
        raise FileNotFoundError(f"{role} image {path}: no such file")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{role} image {path}: not a readable image")
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{role} image {path}: unsupported pixel type {image.dtype}")
    return image


def _pair_to_8_bits(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray, str | None]:
    """A 16-bit pair as 8 bits, both by one scale: a 10- or 12-bit camera's images saved as 16-bit
    PNG hold 0..1023 or 0..4095, whose top 8 bits would be near black, so the bits the brighter
    image's peak needs are kept (``swarm.formats.pixel_bits``); with a note saying how many. 8-bit
    images pass unchanged."""
    from swarm.formats.pixel_bits import SignificantBits, to_8_bits

    bits = SignificantBits({"pair": 2}, samples=2)
    for image in (left, right):
        bits.add(image)
    if bits.bits is None:
        return left, right, None
    scaled = (to_8_bits(image, bits.bits) for image in (left, right))
    return *scaled, f"16-bit images: {bits.bits} significant bits (brightest value {bits.peak})"


def run(args: argparse.Namespace) -> int:
    """Run ``swarm stereo depth``; returns the exit status (0 ok, 2 on a user error)."""
    import cv2

    from robot_agent.stereo import StereoMatcher
    from swarm.formats.calibration_formats import load_stereo_calibration
    from swarm.formats.depth_picture import depth_picture
    from swarm.formats.stereo_calibration import CalibrationError

    if args.out.suffix.lower() != ".npy":
        return _fail(
            f"--out {args.out}: the depth is written as a NumPy .npy file (float32 metres); name it "
            f"{args.out.with_suffix('.npy').name}, and use --png for a picture"
        )
    if args.png is not None and args.png.suffix.lower() != ".png":
        return _fail(f"--png {args.png}: the picture is a PNG; name it {args.png.with_suffix('.png').name}")
    option_problems = []
    if args.min_depth is not None and not args.min_depth > 0:
        option_problems.append(f"--min-depth {args.min_depth:g}: must be > 0 (metres)")
    if not args.max_depth > (args.min_depth or 0.0):
        option_problems.append(f"--max-depth {args.max_depth:g}: must be beyond --min-depth (metres)")
    if not (args.block_size >= 1 and args.block_size % 2 == 1):
        option_problems.append(f"--block-size {args.block_size}: must be odd and >= 1 (pixels)")
    if not 0 < args.scale <= 1:
        option_problems.append(f"--scale {args.scale:g}: must be in (0, 1]")
    if option_problems:
        return _fail("\n".join(option_problems))
    try:
        left, right, bits_note = _pair_to_8_bits(
            _read_image(args.left, "left"), _read_image(args.right, "right")
        )
        calib = load_stereo_calibration(
            args.calib, args.calib_right, image_size=left.shape[1::-1], units=args.calib_units
        )
    except (CalibrationError, FileNotFoundError, ValueError) as exc:
        return _fail(str(exc))
    if bits_note:
        print(f"note: {bits_note}")
    calib.print_notes()
    (hl, wl), (hr, wr) = left.shape[:2], right.shape[:2]
    if (hl, wl) != (hr, wr):
        return _fail(
            f"size mismatch: left image {args.left} is {wl}x{hl}, right image {args.right} is {wr}x{hr}"
        )
    try:
        calib.check_image_size(wl, hl, f"left image {args.left}")
        options = {
            "block_size": args.block_size,
            "mode": args.mode,
            "scale": args.scale,
            "refine_subpixel": args.refine_subpixel,
        }
        min_depth = args.min_depth
        if min_depth is None and calib.ndisp:
            # The file's disparity range: the nearest depth whose disparity is ndisp.
            min_depth = calib.fx * calib.baseline / (calib.ndisp + calib.disparity_offset)
        min_depth = DEFAULT_MIN_DEPTH if min_depth is None else min_depth
        matcher = StereoMatcher.for_rig(calib, min_depth, args.max_depth, **options)
        depth = matcher.depth(left, right, calib)
    except (CalibrationError, ValueError) as exc:
        return _fail(str(exc))
    if np.isfinite(args.max_depth):
        depth[depth > args.max_depth] = np.nan
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with open(args.out, "wb") as fh:  # np.save(path) would append .npy to other names
            np.save(fh, depth)
        if args.png is not None:
            args.png.parent.mkdir(parents=True, exist_ok=True)
            if not cv2.imwrite(str(args.png), depth_picture(depth, *picture_range(depth, args.max_depth))):
                return _fail(f"--png {args.png}: cannot write a PNG there")
    except OSError as exc:
        return _fail(f"cannot write output: {exc}")
    print(f"wrote {args.out} ({depth_summary(depth)})" + (f" and {args.png}" if args.png is not None else ""))
    return 0


def depth_summary(depth: np.ndarray) -> str:
    """``WxH, V% valid, depth A-B m (median M; 96% of the valid pixels within P2-P98 m)`` of a
    depth image (metres, NaN unknown). The nearest and farthest depths are often a few stray
    matches (on Middlebury's Adirondack 9 pixels beyond 10 m, the farthest 2,191 m, where the
    scene ends at 2.9 m); the 2nd-98th percentile range says where the scene is."""
    h, w = depth.shape[:2]
    valid = depth[np.isfinite(depth)]
    summary = f"{w}x{h}, {valid.size / max(depth.size, 1):.0%} valid"
    if valid.size:
        p2, median, p98 = np.percentile(valid, [2, 50, 98])
        summary += (
            f", depth {valid.min():.2f}-{valid.max():.2f} m "
            f"(median {median:.2f}; 96% of the valid pixels within {p2:.2f}-{p98:.2f} m)"
        )
    return summary


def picture_range(depth: np.ndarray, max_depth: float) -> tuple[float, float]:
    """The colour bar's range in metres: the 2nd percentile of the depths to --max-depth (else
    the 98th percentile). Not the nearest depth: a few stray matches at the matcher's nearest
    depth (0.34 m on a EuRoC pair whose nearest surface is the floor 1 m away) squeezed the
    scene into a third of the colours."""
    valid = depth[np.isfinite(depth) & (depth > 0)]
    if valid.size == 0:
        return 0.0, 1.0
    near = float(np.percentile(valid, 2))
    far = float(max_depth) if np.isfinite(max_depth) else float(np.percentile(valid, 98))
    return near, max(far, near + 1e-3)
