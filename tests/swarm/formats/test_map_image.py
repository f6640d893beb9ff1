"""Map images read as their formats define them, and ROS maps classified as map_server does."""

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.config import ConfigError, mission_from_map
from swarm.formats.errors import FloorPlanError, InputError
from swarm.formats.map_image import read_map_image
from swarm.formats.ros_map import load_ros_map


def pgm(samples: np.ndarray, maxval: int, comment: bytes = b"") -> bytes:
    """A binary PGM (P5) written from the Netpbm definition: 1 or 2 big-endian bytes per sample."""
    rows, cols = samples.shape
    header = b"P5\n" + comment + f"{cols} {rows}\n{maxval}\n".encode()
    body = samples.astype(np.uint8 if maxval < 256 else ">u2").tobytes()
    return header + body


def write_map(folder: Path, image_name: str, **keys) -> Path:
    spec = {"image": image_name, "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0,
            "occupied_thresh": 0.65, "free_thresh": 0.196, **keys}  # fmt: skip
    path = folder / "map.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def room(free: int, wall: int, size: int = 20) -> np.ndarray:
    """A square room: a one-cell wall border (value ``wall``) around floor cells (value ``free``)."""
    image = np.full((size, size), free, dtype=np.int64)
    image[0, :] = image[-1, :] = image[:, 0] = image[:, -1] = wall
    return image


@given(
    maxval=st.integers(1, 65535),
    data=st.data(),
)
@settings(max_examples=60, deadline=None)
def test_pgm_samples_scale_by_maxval(tmp_path_factory, maxval, data):
    rows, cols = data.draw(st.integers(1, 5)), data.draw(st.integers(1, 5))
    values = np.array(data.draw(st.lists(st.integers(0, maxval), min_size=rows * cols, max_size=rows * cols)))
    samples = values.reshape(rows, cols)
    path = tmp_path_factory.mktemp("pgm") / "m.pgm"
    path.write_bytes(pgm(samples, maxval, comment=b"# written by a test\n"))
    image = read_map_image(path)
    np.testing.assert_allclose(image.shade, samples / maxval, atol=1e-12)
    assert image.alpha is None


def test_ascii_and_binary_netpbm_agree(tmp_path):
    samples = np.array([[0, 50, 100], [100, 25, 75]])
    (tmp_path / "a.pgm").write_bytes(b"P2\n# comment\n3 2 # after the size\n100\n0 50 100\n100 25 75\n")
    (tmp_path / "b.pgm").write_bytes(pgm(samples, 100))
    colour = np.stack([samples] * 3, axis=-1)
    (tmp_path / "c.ppm").write_bytes(b"P6 3 2 100\n" + colour.astype(np.uint8).tobytes())
    (tmp_path / "d.ppm").write_bytes(b"P3 3 2 100\n" + " ".join(map(str, colour.ravel())).encode())
    for name in ("a.pgm", "b.pgm", "c.ppm", "d.ppm"):
        np.testing.assert_allclose(read_map_image(tmp_path / name).shade, samples / 100, err_msg=name)


def test_pbm_one_is_black(tmp_path):
    (tmp_path / "a.pbm").write_bytes(b"P1\n3 2\n100\n0 1 1\n")
    (tmp_path / "b.pbm").write_bytes(b"P4\n3 2\n" + bytes([0b10000000, 0b01100000]))
    want = np.array([[0, 1, 1], [1, 0, 0]], dtype=float)
    np.testing.assert_array_equal(read_map_image(tmp_path / "a.pbm").shade, want)
    np.testing.assert_array_equal(read_map_image(tmp_path / "b.pbm").shade, want)


def test_pam_with_alpha(tmp_path):
    header = b"P7\nWIDTH 2\nHEIGHT 1\nDEPTH 2\nMAXVAL 255\nTUPLTYPE GRAYSCALE_ALPHA\nENDHDR\n"
    (tmp_path / "m.pam").write_bytes(header + bytes([255, 0, 0, 255]))
    image = read_map_image(tmp_path / "m.pam")
    np.testing.assert_allclose(image.shade, [[1.0, 0.0]])
    np.testing.assert_allclose(image.alpha, [[0.0, 1.0]])


