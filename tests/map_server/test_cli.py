"""`swarm map stats|get|export` against a running map server, and `swarm server`'s errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from swarm import cli
from swarm.formats.map_file import load_map
from swarm.formats.point_cloud_file import read_point_cloud
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_table import default_table
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from tests.support.map_server_mission import (
    MISSION_YAML,
    all_acked,
    central_fusion,
    client_session,
    encode_all,
    publishers,
    robot_batches,
    running_server,
    small_mission,
    wait_until,
)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A server holding three robots' deltas, the central fusion of them, and the endpoint."""
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, per_robot=4, rays=300, seed=21)
    store = tmp_path_factory.mktemp("cli") / "store"
    with running_server(mission, store) as (_server, endpoint), client_session(endpoint) as session:
        pubs = publishers(session, mission.mission, batches)
        for rid, _seq, payload in encode_all(grid, batches):
            pubs[rid].put(payload)
        client = MapClient(session, mission.mission, endpoint=endpoint)
        wait_until(lambda: all_acked(client, dict.fromkeys(batches, 4)), 20, "every delta acked")
        yield endpoint, central_fusion(grid, sensor, batches)


def swarm(capsys, *args: str) -> tuple[int, str, str]:
    code = cli.main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_map_stats_prints_the_servers_json(served, capsys):
    endpoint, central = served
    code, out, err = swarm(capsys, "map", "stats", "--connect", endpoint, "--mission", "srvtest", "--json")
    assert code == 0, err
    stats = json.loads(out)
    assert stats["mission"] == "srvtest" and stats["deltas_applied"] == 12
    assert stats["voxels"] == central.grid.size and stats["voxel_size"] == pytest.approx(0.1)
    assert stats["known_fraction"] == pytest.approx(np.mean(central.known_mask()))
    exact = float(np.sum(default_table()(central.mean(), central.sigma()), dtype=np.float64))
    assert stats["entropy_bits"] == pytest.approx(exact, rel=1e-5)
    assert set(stats["robots"]) == {"r1", "r2", "r3"}


def test_map_get_point_and_box(served, capsys):
    endpoint, central = served
    grid = central.grid
    base = ("map", "get", "--connect", endpoint, "--mission", "srvtest")
    code, out, err = swarm(capsys, *base, "--point", "1.23,0.71,0.46", "--json")
    assert code == 0, err
    (row,) = json.loads(out)
    flat = int(grid.flat(np.array([12, 7, 4])))
    assert row["index"] == [12, 7, 4] and row["centre"] == pytest.approx([1.25, 0.75, 0.45])
    assert row["mu"] == pytest.approx(float(central.mean(flat)), rel=1e-5)
    assert row["sigma"] == pytest.approx(float(central.sigma(flat)), rel=1e-5)
    ec = float(expected_coverage(central.mean(flat), central.sigma(flat)))
    assert row["expected_coverage"] == pytest.approx(ec, abs=1e-5)
    code, out, err = swarm(capsys, *base, "--box", "0.5,0.5,0.2,0.8,0.7,0.4", "--json")
    rows = json.loads(out)
    assert code == 0 and len(rows) == 3 * 2 * 2
    idx = grid.flat(np.array([r["index"] for r in rows]))
    np.testing.assert_allclose([r["mu"] for r in rows], central.mean(idx), rtol=1e-5)
    h = default_table()(central.mean(idx), central.sigma(idx))
    np.testing.assert_allclose([r["entropy_bits"] for r in rows], h, atol=1e-3)
    code, out, _ = swarm(capsys, *base, "--box", "0.5,0.5,0.2,0.6,0.6,0.3")  # the table form
    assert code == 0 and len(out.strip().splitlines()) == 1 + 1 and "E[C]" in out
    code, _, err = swarm(capsys, *base, "--point", "9,9,9")  # an error, not exit 0
    assert code == 2 and err.count("\n") == 1 and "--point 9,9,9: outside the map's workspace" in err
    code, _, err = swarm(capsys, *base, "--point", "nan,1,1")
    assert code == 2 and "must be finite" in err
    code, _, err = swarm(capsys, *base, "--point", "1,2")
    assert code == 2 and "--point takes X,Y,Z" in err
    code, _, err = swarm(capsys, *base, "--box", "1,1,1,0,0,0")
    assert code == 2 and "map/region" in err and "must be >=" in err


