"""Every entry point turns a user's bad input into one ``error: FILE: FIELD: what`` line and exit 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from swarm.cli import main
from swarm.cli.common import endpoint_problem
from swarm.protocol import bus
from tests.support.paths import CONFIGS, TEST_DATA


@pytest.fixture
def site(tmp_path: Path) -> Path:
    """A good 100-maxval PGM room, map.yaml files (good, -nan origin, ~ image) and a mission."""
    room = np.full((60, 60), 100, np.uint8)
    room[0, :] = room[-1, :] = room[:, 0] = room[:, -1] = 0
    (tmp_path / "site.pgm").write_bytes(b"P5\n60 60\n100\n" + room.tobytes())
    keys = "resolution: 0.05\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    (tmp_path / "map.yaml").write_text("image: site.pgm\norigin: [0.0, 0.0, 0.0]\n" + keys)
    (tmp_path / "nan.yaml").write_text("image: site.pgm\norigin: [0.0, 0.0, -nan]\n" + keys)
    (tmp_path / "tilde.yaml").write_text("image: ~/no-such-site.pgm\norigin: [0, 0, 0]\n" + keys)
    (tmp_path / "mission.yaml").write_text(
        "workspace: {lo: [0, 0, 0], hi: [3, 3, 2]}\nfloor_plan: nan.yaml\n"
        "robots: [{id: r1, start: {x: 1.5, y: 1.5}}]\n"
    )
    return tmp_path


def run(capsys, *argv: str) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    return code, err


NAN_ORIGIN = "nan.yaml: origin[2]: must be a finite number"


@pytest.mark.parametrize(
    "argv",
    [
        ["sim", "render", "--map", "{d}/nan.yaml", "--out", "{d}/v"],
        ["sim", "render", "{d}/mission.yaml", "--out", "{d}/v"],
        ["sim", "--map", "{d}/nan.yaml", "--out", "{d}/r"],
        ["sim", "{d}/mission.yaml", "--out", "{d}/r"],
        ["sim", "world", "{d}/mission.yaml"],
        ["study", "{d}/mission.yaml", "--robots", "1", "--seeds", "0", "--out", "{d}/s"],
        ["study", "--map", "{d}/nan.yaml", "--robots", "1", "--seeds", "0", "--out", "{d}/s"],
        ["coordinator", "--config", "{d}/mission.yaml"],
        ["agent", "--id", "r1", "--config", "{d}/mission.yaml"],
        ["server", "--config", "{d}/mission.yaml", "--store", "{d}/store"],
    ],
)
def test_nan_origin_map_is_one_error_line_from_every_command(site, capsys, argv):
    code, err = run(capsys, *(a.format(d=site) for a in argv))
    assert code == 2 and err.count("\n") == 1 and "error: " in err, err
    assert NAN_ORIGIN in err and "workspace" not in err and "Traceback" not in err, err


NO_START = (
    "office_robots.yaml: robots[0].start, robots[1].start, robots[2].start: are required by the simulator"
)


@pytest.mark.parametrize(
    "argv",
    [
        ["sim", "{c}/office_robots.yaml", "--out", "{d}/r"],
        ["sim", "run", "{c}/office_robots.yaml", "--ros2", "--out", "{d}/r"],
        ["sim", "world", "{c}/office_robots.yaml"],
        ["sim", "world", "{c}/office_robots.yaml", "--ros2"],
        ["sim", "render", "{c}/office_robots.yaml", "--out", "{d}/v"],
        ["study", "{c}/office_robots.yaml", "--robots", "1", "--seeds", "0", "--out", "{d}/s"],
    ],
)
def test_the_simulator_refuses_robots_without_start_in_one_line(tmp_path, capsys, argv):
    """A mission of real robots leaves ``start`` out; every command that simulates it says which
    fields it needs, and writes nothing."""
    code, err = run(capsys, *(a.format(c=CONFIGS, d=tmp_path) for a in argv))
    assert code == 2 and err.count("\n") == 1 and NO_START in err and "Traceback" not in err, err
    assert "'r1', 'r2', 'r3'" in err and "docs/deployment.md" in err
    assert list(tmp_path.iterdir()) == []


def test_missing_image_behind_tilde_is_one_line(site, capsys):
    code, err = run(capsys, "sim", "render", "--map", site / "tilde.yaml", "--out", site / "v")
    assert code == 2 and err.count("\n") == 1
    assert f"{site / 'tilde.yaml'}: image: file not found: {Path.home() / 'no-such-site.pgm'}" in err


def test_maxval_100_map_renders(site, capsys):
    code = main(["sim", "render", "--map", str(site / "map.yaml"), "--out", str(site / "v")])
    assert code == 0 and (site / "v" / "depth.npy").exists()


@pytest.mark.parametrize(
    "argv, option",
    [
        (["server", "--config", "{c}/lab.yaml", "--store", "{d}/s", "--listen", "0.0.0.0:7464"], "--listen"),
        (["map", "stats", "--connect", "127.0.0.1:7461"], "--connect"),
        (["agent", "--id", "r1", "--config", "{c}/lab.yaml", "--connect", "127.0.0.1:7461"], "--connect"),
        (["coordinator", "--config", "{c}/lab.yaml", "--connect", "tcp/127.0.0.1"], "--connect"),
        (["sim", "world", "{c}/lab.yaml", "--listen", "tpc/127.0.0.1:7461"], "--listen"),
        (
            [
                "replay",
                "asl",
                "{c}/../tests/data/euroc_mini",
                "--out",
                "{d}/r",
                "--connect",
                "127.0.0.1:7461",
            ],
            "--connect",
        ),
    ],
)
def test_endpoints_without_protocol_are_refused_with_the_fix(tmp_path, capsys, argv, option):
    argv = [a.format(c=CONFIGS, d=tmp_path) for a in argv]
    code, err = run(capsys, *argv)
    endpoint = argv[argv.index(option) + 1]
    assert code == 2 and err.count("\n") == 1 and f"error: {option} {endpoint}: " in err, err


def test_a_single_endpoint_option_is_checked_whole() -> None:
    """`swarm replay --connect` takes one endpoint, not a list: it is checked as one string."""
    from swarm.cli.main import endpoint_problems

    assert endpoint_problems({"connect": "tcp/127.0.0.1:7461"}) == []
    assert endpoint_problems({"connect": ["tcp/127.0.0.1:7461", "127.0.0.1:7"]}) == [
        "--connect 127.0.0.1:7: an endpoint names its protocol: write tcp/127.0.0.1:7"
    ]


@pytest.mark.parametrize(
    "text, fine",
    [
        ("tcp/127.0.0.1:7447", True),
        ("tcp/0.0.0.0:0", True),
        ("tcp/[::1]:7447", True),
        ("udp/robot-3.local:7447", True),
        ("tcp/127.0.0.1:7447?iface=eth0", True),
        ("unixsock-stream//tmp/zenoh.sock", True),
        ("127.0.0.1:7447", False),
        ("tcp/127.0.0.1", False),
        ("tcp/127.0.0.1:70000", False),
        ("http/127.0.0.1:80", False),
        ("", False),
    ],
)
def test_endpoint_problem(text, fine):
    assert (endpoint_problem(text) is None) == fine
    if text == "127.0.0.1:7447":
        assert "tcp/127.0.0.1:7447" in endpoint_problem(text)


def test_busy_port_is_one_line_not_a_zenoh_traceback(tmp_path, capsys):
    endpoint = bus.tcp_endpoint(bus.free_port())
    holder = bus.open_session([endpoint])
    try:
        code, err = run(
            capsys,
            "server",
            "--config",
            CONFIGS / "lab.yaml",
            "--store",
            tmp_path / "s",
            "--listen",
            endpoint,
        )
    finally:
        holder.close()
    assert code == 2 and err.count("\n") == 1 and "Address already in use" in err and ".rs:" not in err, err


@pytest.mark.parametrize(
    "argv, option",
    [
        (["ingest", "{d}/c.xyz", "--out", "{d}/m.npz", "--origin", "nan", "0", "0"], "--origin"),
        (["ingest", "{d}/c.xyz", "--out", "{d}/m.npz", "--max-range", "inf"], "--max-range"),
        (["sim", "{c}/lab.yaml", "--max-time", "nan", "--out", "{d}/r"], "--max-time"),
        (["map", "export", "--out", "{d}/m.ply", "--threshold", "nan"], "--threshold"),
    ],
)
def test_non_finite_numbers_on_the_command_line(tmp_path, capsys, argv, option):
    (tmp_path / "c.xyz").write_text("1 2 3\n")
    code, err = run(capsys, *(a.format(c=CONFIGS, d=tmp_path) for a in argv))
    assert code == 2 and err.count("\n") == 1 and f"error: {option} " in err and "finite" in err, err


def test_an_infinite_default_stays_allowed():
    from swarm.cli.main import _infinite_defaults, build_parser

    assert "max_depth" in _infinite_defaults(build_parser())  # swarm stereo depth: inf = no limit


def test_an_out_folder_that_is_a_file_is_one_error_line(tmp_path, capsys) -> None:
    taken = tmp_path / "taken"
    taken.write_text("")
    euroc = TEST_DATA / "euroc_mini"
    code, err = run(capsys, "replay", "asl", str(euroc), "--out", str(taken))
    assert code == 2 and err.strip() == f"swarm: error: {taken}: File exists", err


def test_a_depth_image_given_as_a_map_is_refused_naming_it(tmp_path, capsys) -> None:
    np.save(tmp_path / "depth.npy", np.zeros((4, 4), np.float32))
    code, err = run(capsys, "map", "info", str(tmp_path / "depth.npy"))
    assert code == 2 and "depth.npy: a single array of shape (4, 4) (.npy), not a map file" in err, err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["bench", "entropy", "--voxels", "100"], "argument --voxels: must be at least 20,000 (got 100)"),
        (["bench", "octomap", "--repeat", "0"], "argument --repeat: must be at least 1 (got 0)"),
        (["bench", "entropy", "--repeat", "-1"], "argument --repeat: must be at least 1 (got -1)"),
    ],
)
def test_benchmark_options_out_of_range_are_refused_by_name(capsys, argv, message) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_bench_fusion_outside_the_project_folder_says_it_has_nothing_to_measure(
    tmp_path, capsys, monkeypatch
) -> None:
    # its default inputs are the bundled files, relative to the project folder: an empty table
    # and exit 0 told the user nothing
    monkeypatch.chdir(tmp_path)
    code, err = run(capsys, "bench", "fusion")
    assert code == 2
    assert err.startswith("swarm: error: nothing to measure: no data/octomap/scan.dat.bz2 and no ")
    assert "run from the project folder, or give --scan FILE and/or --euroc DIR" in err


def test_a_file_that_is_no_npz_is_refused_as_a_map(tmp_path, capsys) -> None:
    (tmp_path / "notes.txt").write_text("hello\n")
    code, err = run(capsys, "map", "info", str(tmp_path / "notes.txt"))
    assert (
        code == 2 and err.strip() == f"swarm: error: {tmp_path / 'notes.txt'}: not a NumPy .npz map file"
    ), err


@pytest.mark.parametrize(
    "options, message",
    [
        (["--mission", "of/fice", "--robots", "r1"], "--mission 'of/fice': only letters, digits, _ and -"),
        (["--mission", "office", "--robots", "r 1", "r2"], "--robots 'r 1': only letters, digits, _ and -"),
        (
            ["--mission", "office", "--robots", "r1", "--server-host", "bad host!!"],
            "--server-host 'bad host!!'",
        ),
    ],
)
def test_security_init_refuses_names_the_mission_would_refuse(tmp_path, capsys, options, message) -> None:
    code, err = run(capsys, "security", "init", *options, "--out", str(tmp_path / "team"))
    assert code == 2 and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "team").exists()


@pytest.mark.slow
def test_a_tls_endpoint_without_a_zenoh_config_says_what_it_needs(capsys, monkeypatch) -> None:
    # as a user copying the endpoint of `swarm sim --secure`'s line without its --zenoh-config
    monkeypatch.delenv("ZENOH_CONFIG", raising=False)
    port = bus.free_port()
    code, err = run(capsys, "map", "stats", "--connect", f"tls/127.0.0.1:{port}", "--timeout", "1")
    assert code == 2
    assert f"no map server reachable at tls/127.0.0.1:{port}" in err
    assert "a tls/ endpoint needs --zenoh-config with the mission's CA and a certificate" in err
