"""Mission config: loading, validation messages naming file and field, missions from ROS maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from swarm.config import (
    ConfigError,
    RigConfig,
    load_mission,
    mission_from_dict,
    mission_from_map,
)
from swarm.map.sensor_model import SensorModel
from tests.support.paths import CONFIGS


def write_mission(tmp_path: Path, data: dict, name: str = "m.yaml") -> Path:
    plan = tmp_path / "room.yaml"
    plan.write_text(
        yaml.safe_dump(
            {
                "walls": [{"points": [[0, 0], [4, 0], [4, 3], [0, 3]], "closed": True}],
                "boxes": [{"centre": [2.0, 1.5], "size": [0.6, 0.6], "height": 1.0}],
            }
        )
    )
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def base(**changes) -> dict:
    data = {
        "mission": "test",
        "workspace": {"lo": [0, 0, 0], "hi": [4, 3, 2], "voxel": 0.1},
        "floor_plan": "room.yaml",
        "robots": [{"id": "r1", "start": {"x": 1.0, "y": 1.0, "yaw": 0.0}}],
    }
    data.update(changes)
    return data


@pytest.mark.parametrize("name", sorted(p.stem for p in CONFIGS.glob("*.yaml")))
def test_shipped_configs_load(name):
    mission = load_mission(CONFIGS / f"{name}.yaml")
    if mission.floor_plan is not None:  # a mission of real robots needs none (office_robots)
        assert mission.load_floor_plan().count > 0
    if mission.stop.observable_fraction is not None and mission.stop.entropy_threshold_bits is None:
        return  # the simulator resolves H_th (tests/sim2d/test_observability.py)
    assert mission.threshold_bits() > 0


def test_lab_replicates_the_paper_experiment():
    mission = load_mission(CONFIGS / "lab.yaml")
    grid = mission.workspace.grid()
    assert grid.shape == (40, 20, 20)
    assert grid.volume == pytest.approx(16.0)
    assert 7 * grid.size == pytest.approx(1.12e5)
    assert mission.threshold_bits() == 3e4
    assert mission.robot_ids == ["r1"]


def test_defaults_and_models(tmp_path):
    mission = load_mission(write_mission(tmp_path, base()))
    assert mission.sensor.model() == SensorModel(0.06, 0.0375, 2.0, 5.0)
    rig = mission.rig_for("r1")
    assert (rig.width, rig.height, rig.hfov_deg, rig.baseline) == (160, 120, 60, 0.09)
    cam = rig.camera()
    assert cam.fx == pytest.approx(80 / np.tan(np.radians(30)))
    assert (cam.cx, cam.cy) == (79.5, 59.5)
    assert mission.sharing.share_min_bits == 0.5
    assert (mission.sim.dt, mission.sim.frame_period_s) == (0.1, 0.5)
    # Without a threshold: 25% of 7 bits per voxel.
    assert mission.threshold_bits() == pytest.approx(0.25 * 7 * 40 * 30 * 20)


def test_information_model_by_camera_size_and_yaml_switches(tmp_path):
    """auto: weighted up to 100,000 pixels, discretize above; YAML's unquoted on/off are taken as meant."""
    mission = load_mission(write_mission(tmp_path, base()))
    models = {p: mission.sensor.model(pixels=p) for p in (160 * 120, 320 * 240, 640 * 480)}
    chosen = [(m.discretize, m.weighted) for m in models.values()]
    assert chosen == [(True, True), (True, True), (True, False)]
    assert not mission.sensor.model().discretize  # size unknown: one measurement per ray
    path = tmp_path / "switch.yaml"
    for text, expected in (("off", (False, False)), ("on", (True, False)), ("weighted", (True, True))):
        write_mission(tmp_path, base(), name="switch.yaml")
        path.write_text(path.read_text() + f"sensor: {{discretize: {text}}}\n")
        model = load_mission(path).sensor.model(pixels=160 * 120)
        assert (model.discretize, model.weighted) == expected, text
    path.write_text(path.read_text().replace("discretize: weighted", "discretize: sometimes"))
    with pytest.raises(ConfigError, match=r"switch.yaml: sensor.discretize: must be one of"):
        load_mission(path)


