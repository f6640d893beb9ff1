"""`swarm sim render`: the files it writes, from a mission config or a bare ROS map."""

from __future__ import annotations

import argparse

import cv2
import numpy as np
import pytest

from sim2d.commands import add_render_arguments, run_render
from sim2d.render import Renderer, camera_pose
from swarm.config import RigConfig
from swarm.formats.depth_picture import BAR_WIDTH
from swarm.formats.floor_plan import load_floor_plan
from tests.support.paths import CONFIGS


def render(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    add_render_arguments(parser)
    return run_render(parser.parse_args(list(argv)))


@pytest.mark.slow
def test_render_a_mission(tmp_path, capsys):
    assert render(str(CONFIGS / "lab.yaml"), "--robot", "r1", "--out", str(tmp_path)) == 0
    left = cv2.imread(str(tmp_path / "left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(tmp_path / "right.png"), cv2.IMREAD_UNCHANGED)
    assert left.shape == right.shape == (120, 160) and left.dtype == np.uint8
    assert not np.array_equal(left, right)
    depth = np.load(tmp_path / "depth.npy")
    plan = load_floor_plan(CONFIGS / "plans" / "lab.yaml")
    truth = Renderer(plan, RigConfig().camera()).cast(camera_pose(0.6, 1.0, 0.0, 0.4)).depth
    np.testing.assert_allclose(depth, truth, rtol=1e-6)  # stereo mode: the true depth
    picture = cv2.imread(str(tmp_path / "depth.png"))
    assert picture.shape == (240, 2 * 160 + BAR_WIDTH, 3)  # the depth enlarged 2x, then the colour bar
    assert np.all(picture[:240:2, :320:2][np.isnan(depth)] == 0)  # no return: black
    assert picture[:, 320:].std() > 20  # the bar is drawn
    assert "r1" in capsys.readouterr().out


def test_render_a_ros_map_at_another_size(tmp_path):
    out = tmp_path / "view"
    args = ["--map", str(CONFIGS / "maps" / "tb3_sandbox.yaml"), "--out", str(out)]
    assert render(*args, "--width", "80", "--height", "60") == 0
    depth = np.load(out / "depth.npy")
    assert depth.shape == (60, 80) and np.isfinite(depth).mean() > 0.5


def test_render_errors(tmp_path, capsys):
    assert render(str(CONFIGS / "lab.yaml"), "--robot", "r9", "--out", str(tmp_path)) == 2
    assert "no robot 'r9'" in capsys.readouterr().err
    assert render("--out", str(tmp_path)) == 2
    bad = tmp_path / "bad.yaml"
    bad.write_text("workspace: {lo: [0, 0, 0], hi: [1, 1, 1], voxel: 0}\nrobots: []\n")
    assert render(str(bad), "--out", str(tmp_path)) == 2
    assert "workspace.voxel: must be > 0" in capsys.readouterr().err


def test_render_and_world_take_swarm_sims_default_mission(tmp_path, capsys, monkeypatch):
    # README: `swarm sim render [CONFIG | --map MAP.yaml]`, as `swarm sim` (configs/office.yaml)
    from swarm.cli import main

    monkeypatch.chdir(CONFIGS.parent)
    assert main(["sim", "render", "--out", str(tmp_path / "view")]) == 0
    assert (tmp_path / "view" / "depth.npy").is_file()
    monkeypatch.chdir(tmp_path)  # not the project folder: the error says so, as swarm sim's
    for command in (["sim", "render", "--out", str(tmp_path)], ["sim", "world"]):
        capsys.readouterr()
        assert main(command) == 2
        err = capsys.readouterr().err
        assert err.startswith("swarm: error: configs/office.yaml: no such mission file"), err
    assert main(["sim", "render", str(CONFIGS / "lab.yaml"), "--map", "m.yaml", "--out", str(tmp_path)]) == 2
    assert "not both" in capsys.readouterr().err
