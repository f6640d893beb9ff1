"""The runners' children run the runner's own copy of swarm (swarm.child_command)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from swarm.child_command import OPENCV_THREADS, child_environment, started_by_runner_environment, swarm_argv
from tests.support.paths import ROOT


def test_a_child_started_in_another_copys_folder_runs_this_copy(tmp_path: Path) -> None:
    # as `swarm sim` of an installed copy started from the project folder: `python -m` would
    # import the swarm package of the working folder, not the runner's own
    cli = tmp_path / "swarm" / "cli"
    cli.mkdir(parents=True)
    (tmp_path / "swarm" / "__init__.py").write_text("")
    (cli / "__init__.py").write_text("")
    (cli / "__main__.py").write_text("print('the working folder copy')\nraise SystemExit(3)\n")
    out = subprocess.run(
        swarm_argv("map", "--help"),
        cwd=tmp_path,
        env=child_environment(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "usage: swarm map" in out.stdout


def test_a_checkout_puts_its_own_folder_first_on_the_childs_path() -> None:
    env = child_environment(PYTHONUNBUFFERED="1")
    assert env["PYTHONPATH"].split(os.pathsep)[0] == str(ROOT)
    assert env["PYTHONUNBUFFERED"] == "1"


def test_roles_a_runner_starts_get_one_opencv_thread_unless_the_user_set_it(monkeypatch):
    monkeypatch.delenv(OPENCV_THREADS, raising=False)
    assert started_by_runner_environment()[OPENCV_THREADS] == "1"
    monkeypatch.setenv(OPENCV_THREADS, "4")
    assert started_by_runner_environment()[OPENCV_THREADS] == "4"
    out = subprocess.run(
        [sys.executable, "-c", "import cv2; print(cv2.getNumThreads())"],
        env={**started_by_runner_environment(), OPENCV_THREADS: "1"},
        capture_output=True,
        text=True,
        check=True,
    )
    assert out.stdout.strip() == "1"  # OpenCV reads the variable: one thread, no pool workers