def test_hit_range_auto_from_the_rig_a_number_or_off(tmp_path):
    """auto: where the depth error reaches one voxel edge; the agent's sensor model carries it."""
    mission = load_mission(write_mission(tmp_path, base()))  # auto is the default
    assert mission.rig_for("r1").hit_range == "auto"
    rig = mission.rig_for("r1")
    fb = rig.fx * rig.baseline  # 12.47 px m
    auto = rig.hit_range_m(0.1)
    assert auto == pytest.approx(3.53, abs=0.01)
    assert auto**2 * 0.1 / fb == pytest.approx(0.1)  # sigma_Z = Z^2 sigma_d / (fx b): one voxel edge
    assert rig.hit_range_m(0.05) == pytest.approx(auto / np.sqrt(2))
    assert mission.sensor_model_for("r1").hit_range == pytest.approx(auto)
    assert mission.sensor_model_for("r1").reach == pytest.approx(auto)
    assert mission.sensor_model_for("r1") == mission.sensor.model()  # the map means the same
    depth = RigConfig(mode="range", range_noise=0.02, hit_range="auto")
    assert depth.hit_range_m(0.1) == pytest.approx(5.0)
    assert RigConfig(mode="range", range_noise=0.0, hit_range="auto").hit_range_m(0.1) is None
    path = tmp_path / "hit.yaml"
    for text, expected in (("off", None), ("null", None), ("2.5", 2.5), ("auto", auto)):
        write_mission(tmp_path, base(), name="hit.yaml")
        path.write_text(path.read_text() + f"rig: {{hit_range: {text}}}\n")
        assert load_mission(path).sensor_model_for("r1").hit_range == pytest.approx(expected), text
    for bad in ("-1", "0", "sometimes"):
        write_mission(tmp_path, base(), name="near.yaml")
        (tmp_path / "near.yaml").write_text(
            (tmp_path / "near.yaml").read_text() + f"rig: {{min_depth: {bad}}}\n"
        )
        with pytest.raises(ConfigError, match=r"near.yaml: rig\.min_depth"):
            load_mission(tmp_path / "near.yaml")
        write_mission(tmp_path, base(), name="hit.yaml")
        path.write_text(path.read_text() + f"rig: {{hit_range: {bad}, disparity_sigma_px: 0.2}}\n")
        with pytest.raises(ConfigError, match=r"hit.yaml: rig\.hit_range"):
            load_mission(path)
    write_mission(tmp_path, base(), name="hit.yaml")
    path.write_text(path.read_text() + "rig: {disparity_sigma_px: 0}\n")
    with pytest.raises(ConfigError, match=r"hit.yaml: rig\.disparity_sigma_px: must be > 0"):
        load_mission(path)


def test_negative_voxel_is_rejected_naming_file_and_field(tmp_path):
    path = write_mission(tmp_path, base(workspace={"lo": [0, 0, 0], "hi": [4, 3, 2], "voxel": -0.1}))
    with pytest.raises(ConfigError) as err:
        load_mission(path)
    assert str(err.value) == f"{path}: workspace.voxel: must be > 0 (got -0.1)"


def test_robot_inside_a_wall_is_rejected(tmp_path):
    robots = [
        {"id": "r1", "start": {"x": 1.0, "y": 1.0}},
        {"id": "r2", "start": {"x": 2.1, "y": 1.4}},  # inside the box
    ]
    path = write_mission(tmp_path, base(robots=robots))
    with pytest.raises(ConfigError, match=r"m\.yaml: robots\[1\]\.start: .*inside a wall/box"):
        load_mission(path)


def test_robot_touching_a_wall_is_rejected(tmp_path):
    robots = [{"id": "r1", "start": {"x": 0.15, "y": 1.0}}]  # wall face at 0.05, radius 0.18
    with pytest.raises(ConfigError, match=r"robots\[0\]\.start: .*closer than the robot radius"):
        load_mission(write_mission(tmp_path, base(robots=robots)))


