"""One map server per store: a second server on the same folder is refused naming the folder
and the holder's pid and host; the lock of a dead process (SIGKILL) does not block a restart;
a start that fails leaves no store behind, and a folder that is not a store is not touched."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from map_server.server import MapServer
from map_server.store import Store, StoreError
from swarm import cli
from tests.support.map_server_mission import (
    EPOCH,
    MISSION_YAML,
    encode_all,
    robot_batches,
    signed,
    small_mission,
)
from tests.support.store_identity import IDENTITY


def test_a_second_store_on_the_same_folder_is_refused_naming_the_holder(tmp_path: Path):
    first, _ = Store.open(tmp_path / "s", IDENTITY)
    with pytest.raises(StoreError) as refused:
        Store.open(tmp_path / "s", IDENTITY)
    text = str(refused.value)
    assert str(tmp_path / "s") in text and "in use by another map server" in text
    assert f"pid {os.getpid()} on host {socket.gethostname()}" in text
    first.append([b"still mine"])  # the refused open touched nothing of the holder's
    first.close()
    again, recovered = Store.open(tmp_path / "s", IDENTITY)  # closed: free again
    assert recovered.wal_payloads == [b"still mine"]
    again.close()


@pytest.mark.slow
def test_the_lock_of_a_killed_server_does_not_block_a_restart(tmp_path: Path):
    holder = (
        "import sys, time\n"
        "from map_server.store import Store\n"
        "from tests.support.store_identity import IDENTITY\n"
        f"store, _ = Store.open({str(tmp_path / 's')!r}, IDENTITY)\n"
        "store.append([b'acked'])\n"
        "print('held', flush=True)\n"
        "time.sleep(600)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", holder], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        with pytest.raises(StoreError, match=f"pid {proc.pid} on host"):
            Store.open(tmp_path / "s", IDENTITY)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    store, recovered = Store.open(tmp_path / "s", IDENTITY)  # store.lock is still there, unlocked
    assert recovered.wal_payloads == [b"acked"]
    store.close()


def test_a_start_that_fails_leaves_no_store_folder(tmp_path: Path, capsys):
    config = tmp_path / "mission.yaml"
    config.write_text(MISSION_YAML)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        args = ["server", "--config", str(config), "--listen", f"tcp/127.0.0.1:{port}"]
        assert cli.main([*args, "--store", str(tmp_path / "new")]) == 2
        (tmp_path / "empty").mkdir()
        assert cli.main([*args, "--store", str(tmp_path / "empty")]) == 2
    assert "swarm: error:" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    assert list((tmp_path / "empty").iterdir()) == []  # the user's folder stays, empty


def test_a_failed_start_keeps_a_store_that_holds_deltas(tmp_path: Path):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    sent = encode_all(grid, robot_batches(grid, sensor, robots=1, per_robot=2, rays=40, seed=3))
    server = MapServer(mission, tmp_path / "store")
    assert server.merge(signed(server, sent)) == 2
    server.store.discard_new()  # what a failed start does: this store holds acked deltas
    again = MapServer(mission, tmp_path / "store")
    assert again.team.acks() == {"r1": {EPOCH: 2}}
    again.store.close()


def test_a_folder_that_is_not_a_store_is_left_untouched(tmp_path: Path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "notes.txt").write_text("mine")
    with pytest.raises(StoreError, match="not a map store"):
        Store.open(tmp_path / "docs", IDENTITY)
    assert [p.name for p in (tmp_path / "docs").iterdir()] == ["notes.txt"]
