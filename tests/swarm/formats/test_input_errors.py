"""Non-finite numbers, '~' and the shared error type, wherever configs, plans and calibrations are read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.calibration import CalibrationError, load_calibration
from swarm.config import ConfigError, load_mission
from swarm.formats.errors import FloorPlanError, InputError, non_finite_numbers
from swarm.formats.floor_plan import load_floor_plan
from swarm.formats.map_file import MapFileError
from swarm.formats.point_cloud_file import PointCloudError

PLAN = {
    "walls": [{"points": [[0, 0], [4, 0], [4, 3], [0, 3]], "closed": True}],
    "boxes": [{"centre": [2.0, 1.5], "size": [0.6, 0.6], "height": 1.0}],
}


def mission(**changes) -> dict:
    data = {
        "workspace": {"lo": [0, 0, 0], "hi": [4, 3, 2], "voxel": 0.1},
        "floor_plan": "room.yaml",
        "robots": [{"id": "r1", "start": {"x": 1.0, "y": 1.0, "yaw": 0.0}}],
    }
    data.update(changes)
    return data


def write(path: Path, data) -> Path:
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


def test_every_input_error_shares_one_base():
    for kind in (ConfigError, FloorPlanError, PointCloudError, MapFileError, CalibrationError):
        assert issubclass(kind, InputError)


@pytest.mark.parametrize(
    "text, field",
    [
        ("workspace: {lo: [0, 0, 0], hi: [4, 3, .inf]}", "workspace.hi[2]"),
        ("workspace: {lo: [0, 0, 0], hi: [4, 3, 2], voxel: .nan}", "workspace.voxel"),
        ("sensor: {max_range: -.inf}", "sensor.max_range"),
        ("exploration: {my_role_setting: .nan}", "exploration.my_role_setting"),
        ("rigs: {wide: {hfov_deg: .nan}}", "rigs.wide.hfov_deg"),
        ("robots: [{id: r1, start: {x: 1, y: -nan}}]", "robots[0].start.y"),
        ("robots: [{id: r1, start: {x: 1, y: 1, yaw: inf}}]", "robots[0].start.yaw"),
    ],
)
def test_non_finite_mission_values_name_the_key(tmp_path, text, field):
    write(tmp_path / "room.yaml", PLAN)
    data = mission()
    data.update(yaml.safe_load(text))
    path = write(tmp_path / "m.yaml", data)
    with pytest.raises(ConfigError) as info:
        load_mission(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {field}: ") and "finite" in message, message


def test_non_finite_value_in_a_rig_file(tmp_path):
    write(tmp_path / "room.yaml", PLAN)
    write(tmp_path / "rig.yaml", "baseline: .nan\n")
    path = write(
        tmp_path / "m.yaml", mission(robots=[{"id": "r1", "start": {"x": 1, "y": 1}, "rig": "rig.yaml"}])
    )
    with pytest.raises(ConfigError) as info:
        load_mission(path)
    rig = tmp_path / "rig.yaml"
    assert (
        str(info.value)
        == f"{path}: robots[0].rig: rig file {rig}: baseline: must be a finite number (got nan)"
    )


@pytest.mark.parametrize(
    "plan, field",
    [
        ({"walls": [{"points": [[0, 0], [4, ".nan"]]}]}, "walls[0].points[1][1]"),
        ({"boxes": [{"centre": [1, 1], "size": [1, 1], "height": ".inf"}]}, "boxes[0].height"),
        ({"walls": [{"points": [[0, 0], [1, 1]], "thickness": "nan"}]}, "walls[0].thickness"),
        ({"bounds": [[0, 0], ["-inf", 3]]}, "bounds[1][0]"),
        ({"wall_height": "NaN"}, "wall_height"),
    ],
)
def test_non_finite_floor_plan_values_name_the_key(tmp_path, plan, field):
    text = yaml.safe_dump(plan).replace("'.nan'", ".nan").replace("'.inf'", ".inf")
    path = write(tmp_path / "plan.yaml", text)
    with pytest.raises(FloorPlanError) as info:
        load_floor_plan(path)
    assert str(info.value).startswith(f"{path}: {field}: "), str(info.value)
    assert "finite" in str(info.value)


def test_floor_plan_with_nan_map_is_refused_from_a_mission(tmp_path):
    """A mission's floor_plan map with a NaN origin is refused, not taken as a world without walls."""
    (tmp_path / "m.pgm").write_bytes(b"P5 3 3 255\n" + bytes(9))
    write(tmp_path / "map.yaml", "image: m.pgm\nresolution: 0.1\norigin: [0.0, 0.0, .nan]\n")
    path = write(tmp_path / "m.yaml", mission(floor_plan="map.yaml"))
    with pytest.raises(
        ConfigError, match=r"m.yaml: floor_plan: .*map.yaml: origin\[2\]: must be a finite number"
    ):
        load_mission(path)


def test_empty_and_inverted_floor_plans(tmp_path):
    with pytest.raises(FloorPlanError, match="the file is empty"):
        load_floor_plan(write(tmp_path / "empty.yaml", ""))
    with pytest.raises(FloorPlanError, match="bounds"):
        load_floor_plan(write(tmp_path / "inv.yaml", {"bounds": [[2, 2], [0, 0]]}))


def test_floor_plan_path_with_tilde(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    (tmp_path / "home").mkdir()
    write(tmp_path / "home" / "room.yaml", PLAN)
    path = write(tmp_path / "m.yaml", mission(floor_plan="~/room.yaml"))
    loaded = load_mission(path)
    assert loaded.floor_plan_ref().path == str(tmp_path / "home" / "room.yaml")
    assert loaded.load_floor_plan().count == 5


@pytest.mark.parametrize(
    "text, field",
    [
        ("fx: .nan\nfy: 100\ncx: 50\ncy: 40\nbaseline: 0.1\n", "fx"),
        ("fx: 100\nfy: 100\ncx: 50\ncy: 40\nbaseline: .inf\n", "baseline"),
        ("fx: 100\nfy: 100\ncx: -nan\ncy: 40\nbaseline: 0.1\n", "cx"),
        (
            "K1: [[100, 0, 50], [0, 100, 40], [0, 0, 1]]\nK2: [[100, 0, 50], [0, 100, 40], [0, 0, 1]]\n"
            "D1: [0, 0, 0, 0, .nan]\nD2: []\nR: [0, 0, 0]\nT: [-0.1, 0, 0]\nimage_size: [100, 80]\n",
            "D1",
        ),
    ],
)
def test_non_finite_calibration_values_name_the_key(tmp_path, text, field):
    path = write(tmp_path / "cal.yaml", text)
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    assert str(info.value).startswith(f"{path}: {field}: "), str(info.value)


yaml_values = st.recursive(
    st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(), st.text(max_size=3), st.none()),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.dictionaries(st.text("abc", min_size=1, max_size=3), inner, max_size=4),
    ),
    max_leaves=20,
)


@given(yaml_values)
@settings(max_examples=60, deadline=None)
def test_non_finite_numbers_finds_exactly_the_non_finite_floats(data):
    found = list(non_finite_numbers(data))

    def count(value) -> int:
        if isinstance(value, float):
            return int(not np.isfinite(value))
        if isinstance(value, dict):
            return sum(count(v) for v in value.values())
        if isinstance(value, list):
            return sum(count(v) for v in value)
        return 0

    assert len(found) == count(data)
    assert all(not np.isfinite(value) for _, value in found)