def test_map_export_npz_and_ply(served, capsys, tmp_path: Path):
    endpoint, central = served
    base = ("map", "export", "--connect", endpoint, "--mission", "srvtest")
    code, out, err = swarm(capsys, *base, "--out", str(tmp_path / "map.npz"))
    assert code == 0, err
    cmap = load_map(tmp_path / "map.npz")
    assert cmap.grid == central.grid and cmap.sensor == central.sensor
    np.testing.assert_allclose(cmap.mean(), central.mean(), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(cmap.sigma(), central.sigma(), rtol=1e-5)
    for threshold in ("0.5", "0.3"):
        code, out, err = swarm(capsys, *base, "--out", str(tmp_path / "occ.ply"), "--threshold", threshold)
        assert code == 0, err
        points = read_point_cloud(tmp_path / "occ.ply")
        ec = expected_coverage(central.mean(), central.sigma())
        want = central.grid.centre(central.grid.unflat(np.flatnonzero(ec > float(threshold))))
        assert len(want) > 0 and f"{len(want):,} voxel centres" in out
        np.testing.assert_allclose(points, want, atol=1e-5)
    code, _, err = swarm(capsys, *base, "--out", str(tmp_path / "map.txt"))
    assert code == 2 and ".npz" in err


@pytest.mark.slow
def test_clear_error_when_nothing_answers(capsys):
    endpoint = bus.tcp_endpoint(bus.free_port())
    code, _, err = swarm(capsys, "map", "stats", "--connect", endpoint, "--timeout", "1")
    assert code == 2 and endpoint in err and "no map server" in err


def test_server_refuses_a_store_of_another_mission(tmp_path: Path, capsys):
    config = tmp_path / "m.yaml"
    config.write_text(MISSION_YAML)
    other = tmp_path / "other.yaml"
    other.write_text(MISSION_YAML.replace("hi: [3.0, 2.0, 1.0]", "hi: [3.0, 2.0, 2.0]"))
    endpoint = bus.tcp_endpoint(bus.free_port())
    with running_server(small_mission(), tmp_path / "store"):
        pass  # creates the store for the 3 x 2 x 1 m grid
    code, _, err = swarm(capsys, "server", "--config", str(other), "--store", str(tmp_path / "store"),
                         "--listen", endpoint)  # fmt: skip
    assert code == 2 and f"{tmp_path / 'store'}: this store was written for mission 'srvtest'" in err
    assert "shape [30, 20, 10]" in err and "shape [30, 20, 20]" in err


def test_map_tools_find_the_servers_mission_or_name_both(served, capsys, tmp_path: Path):
    """Without --mission the tools use the only mission that answers; a
    --mission or --config naming another mission is an error naming both."""
    endpoint, _central = served
    code, out, err = swarm(capsys, "map", "stats", "--connect", endpoint, "--json")
    assert code == 0, err
    assert json.loads(out)["mission"] == "srvtest"
    code, out, err = swarm(capsys, "map", "get", "--connect", endpoint, "--point", "1.23,0.71,0.46", "--json")
    assert code == 0 and json.loads(out)[0]["index"] == [12, 7, 4], err
    code, _, err = swarm(
        capsys, "map", "stats", "--connect", endpoint, "--mission", "office", "--timeout", "2"
    )
    assert code == 2 and err.count("\n") == 1, err
    assert "--mission names mission 'office'" in err and "serves mission 'srvtest'" in err
    config = tmp_path / "office.yaml"
    config.write_text(MISSION_YAML.replace("mission: srvtest", "mission: office"))
    code, _, err = swarm(capsys, "map", "export", "--connect", endpoint, "--config", str(config),
                         "--out", str(tmp_path / "m.npz"), "--timeout", "2")  # fmt: skip
    assert code == 2 and f"{config}: mission names mission 'office'" in err and "'srvtest'" in err
    config.write_text(MISSION_YAML)
    code, out, err = swarm(capsys, "map", "export", "--connect", endpoint, "--config", str(config),
                           "--out", str(tmp_path / "m.npz"))  # fmt: skip
    assert code == 0 and "wrote" in out, err


@pytest.mark.slow
def test_a_server_listening_on_its_zenoh_config_names_the_endpoints(tmp_path: Path):
    # docs/security.md's walk-through starts the server with only --zenoh-config: its log said
    # "listening on the endpoints of team/server/zenoh.json5", not which
    import subprocess
    import sys
    import time

    from swarm.security.team_setup import init_team

    port = bus.free_port()
    team = init_team("srvtest", ["r1"], tmp_path / "team", port=port)
    (tmp_path / "m.yaml").write_text(MISSION_YAML)
    log = tmp_path / "server.log"
    cmd = [sys.executable, "-m", "swarm.cli", "server", "--config", str(tmp_path / "m.yaml")]
    cmd += ["--store", str(tmp_path / "store"), "--zenoh-config", str(team.configs["server"])]
    with open(log, "w") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60
        while "listening on" not in log.read_text() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    line = next(x for x in log.read_text().splitlines() if "listening on" in x)
    assert f"listening on tls/0.0.0.0:{port} (from {team.configs['server']})" in line, line