def robot(x: float = 1.0, y: float = 1.0, **more) -> list[dict]:
    return [{"id": "r1", "start": {"x": x, "y": y}, **more}]


@pytest.mark.parametrize(
    "changes, expected",
    [
        ({"workspace": {"lo": [0, 0, 0], "hi": [4, 0, 2]}}, r"workspace: hi .* must be above lo"),
        ({"robots": []}, r"robots: list should have at least 1 item"),
        ({"robots": [{"id": "r 1", "start": {"x": 1, "y": 1}}]}, r"robots\[0\]\.id: string should match"),
        ({"robots": [{"id": "r1", "start": {"x": 1}}]}, r"robots\[0\]\.start\.y: is required"),
        ({"robots": [{"start": {"x": 1, "y": 1}}]}, r"robots\[0\]\.id: is required$"),
        ({"workspace": {"lo": [0, 0, 0]}}, r"workspace\.hi: is required$"),
        (
            {"robots": [{"id": "r1", "start": None}, {"id": "r2", "start": {}}]},
            r"robots\[1\]\.start\.x: is required\n.*robots\[1\]\.start\.y: is required$",
        ),
        ({"sensro": {}}, r"sensro: unknown field \(did you mean sensor\?\)"),
        ({"sensor": {"max_rnage": 4}}, r"sensor\.max_rnage: unknown field \(did you mean max_range\?\)"),
        ({"robots": [{"id": "r1", "strat": {"x": 1, "y": 1}}]}, r"robots\[0\]\.strat: .*mean start\?"),
        ({"robots": robot(rig={"basline": 0.1})}, r"robots\[0\]\.rig\.basline: .*did you mean baseline\?"),
        ({"xyz": 1}, r"xyz: unknown field$"),
        ({"rig": {"mode": "lidar"}}, r"rig\.mode: must be one of 'stereo' or 'range'"),
        ({"sim": {"dt": 0.5, "frame_period_s": 0.1}}, r"sim: frame_period_s \(0\.1\) must be >= dt"),
        ({"floor_plan": "missing.yaml"}, r"floor_plan: file not found: .*missing\.yaml"),
        ({"robots": robot(x=9)}, r"robots\[0\]\.start: .*outside the workspace"),
        ({"robots": robot(rig="wide")}, r"robots\[0\]\.rig: unknown rig 'wide'"),
        ({"robots": robot(rig={"hfov_deg": 0})}, r"robots\[0\]\.rig\.hfov_deg: must be > 0"),
    ],
)
def test_validation_messages_name_the_field(tmp_path, changes, expected):
    path = write_mission(tmp_path, base(**changes))
    with pytest.raises(ConfigError, match=expected) as err:
        load_mission(path)
    assert all(line.startswith(f"{path}: ") for line in str(err.value).splitlines())


def test_a_mission_without_workspace_names_file_and_field(tmp_path):
    data = base()
    del data["workspace"]
    path = write_mission(tmp_path, data)
    with pytest.raises(ConfigError, match=r"^\S*m\.yaml: workspace: is required$"):
        load_mission(path)


