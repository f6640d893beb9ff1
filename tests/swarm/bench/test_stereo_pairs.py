"""The stereo-pairs benchmark: ground-truth readers, the depth-error measure, pair discovery, the table."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from robot_agent.stereo import StereoMatcher
from swarm.bench import stereo_pairs as bench
from tests.support.stereo_scenes import texture

W, H, D, DOFFS = 160, 120, 12, 5.0


def write_pfm(path, disp: np.ndarray) -> None:
    """Grey PFM as Middlebury writes it: little endian (negative scale), bottom row first."""
    h, w = disp.shape
    with open(path, "wb") as fh:
        fh.write(f"Pf\n{w} {h}\n-1.0\n".encode())
        np.flipud(disp).astype("<f4").tofile(fh)


def make_pair(folder, truth: np.ndarray | None = None) -> np.ndarray:
    """A fronto-parallel textured plane at disparity D (left(u) = right(u - D)), Middlebury layout."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    right = texture(rng)
    left = np.empty_like(right)
    left[:, D:] = right[:, :-D]
    left[:, :D] = texture(rng)[:, :D]  # seen by the left camera only
    cv2.imwrite(str(folder / "im0.png"), left)
    cv2.imwrite(str(folder / "im1.png"), right)
    if truth is None:
        truth = np.full((H, W), float(D), np.float32)
    write_pfm(folder / "disp0.pfm", truth)
    mask = np.full((H, W), 255, np.uint8)
    mask[:, :D] = 128
    cv2.imwrite(str(folder / "mask0nocc.png"), mask)
    cx = (W - 1) / 2
    (folder / "calib.txt").write_text(
        f"cam0=[500 0 {cx}; 0 500 60; 0 0 1]\ncam1=[500 0 {cx + DOFFS}; 0 500 60; 0 0 1]\n"
        f"doffs={DOFFS}\nbaseline=100\nwidth={W}\nheight={H}\nndisp=32\n"
    )
    return truth


@pytest.mark.parametrize("name", ["disp0.pfm", "disp0GT.pfm"])  # 2014 scenes, MiddEval3 training
def test_pfm_reads_top_row_first_and_inf_as_unknown(tmp_path, name) -> None:
    disp = np.arange(12, dtype=np.float32).reshape(3, 4)
    disp[0, 1] = np.inf
    write_pfm(tmp_path / name, disp)
    got = bench.read_disparity(tmp_path)
    assert np.isnan(got[0, 1])
    mask = np.isfinite(disp)
    np.testing.assert_array_equal(got[mask], disp[mask])


def test_a_folder_without_ground_truth_is_refused_naming_the_files(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="no disp0.pfm, disp0GT.pfm, disp0.tif or disp0.png"):
        bench.read_disparity(tmp_path)


def test_truncated_pfm_is_refused(tmp_path) -> None:
    (tmp_path / "disp0.pfm").write_bytes(b"Pf\n4 3\n-1.0\n" + b"\0" * 20)
    with pytest.raises(ValueError, match="truncated"):
        bench.read_disparity(tmp_path)


def test_score_matches_an_independent_depth_error(tmp_path) -> None:
    truth = np.full((H, W), float(D), np.float32)
    truth[:40] *= 1.2  # ground truth 20 % off in the top third: those depths are not within 5 %
    truth[40:50, 60:100] = np.inf  # unknown
    make_pair(tmp_path / "p", truth)
    pair = bench.load_pair(tmp_path / "p")
    got = bench.score(pair)

    # Oracle: the same matcher, then Z = f b / (d + doffs) by hand over the finite ground truth.
    fb = 500 * 0.1
    matcher = StereoMatcher.for_rig(pair.calib, fb / (32 + DOFFS))
    disp = matcher.disparity(pair.left, pair.right)
    known = np.isfinite(truth)
    valid = np.isfinite(disp) & known
    z_true = fb / (truth + DOFFS)
    z = fb / (disp + DOFFS)
    within = np.abs(z[valid] - z_true[valid]) < 0.05 * z_true[valid]
    assert got.valid == pytest.approx(valid.sum() / known.sum())
    assert got.within == pytest.approx(within.mean())
    visible = known.copy()
    visible[:, :D] = False
    assert got.valid_visible == pytest.approx(valid[visible].sum() / visible.sum())
    # The top third (20 % off) fails, most of the rest passes.
    assert 0.5 < got.within < 0.75


def test_default_matcher_on_an_exact_pair(tmp_path) -> None:
    make_pair(tmp_path / "p")
    got = bench.score(bench.load_pair(tmp_path / "p"))
    assert got.valid_visible > 0.9
    assert got.within > 0.99
    assert got.passes


def test_pair_folders_finds_pairs_and_names_an_empty_root(tmp_path) -> None:
    make_pair(tmp_path / "all" / "b")
    make_pair(tmp_path / "all" / "a")
    (tmp_path / "all" / "notes").mkdir()
    found = bench.pair_folders([tmp_path / "all" / "b"], [tmp_path / "all"])
    assert [p.name for p in found] == ["b", "a", "b"]
    with pytest.raises(FileNotFoundError, match="calib.txt"):
        bench.pair_folders([], [tmp_path / "all" / "notes"])


def test_main_prints_a_line_per_pair_the_mean_and_the_summary(tmp_path, capsys) -> None:
    make_pair(tmp_path / "all" / "a")
    make_pair(tmp_path / "all" / "b")
    bench.main(["--pairs", str(tmp_path / "all"), "--variants", "default,texture 0"])
    out = capsys.readouterr().out
    for label in ("default", "texture 0"):
        block = out.split(f"\n{label} (")[1]
        assert [line.split()[0] for line in block.splitlines()[2:5]] == ["a", "b", "mean"]
    summary = out.split("summary over 2 pairs")[1]
    assert "default" in summary and "2/2" in summary


def test_main_refuses_an_unknown_variant(capsys) -> None:
    with pytest.raises(SystemExit):
        bench.main(["--variants", "default,blocks 9"])
    assert "blocks 9" in capsys.readouterr().err
