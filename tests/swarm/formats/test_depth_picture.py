"""Depth pictures: one colour rule (near red, far blue, no return black), a
colour bar in metres, `stereo depth --out` never a NumPy file under a picture's name, and
`--help` text on every option of every command."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from swarm.cli.main import build_parser
from swarm.formats.depth_picture import BAR_WIDTH, depth_picture
from tests.support.stereo_scenes import cli, pair_files  # noqa: F401 (a fixture)


def test_near_is_red_far_is_blue_no_return_black_and_a_bar():
    depth = np.tile(np.linspace(0.5, 4.5, 200), (150, 1))
    depth[:10, :10] = np.nan
    depth[-10:, -10:] = 0.0
    picture = depth_picture(depth, 0.5, 4.5)
    factor = 2  # 150 rows are enlarged to 300 (>= 240)
    assert picture.shape == (300, 400 + BAR_WIDTH, 3)
    image = picture[:, :400].astype(int)
    b, _g, r = image[150, 4], image[150, 200], image[150, 396]
    near, far = image[150, 2], image[150, 390]
    assert near[2] > 150 and near[0] < 100, near  # BGR: red
    assert far[0] > 100 and far[2] < 100, far  # blue
    assert np.all(image[: 10 * factor, : 10 * factor] == 0) and np.all(
        image[-10 * factor :, -10 * factor :] == 0
    )
    assert b is not None and r is not None
    bar = picture[:, 400:].astype(int)
    strip = bar[18:-8, 12]
    assert (
        strip[0][2] > strip[0][0] + 80 and strip[-1][0] > strip[-1][2] + 20
    )  # the bar: near (red) on top, far (blue) below
    assert (bar[:, 27:] < 80).all(axis=2).sum() > 100  # its labels are written
    with pytest.raises(ValueError, match="near < far"):
        depth_picture(depth, 3.0, 3.0)


def test_stereo_depth_refuses_a_picture_name_for_the_npy(pair_files, capsys):  # noqa: F811
    d, _ = pair_files
    args = [str(d / "left.png"), str(d / "right.png"), "--calib", str(d / "calib.yaml")]
    assert cli([*args, "--out", str(d / "d.png")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "d.png" in err and ".npy" in err and "--png" in err
    assert not (d / "d.png").exists()
    assert cli([*args, "--out", str(d / "d.npy"), "--png", str(d / "d.jpg")]) == 2
    assert "--png" in capsys.readouterr().err and not (d / "d.npy").exists()


def test_every_option_of_every_command_explains_itself():
    missing = []

    def walk(parser: argparse.ArgumentParser, path: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, f"{path} {name}")
            elif not isinstance(action, argparse._HelpAction) and not action.help:
                missing.append(f"{path} {'/'.join(action.option_strings) or action.dest}")

    walk(build_parser(), "swarm")
    assert not missing, missing


def test_stereo_depth_options_out_of_range_are_named_one_per_line(pair_files, capsys):  # noqa: F811
    """--min-depth 0 was taken as the default; every bad option is named as the user wrote it."""
    d, _ = pair_files
    argv = [
        str(d / "left.png"),
        str(d / "right.png"),
        "--calib",
        str(d / "calib.yaml"),
        "--out",
        str(d / "o.npy"),
    ]
    rc = cli([*argv, "--min-depth", "0", "--block-size", "4", "--scale", "3"])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2 and err == [
        "swarm stereo depth: error: --min-depth 0: must be > 0 (metres)",
        "swarm stereo depth: error: --block-size 4: must be odd and >= 1 (pixels)",
        "swarm stereo depth: error: --scale 3: must be in (0, 1]",
    ]
    assert not (d / "o.npy").exists()


def test_the_stereo_summary_says_where_the_scene_is_beside_stray_far_matches():
    from robot_agent.stereo_command import depth_summary

    depth = np.full((100, 100), 2.0, np.float32)
    depth[:, 50:] = 3.0
    depth[0, 0] = 2191.0  # one stray match, as SGBM gives at a disparity near -doffs
    depth[1] = np.nan
    summary = depth_summary(depth)
    assert summary.startswith("100x100, 99% valid, depth 2.00-2191.00 m (median ")
    assert summary.endswith("96% of the valid pixels within 2.00-3.00 m)")


def test_the_colour_bar_spans_the_scene_not_a_few_stray_near_matches():
    from robot_agent.stereo_command import picture_range

    depth = np.tile(np.linspace(1.0, 3.0, 100, dtype=np.float32), (100, 1))
    depth[-1, :10] = 0.34  # ten stray matches at the nearest depth searched
    near, far = picture_range(depth, float("inf"))
    assert 1.0 <= near < 1.1 and 2.9 < far <= 3.0
    assert picture_range(depth, 2.5)[1] == 2.5  # --max-depth is the far end


def test_a_bar_end_that_also_stands_for_depths_beyond_it_says_so():
    """`swarm sim render --map` on the AWS small house: the console said "depth 0.93-9.27 m",
    and the bar ended at "5 m" (the sensor's range) while 40% of the picture, up to 9.27 m,
    took its colour. Such an end now reads ">=5 m" (and "<=near" at the near end)."""
    from swarm.formats.depth_picture import tick_labels

    assert tick_labels(0.0, 5.0) == ["0 m", "1.25 m", "2.5 m", "3.75 m", "5 m"]
    assert tick_labels(0.5, 5.0, nearer=True, farther=True)[::4] == ["<=0.5 m", ">=5 m"]
    within = np.tile(np.linspace(1.0, 4.0, 200), (150, 1))
    beyond = within.copy()
    beyond[:, -20:] = 9.27
    bars = [depth_picture(d, 0.0, 5.0)[:, -BAR_WIDTH:] for d in (within, beyond, within)]
    assert np.array_equal(bars[0], bars[2])
    assert not np.array_equal(bars[0], bars[1])  # the far label differs
    assert np.array_equal(bars[0][:-40], bars[1][:-40])  # and nothing above it