def test_robots_without_start_load_and_only_the_simulator_asks_for_it(tmp_path):
    """Real robots take their poses from their frames: ``start`` may be left out, for some
    robots or all; the starts given are still checked, and asking for a missing one (what the
    simulator does) names the file and each missing ``robots[i].start``."""
    robots = [{"id": "r1"}, {"id": "r2", "start": {"x": 1.0, "y": 1.0}}, {"id": "r3", "start": None}]
    path = write_mission(tmp_path, base(robots=robots))
    mission = load_mission(path)
    assert [r.start for r in mission.robots][::2] == [None, None]
    assert mission.start_of("r2").x == 1.0
    with pytest.raises(ConfigError, match=r"robots\[0\]\.start: is required by the simulator") as err:
        mission.start_of("r1")
    assert str(err.value).startswith(f"{path}: ") and "'r1'" in str(err.value)
    with pytest.raises(ConfigError) as err:
        mission.start_poses()
    assert str(err.value).startswith(
        f"{path}: robots[0].start, robots[2].start: are required by the simulator"
    )
    assert "'r1', 'r3'" in str(err.value) and "\n" not in str(err.value)
    again = mission_from_dict(yaml.safe_load(mission.to_yaml()), source=tmp_path / "copy.yaml")
    assert [r.start for r in again.robots] == [r.start for r in mission.robots]
    assert "start" not in yaml.safe_load(mission.to_yaml())["robots"][0]
    # a start given is checked as before, beside robots without one
    robots[1]["start"] = {"x": 2.1, "y": 1.4}  # inside the box
    with pytest.raises(ConfigError, match=r"robots\[1\]\.start: .*inside a wall/box"):
        load_mission(write_mission(tmp_path, base(robots=robots)))


def test_the_shipped_mission_of_real_robots_has_no_starts():
    mission = load_mission(CONFIGS / "office_robots.yaml")
    assert mission.robot_ids == ["r1", "r2", "r3"] and all(r.start is None for r in mission.robots)
    assert mission.floor_plan is None and mission.threshold_bits() == 6.2e5
    assert mission.ros2_for("r2").topic("left") == "/r2/left/image_raw"
    # docs/deployment.md shows this file
    page = (CONFIGS.parent / "docs" / "deployment.md").read_text()
    shown = page.split("## A mission of real robots")[1].split("```yaml\n")[1].split("```")[0]
    assert mission_from_dict(yaml.safe_load(shown)).model_dump() == mission.model_dump()


def test_duplicate_and_overlapping_robots(tmp_path):
    twins = [{"id": "r1", "start": {"x": 1, "y": 1}}, {"id": "r1", "start": {"x": 3, "y": 1}}]
    with pytest.raises(ConfigError, match=r"robots\[1\]\.id: duplicate robot id 'r1'"):
        load_mission(write_mission(tmp_path, base(robots=twins)))
    close = [{"id": "r1", "start": {"x": 1, "y": 1}}, {"id": "r2", "start": {"x": 1.2, "y": 1}}]
    with pytest.raises(ConfigError, match=r"robots\[1\]\.start: overlaps robot 'r1'"):
        load_mission(write_mission(tmp_path, base(robots=close)))


def test_rigs_inherit_from_the_default_rig(tmp_path):
    (tmp_path / "tof.yaml").write_text("mode: range\nrange_noise: 0.02\n")
    robots = [
        {"id": "a", "start": {"x": 1, "y": 1}},
        {"id": "b", "start": {"x": 1, "y": 2}, "rig": "wide"},
        {"id": "c", "start": {"x": 3, "y": 1}, "rig": {"width": 320}},
        {"id": "d", "start": {"x": 3, "y": 2.3}, "rig": "tof.yaml"},
    ]
    data = base(robots=robots, rig={"height": 100}, rigs={"wide": {"hfov_deg": 90}})
    mission = load_mission(write_mission(tmp_path, data))
    assert mission.rig_for("a") == RigConfig(height=100)
    assert mission.rig_for("b") == RigConfig(height=100, hfov_deg=90)
    assert mission.rig_for("c") == RigConfig(height=100, width=320)
    assert mission.rig_for("d") == RigConfig(height=100, mode="range", range_noise=0.02)


def test_yaml_round_trip(tmp_path):
    mission = load_mission(CONFIGS / "office.yaml")
    again = mission_from_dict(yaml.safe_load(mission.to_yaml()), source=tmp_path / "copy.yaml")
    assert again.model_dump() == {**mission.model_dump(), "floor_plan": again.model_dump()["floor_plan"]}
    assert again.load_floor_plan().count == mission.load_floor_plan().count


