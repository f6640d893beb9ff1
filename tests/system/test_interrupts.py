"""Ctrl-C of a running ``swarm sim``, as a terminal sends it: SIGINT to the whole foreground
process group (the runner and every role it started), with the runner's stdout a pipe whose
reader (``tee``) goes away with it. One Ctrl-C writes the run folder from the map server's map;
a second ends the command at once. Also the pieces: the children's signal convention, a stdout
whose reader has gone, and the study's refusal to resume an interrupted run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swarm.child_command import STOPPED_BY_RUNNER
from swarm.mission.study.grid import Cell
from swarm.mission.study.runner import _matches
from tests.support.endless_lab import endless_lab
from tests.support.paths import ROOT


def _start_mission(tmp_path: Path, until: str = "sim t=") -> tuple[subprocess.Popen, Path]:
    """``swarm sim`` of the endless lab in a session of its own (a terminal's foreground job),
    stdout a pipe; returns once it prints ``until`` (by default: once the world has simulated a
    little)."""
    out = tmp_path / "run"
    lab = endless_lab(tmp_path)
    sim = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "sim", str(lab), "--out", str(out), "--max-time", "100000"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        env={k: v for k, v in os.environ.items() if k != STOPPED_BY_RUNNER},
    )  # fmt: skip
    seen = []
    for line in sim.stdout:
        seen.append(line)
        if until in line and "sim t=    0.0" not in line:
            return sim, out
    raise AssertionError("the mission never ran: " + "".join(seen) + sim.stderr.read())


def _leftovers(out: Path) -> list[str]:
    """Live processes (not zombies) whose command line names the run folder."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            cmdline = (Path("/proc") / pid / "cmdline").read_bytes().decode(errors="replace")
            state = (Path("/proc") / pid / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if str(out) in cmdline and state != "Z":
            found.append(cmdline.replace("\0", " "))
    return found


@pytest.mark.slow
def test_one_ctrl_c_writes_the_run_folder_from_the_servers_map_behind_a_dead_pipe(tmp_path) -> None:
    sim, out = _start_mission(tmp_path)
    os.killpg(sim.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole group
    sim.stdout.close()  # and `tee` dies with it: every later line goes to a broken pipe
    start = time.monotonic()
    err = sim.stderr.read()
    sim.wait(timeout=120)
    took = time.monotonic() - start
    assert sim.returncode == 130, err
    assert took < 30, f"{took:.1f} s"  # it took 23-29 s, the last of them stuck, before
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["interrupted"] is True and metrics["stop_reason"] == "interrupted"
    assert metrics["sim_time_s"] > 0
    for name in ("map.npz", "top_view.png", "map_3d.png", "entropy.png", "server_map.npz"):
        assert (out / name).is_file(), name
    assert list((out / "slices").glob("band_*.png"))
    # the map the folder holds is the server's (map.npz is the server's map, not the replica's)
    import numpy as np

    from swarm.formats.map_file import load_map

    written, server = load_map(out / "map.npz"), load_map(out / "server_map.npz")
    assert np.array_equal(written.mean(), server.mean()) and written.known_mask().any()
    assert "from the map server to" in err
    assert "wrote metrics.json (stop_reason interrupted)" in err and str(out) in err, err
    assert "no map server answered" not in err, err
    assert "Traceback" not in err and "Traceback" not in (out / "world.log").read_text()
    time.sleep(0.5)
    assert _leftovers(out) == []


@pytest.mark.slow
def test_a_second_ctrl_c_ends_at_once(tmp_path) -> None:
    sim, out = _start_mission(tmp_path)
    os.killpg(sim.pid, signal.SIGINT)
    time.sleep(0.3)
    os.killpg(sim.pid, signal.SIGINT)
    start = time.monotonic()
    _, err = sim.communicate(timeout=60)
    assert time.monotonic() - start < 5.0
    assert sim.returncode == 130, err
    assert "SIGINT again: stopping at once" in err, err
    assert _leftovers(out) == []


@pytest.mark.slow
def test_a_ctrl_c_while_the_mission_starts_stops_every_role_and_writes_nothing(tmp_path) -> None:
    sim, out = _start_mission(tmp_path, until="runner: the map server is up")
    os.killpg(sim.pid, signal.SIGINT)  # the world and the agents start about now
    _, err = sim.communicate(timeout=60)
    assert sim.returncode == 130, err
    assert "before the first frame" in err and "has no metrics.json" in err, err
    assert "Traceback" not in err and not (out / "metrics.json").exists()
    time.sleep(0.5)
    assert _leftovers(out) == []


@pytest.mark.slow
def test_a_role_a_runner_started_ignores_the_terminals_ctrl_c_and_stops_on_sigterm(tmp_path) -> None:
    """The convention of swarm.child_command, in a real child: SIGINT (sent while it starts,
    too) changes nothing; SIGTERM stops it."""
    from swarm.mission.role_processes import start_role, stop_roles
    from swarm.protocol import bus

    lab, listen = ROOT / "configs" / "lab.yaml", bus.tcp_endpoint(bus.free_port())
    args = ["server", "--config", str(lab), "--store", str(tmp_path / "store"), "--listen", listen]
    child = start_role(args, tmp_path / "server.log")
    child.send_signal(signal.SIGINT)  # in its first milliseconds: blocked, then discarded
    deadline = time.monotonic() + 120
    while "listening on" not in (tmp_path / "server.log").read_text() and time.monotonic() < deadline:
        assert child.poll() is None, (tmp_path / "server.log").read_text()
        time.sleep(0.1)
    child.send_signal(signal.SIGINT)
    time.sleep(1.0)
    assert child.poll() is None, (tmp_path / "server.log").read_text()
    stop_roles([child], timeout=30)
    assert child.returncode == 0, (tmp_path / "server.log").read_text()


def test_a_stdout_whose_reader_has_gone_takes_every_line_without_an_error() -> None:
    code = (
        "import sys, time\n"
        "from swarm.mission.console import surviving_stdout\n"
        "with surviving_stdout() as out:\n"
        "    print('first', flush=True)\n"
        "    time.sleep(0.5)\n"  # the reader goes away meanwhile
        "    for n in range(2000):\n"
        "        print('line', n, flush=True)\n"
        "    print('lost' if out.lost else 'not lost', file=sys.stderr)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout.readline() == b"first\n"
    proc.stdout.close()
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err.decode()
    assert err.decode().strip() == "lost"  # no BrokenPipeError, at the prints or at exit


def test_the_study_does_not_resume_an_interrupted_run() -> None:
    cell = Cell(Path("configs/office.yaml"), "config", 4, "entropy", "coordinator", 0)
    finished = {"robots": ["r1", "r2", "r3", "r4"], "strategy": "entropy", "coordination": "coordinator",
                "seed": 0, "stop_reason": "threshold", "interrupted": False}  # fmt: skip
    assert _matches(cell, finished)
    assert not _matches(cell, {**finished, "stop_reason": "interrupted", "interrupted": True})


def test_a_first_interrupt_is_raised_held_or_deferred_and_a_second_exits_at_once() -> None:
    """The runner's signal rules, in a child process that signals itself."""
    code = (
        "import os, signal, sys\n"
        "from swarm.mission.interrupts import Interrupts\n"
        "def kill(): os.kill(os.getpid(), signal.SIGINT)\n"
        "def run(body):\n"
        "    with Interrupts(lambda: print('forced', flush=True), 'the test', '') as it:\n"
        "        try:\n"
        "            body(it)\n"
        "        except KeyboardInterrupt:\n"
        "            print('raised', it.count, flush=True)\n"
        "def held(it):\n"
        "    with it.held():\n"
        "        kill(); print('went on', it.count, flush=True)\n"
        "def deferred(it):\n"
        "    with it.deferred():\n"
        "        kill(); print('not yet', flush=True)\n"
        "    print('never')\n"
        "def twice(it):\n"
        "    with it.held():\n"
        "        kill(); kill(); print('never')\n"
        "run(lambda it: kill())\n"
        "run(held)\n"
        "run(deferred)\n"
        "run(twice)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 130, proc.stdout + proc.stderr
    assert proc.stdout.split("\n") == ["raised 1", "went on 1", "not yet", "raised 1", "forced", ""], (
        proc.stdout
    )
    assert "SIGINT again: stopping at once" in proc.stderr