def test_sixteen_bit_png_and_alpha_png(tmp_path):
    grey16 = np.array([[0, 65535], [32768, 1000]], dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "g.png"), grey16)
    np.testing.assert_allclose(read_map_image(tmp_path / "g.png").shade, grey16 / 65535)
    bgra = np.zeros((1, 2, 4), np.uint8)
    bgra[0, 0] = [30, 60, 90, 255]
    bgra[0, 1] = [255, 255, 255, 0]
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    image = read_map_image(tmp_path / "a.png")
    np.testing.assert_allclose(image.shade, [[60 / 255, 1.0]])
    np.testing.assert_allclose(image.alpha, [[1.0, 0.0]])


@pytest.mark.parametrize(
    "content, words",
    [
        (b"P5\n4 4\n255\n" + bytes(10), ["truncated", "16", "10"]),
        (b"P5\n4 4\n", ["maxval"]),
        (b"P5\n4\n", ["height"]),
        (b"P5\n4 x\n255\n", ["height", "whole number"]),
        (b"P5\n4 4\n0\n" + bytes(16), ["maxval", "[1, 65535]"]),
        (b"P5\n2 1\n100\n" + bytes([0, 200]), ["200", "maxval 100"]),
        (b"P2\n2 2\n255\n1 2 3\n", ["4 samples", "holds 3", "truncated"]),
        (b"P2\n2 1\n255\n1 x\n", ["whole numbers"]),
        (b"P5\n0 4\n255\n", ["width", "[1,"]),
        (b"", ["empty"]),
        (b"\x89PNG\r\n\x1a\n broken", ["not a readable image"]),
    ],
)
def test_broken_images_name_the_cause(tmp_path, content, words):
    path = tmp_path / "m.pgm"
    path.write_bytes(content)
    with pytest.raises(FloorPlanError) as info:
        read_map_image(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message
    for word in words:
        assert word in message, message


def test_maxval_100_floor_is_free_as_map_server_reads_it(tmp_path):
    """Floor pixels 100 of maxval 100 are white, so free, not unknown."""
    (tmp_path / "site.pgm").write_bytes(pgm(room(free=100, wall=0), 100))
    ros_map = load_ros_map(write_map(tmp_path, "site.pgm"))
    assert ros_map.free.sum() == 18 * 18 and ros_map.occupied.sum() == 20 * 20 - 18 * 18
    mission = mission_from_map(tmp_path / "map.yaml")
    assert len(mission.robots) == 1


def test_sixteen_bit_pgm_map(tmp_path):
    (tmp_path / "site.pgm").write_bytes(pgm(room(free=1000, wall=0), 1000))
    ros_map = load_ros_map(write_map(tmp_path, "site.pgm"))
    assert ros_map.free.sum() == 18 * 18 and ros_map.occupied.sum() == 76


def classify_like_map_server(grey, alpha, mode, negate, occ_th, free_th):
    """Per-pixel oracle written from map_server's loader: returns 100 / 0 / -1 (or raw percent)."""
    channels = [grey] * 3 + ([alpha] if alpha is not None and mode == "trinary" else [])
    shade = sum(channels) / len(channels)
    if mode == "raw":
        percent = round(shade * 255)
        if percent > 100:
            return -1
        return 100 if percent > occ_th * 100 else 0 if percent < free_th * 100 else -1
    if mode == "scale" and alpha is not None and alpha < 1:
        return -1
    occ = shade if negate else 1 - shade
    return 100 if occ > occ_th else 0 if occ < free_th else -1


@given(
    grey=st.lists(st.integers(0, 255), min_size=12, max_size=12),
    alpha=st.one_of(st.none(), st.lists(st.sampled_from([0, 128, 255]), min_size=12, max_size=12)),
    mode=st.sampled_from(["trinary", "scale", "raw"]),
    negate=st.booleans(),
    thresholds=st.tuples(st.floats(0, 1), st.floats(0, 1)).map(sorted),
)
@settings(max_examples=60, deadline=None)
def test_classification_matches_the_map_server_oracle(
    tmp_path_factory, grey, alpha, mode, negate, thresholds
):
    folder = tmp_path_factory.mktemp("map")
    g = np.array(grey, np.uint8).reshape(3, 4)
    if alpha is None:
        cv2.imwrite(str(folder / "m.png"), g)
    else:
        a = np.array(alpha, np.uint8).reshape(3, 4)
        cv2.imwrite(str(folder / "m.png"), np.dstack([g, g, g, a]))
    free_th, occ_th = thresholds
    path = write_map(
        folder, "m.png", mode=mode, negate=int(negate), occupied_thresh=occ_th, free_thresh=free_th
    )
    ros_map = load_ros_map(path)
    saver = set(grey) <= {0, 205, 254} and 205 in grey and alpha is None and mode == "trinary" and not negate
    if saver and occ_th >= 1 - 205 / 255:  # map_saver's own image: 205 stays unknown (test below)
        free_th = min(free_th, 0.196)
    for r in range(3):
        for c in range(4):
            want = classify_like_map_server(
                g[r, c] / 255, None if alpha is None else a[r, c] / 255, mode, negate, occ_th, free_th
            )
            got = 100 if ros_map.occupied[2 - r, c] else 0 if ros_map.free[2 - r, c] else -1
            assert got == want, (r, c, g[r, c])


@pytest.mark.parametrize(
    "keys, field",
    [
        ({"origin": [0.0, 0.0, float("nan")]}, "origin[2]"),
        ({"origin": [0.0, 0.0, "-nan"]}, "origin[2]"),
        ({"origin": [float("inf"), 0.0, 0.0]}, "origin[0]"),
        ({"resolution": float("nan")}, "resolution"),
        ({"occupied_thresh": float("nan")}, "occupied_thresh"),
        ({"mode": "trinery"}, "mode"),
        ({"negate": 2}, "negate"),
        ({"origin": [0.0, 0.0]}, "origin"),
        ({"image": ""}, "image"),
    ],
)
def test_map_yaml_errors_name_the_key(tmp_path, keys, field):
    (tmp_path / "site.pgm").write_bytes(pgm(room(255, 0), 255))
    path = write_map(tmp_path, "site.pgm", **keys)
    with pytest.raises(FloorPlanError) as info:
        load_ros_map(path)
    assert str(info.value).startswith(f"{path}: {field}: "), str(info.value)
    with pytest.raises(InputError) as info:
        mission_from_map(path)
    assert f"{path}: {field}: " in str(info.value)
    assert "workspace" not in str(info.value) and "robots" not in str(info.value)


def test_map_saver_minus_nan_origin_in_a_mission_is_refused(tmp_path):
    """``origin: [0.0, 0.0, -nan]`` as a map saver writes it (not YAML's .nan)."""
    (tmp_path / "site.pgm").write_bytes(pgm(room(255, 0), 255))
    (tmp_path / "map.yaml").write_text(
        "image: site.pgm\nresolution: 0.1\norigin: [0.0, 0.0, -nan]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    mission = tmp_path / "mission.yaml"
    mission.write_text(
        yaml.safe_dump(
            {
                "workspace": {"lo": [0, 0, 0], "hi": [2, 2, 2]},
                "floor_plan": "map.yaml",
                "robots": [{"id": "r1", "start": {"x": 1, "y": 1}}],
            }
        )
    )
    from swarm.config import load_mission

    with pytest.raises(ConfigError) as info:
        load_mission(mission)
    message = str(info.value)
    assert f"{mission}: floor_plan: " in message and "map.yaml: origin[2]: must be a finite number" in message


def test_image_path_tilde_is_expanded(tmp_path, monkeypatch):
    """``image: ~/site.pgm`` names the user's home (map_server would not expand it)."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    (tmp_path / "home").mkdir()
    (tmp_path / "home" / "site.pgm").write_bytes(pgm(room(255, 0), 255))
    (tmp_path / "maps").mkdir()
    ros_map = load_ros_map(write_map(tmp_path / "maps", "~/site.pgm"))
    assert ros_map.free.sum() == 18 * 18


def test_missing_image_names_the_key_and_where_it_looked(tmp_path):
    path = write_map(tmp_path, "nowhere.pgm")
    with pytest.raises(FloorPlanError) as info:
        load_ros_map(path)
    assert str(info.value) == (
        f"{path}: image: file not found: {tmp_path / 'nowhere.pgm'} (taken from the map.yaml's folder)"
    )


def _netpbm_files(samples: np.ndarray) -> dict[str, tuple[bytes, bytes, np.ndarray]]:
    """Binary Netpbm files of one grey image (P5, P6, P7; P4 of its threshold) as (header,
    raster), and the shade each should give, per the Netpbm pages."""
    rows, cols = samples.shape
    bits = samples < 128  # P4: 1 is black
    grey = samples.astype(np.uint8).tobytes()
    rgb = np.repeat(samples[..., None], 3, axis=2).astype(np.uint8).tobytes()
    pam = f"P7\nWIDTH {cols}\nHEIGHT {rows}\nDEPTH 1\nMAXVAL 255\nTUPLTYPE GRAYSCALE\nENDHDR\n"
    return {
        "P5": (f"P5\n{cols} {rows}\n255\n".encode(), grey, samples / 255),
        "P6": (f"P6\n{cols} {rows}\n255\n".encode(), rgb, samples / 255),
        "P7": (pam.encode(), grey, samples / 255),
        "P4": (f"P4\n{cols} {rows}\n".encode(), np.packbits(bits, axis=1).tobytes(), (~bits).astype(float)),
    }


@pytest.mark.parametrize("magic", ["P4", "P5", "P6", "P7"])
def test_header_with_crlf_line_ends_reads_the_raster_after_the_lf(tmp_path, magic):
    """A header written in text mode on Windows ends its lines in CR LF (asfadmin/ASF_MapReady#95,
    DGtal-team/DGtal#1130): the raster starts after the LF, not one byte early."""
    samples = np.array([[0, 205, 254, 40], [254, 0, 205, 90]], dtype=np.int64)  # no byte 10 or 13
    header, raster, want = _netpbm_files(samples)[magic]
    path = tmp_path / "crlf.pnm"
    path.write_bytes(header + raster)
    np.testing.assert_allclose(read_map_image(path).shade, want)
    path.write_bytes(header.replace(b"\n", b"\r\n") + raster)
    np.testing.assert_allclose(read_map_image(path).shade, want)


def test_file_written_in_text_mode_is_refused_not_shifted(tmp_path):
    """Text mode turns every byte 10 of the raster into CR LF too (ssloy/tinyraycaster#9): the
    samples cannot be recovered, so the image is refused with the cause."""
    samples = np.array([[0, 10, 254], [254, 10, 205]], dtype=np.uint8)
    content = b"P5\n3 2\n255\n" + samples.tobytes()
    path = tmp_path / "text_mode.pgm"
    path.write_bytes(content.replace(b"\n", b"\r\n"))
    with pytest.raises(FloorPlanError, match="text mode") as info:
        read_map_image(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)
    # a raster that starts with byte 10 after a lone CR separator is a valid file, read as it is
    path.write_bytes(b"P5\n3 2\n255\r" + bytes([10, 0, 254, 254, 10, 205]))
    np.testing.assert_allclose(read_map_image(path).shade * 255, [[10, 0, 254], [254, 10, 205]])


@pytest.mark.parametrize("mode", ["Trinary", "SCALE", "Raw"])
def test_mode_is_read_in_any_case_as_nav2_does(tmp_path, mode):
    """Nav2's map_mode_from_string lowercases the mode: ``mode: Trinary`` is a trinary map."""
    (tmp_path / "site.pgm").write_bytes(pgm(room(254, 0), 255))
    want = load_ros_map(write_map(tmp_path, "site.pgm", mode=mode.lower()))
    got = load_ros_map(write_map(tmp_path, "site.pgm", mode=mode))
    assert np.array_equal(got.occupied, want.occupied) and np.array_equal(got.free, want.free)


def saver_image(size: int = 20) -> np.ndarray:
    """What map_saver writes: a room of free 254 with a wall of 0 inside unknown 205 all round."""
    image = np.full((size, size), 205, dtype=np.int64)
    image[2:-2, 2:-2] = room(254, 0, size - 4)
    return image


@pytest.mark.parametrize(("free_thresh", "occupied_thresh"), [(0.25, 0.65), (0.3, 0.9)])
def test_map_saver_trinary_image_keeps_its_unknown_when_free_thresh_reads_it_free(
    tmp_path, caplog, free_thresh, occupied_thresh
):
    """Nav2's map_saver wrote free_thresh 0.25 beside trinary images (0 wall, 205 unknown, 254
    free): read as written, every unknown cell (p = 0.196) was free, outside the building too
    (SteveMacenski/slam_toolbox#587; ros-navigation/navigation2#5278 made the saver write 0.196)."""
    image = saver_image()
    (tmp_path / "saved.pgm").write_bytes(pgm(image, 255))
    path = write_map(tmp_path, "saved.pgm", free_thresh=free_thresh, occupied_thresh=occupied_thresh)
    with caplog.at_level("WARNING", logger="swarm.formats.ros_map"):
        got = load_ros_map(path)
        load_ros_map(path)  # once per file
    flipped = image[::-1]
    assert np.array_equal(got.occupied, flipped == 0)
    assert np.array_equal(got.free, flipped == 254)
    (line,) = [r.getMessage() for r in caplog.records]
    assert "\n" not in line and str(path) in line and f"free_thresh: {free_thresh:g}" in line
    assert f"its {int((image == 205).sum()):,} cells are read as unknown" in line


def test_map_saver_image_with_its_own_thresholds_reads_the_same_without_a_warning(tmp_path, caplog):
    image = saver_image()
    (tmp_path / "saved.pgm").write_bytes(pgm(image, 255))
    with caplog.at_level("WARNING", logger="swarm.formats.ros_map"):
        got = load_ros_map(write_map(tmp_path, "saved.pgm", free_thresh=0.196))
    assert np.array_equal(got.free, image[::-1] == 254) and not caplog.records


def test_a_touched_up_map_saver_image_is_still_one(tmp_path):
    """A few pixels of other shades (an anti-aliased edit, up to 1% of the image) leave the image
    map_saver's: its 205 stays unknown; the other shades are read with the saver's free_thresh."""
    image = saver_image()  # 400 pixels: up to 4 others
    image[5, 5:9] = [180, 200, 230, 100]  # p = 0.294, 0.216, 0.098, 0.608
    (tmp_path / "edited.pgm").write_bytes(pgm(image, 255))
    got = load_ros_map(write_map(tmp_path, "edited.pgm", free_thresh=0.25))
    flipped = image[::-1]
    assert not got.free[flipped == 205].any()
    assert np.array_equal(got.free, (flipped == 254) | (flipped == 230))


@pytest.mark.parametrize(
    ("keys", "why"),
    [
        ({"free_thresh": 0.3}, "five other shades: a drawn image, not map_saver's"),
        ({"free_thresh": 0.3, "negate": 1}, "negate: dark is free, not map_saver's meaning"),
        ({"free_thresh": 0.3, "occupied_thresh": 0.1}, "205 reads occupied, not free"),
        ({"free_thresh": 0.3, "mode": "scale"}, "scale mode"),
    ],
)
def test_other_images_keep_the_file_s_thresholds(tmp_path, keys, why):
    image = saver_image()
    if "five" in why:
        image[5, 5:10] = [180, 200, 230, 100, 150]
    (tmp_path / "m.pgm").write_bytes(pgm(image, 255))
    got = load_ros_map(write_map(tmp_path, "m.pgm", **keys))
    flipped = image[::-1]
    p = flipped / 255 if keys.get("negate") else 1 - flipped / 255
    occupied = p > keys.get("occupied_thresh", 0.65)
    assert np.array_equal(got.occupied, occupied), why
    assert np.array_equal(got.free, ~occupied & (p < keys["free_thresh"])), why


def test_a_drawn_image_full_of_grey_205_read_free_is_warned_of(tmp_path, caplog):
    image = saver_image()
    image[5, 5:10] = [180, 200, 230, 100, 150]
    (tmp_path / "drawn.pgm").write_bytes(pgm(image, 255))
    path = write_map(tmp_path, "drawn.pgm", free_thresh=0.25)
    with caplog.at_level("WARNING", logger="swarm.formats.ros_map"):
        assert load_ros_map(path).free[image[::-1] == 205].all()
    (line,) = [r.getMessage() for r in caplog.records]
    assert str(path) in line and "free_thresh: 0.25" in line and "kept free" in line