def test_yaml_round_trip_keeps_an_explicit_null_whose_default_is_not_null(tmp_path):
    # A run folder's config.yaml is what the mission's processes load: rig.hit_range: null
    # (no cut) must not come back as the default (auto), nor a set max_range as none.
    data = base(rig={"hit_range": None, "max_range": 4.0}, stop={"entropy_threshold_bits": None})
    mission = load_mission(write_mission(tmp_path, data))
    again = mission_from_dict(yaml.safe_load(mission.to_yaml()), source=tmp_path / "copy.yaml")
    assert mission.rig.hit_range is None
    assert again.rig.hit_range is None
    assert again.sensor_model_for("r1").hit_range is None
    assert again.rig.max_range == 4.0


def test_mission_from_ros_map_places_robots_in_free_space():
    mission = mission_from_map(CONFIGS / "maps" / "tb3_sandbox.yaml", robots=3)
    plan = mission.load_floor_plan()
    ros = plan.ros_map
    lo, hi = np.array(mission.workspace.lo), np.array(mission.workspace.hi)
    # Workspace: the known part of the map (the arena) grown to whole voxels from the world
    # origin, from the floor to 2 m + margin.
    known_rows, known_cols = np.nonzero(ros.occupied | ros.free)
    corners = np.array(
        [
            ros.to_world(known_cols.min(), known_rows.min()),
            ros.to_world(known_cols.max() + 1, known_rows.max() + 1),
        ]
    )
    voxel = mission.workspace.voxel
    known_lo, known_hi = corners.min(axis=0), corners.max(axis=0)
    assert np.all(lo[:2] <= known_lo + 1e-9) and np.all(lo[:2] > known_lo - voxel)
    assert np.all(hi[:2] >= known_hi - 1e-9) and np.all(hi[:2] < known_hi + voxel)
    assert np.allclose(lo[:2] / voxel, np.round(lo[:2] / voxel)) and np.allclose(
        hi[:2] / voxel, np.round(hi[:2] / voxel)
    )
    assert (lo[2], hi[2]) == (0.0, pytest.approx(2.2))
    starts = np.array([[r.start.x, r.start.y] for r in mission.robots])
    assert np.all(plan.clearance(starts) > mission.robot.radius)
    cells = ros.to_cell(starts)
    assert np.all(ros.free[cells[:, 0], cells[:, 1]])
    gaps = np.linalg.norm(starts[:, None] - starts[None], axis=-1)[np.triu_indices(3, 1)]
    assert np.all(gaps >= 1.0)
    assert mission.stop.entropy_threshold_bits is None
    assert mission.stop.observable_fraction == 0.16
    with pytest.raises(ConfigError, match="stop.observable_fraction"):
        mission.threshold_bits()  # only the simulator knows what can be observed


def test_mission_from_ros_map_starts_near_the_requested_point():
    mission = mission_from_map(CONFIGS / "maps" / "depot.yaml", robots=2, start=(5.0, 3.0))
    first = mission.robots[0].start
    assert np.hypot(first.x - 5.0, first.y - 3.0) < 0.5
    assert mission.workspace.hi[0] == pytest.approx(30.2)


def test_map_service_shards_and_cuts_are_checked_against_the_workspace(tmp_path):
    layout = load_mission(write_mission(tmp_path, base(map_service={"shards": 2}))).shard_layout()
    assert layout.bounds == (0, 20, 40)
    cut = load_mission(write_mission(tmp_path, base(map_service={"shards": 2, "cuts_x": [1.0]})))
    assert cut.shard_layout().bounds == (0, 10, 40)
    path = write_mission(tmp_path, base(map_service={"shards": 3, "cuts_x": [1.0]}))
    with pytest.raises(ConfigError, match=r"map_service.*3 shards need 2"):
        load_mission(path)
    path = write_mission(tmp_path, base(map_service={"shards": 2, "cuts_x": [7.5]}))
    with pytest.raises(ConfigError, match=rf"{path}: map_service.cuts_x: .*inside the workspace"):
        load_mission(path).shard_layout()
    path = write_mission(tmp_path, base(map_service={"shards": 50}))
    with pytest.raises(ConfigError, match=rf"{path}: map_service.shards: .*between 1 and the grid's nx=40"):
        load_mission(path).shard_layout()
