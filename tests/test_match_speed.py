"""``cmal-lcd match`` stays fast (issue 14, item 2): SAD imports no torch, frames are decoded on
a thread pool with the library's exact result and errors, the full difference matrices are
never kept (the figure's every-k-th-frame matrices are computed exactly), and the time of every
step is printed and written to ``metrics.json`` (``benchmarks/bench_match.py`` measures it on
Nordland).
"""

import dataclasses
import json

import cv2
import numpy as np
import pytest

from cmal_lcd.commands import main
from cmal_lcd.data.frames import FrameReadError, read_frame_folder
from cmal_lcd.workflows.match_folders import MATCH_PARTS, TIMING_KEYS, match_parts
from cmal_lcd.reports.match_figures import figure_matrices
from cmal_lcd.matching import SeqSLAMParams, match_sequences
from subprocess_helpers import python_output
from test_cli import write_route


@pytest.fixture
def drives(tmp_path):
    return (write_route(tmp_path / "sunny", brightness=1.0, seed=1,
                        poses=[float(i) for i in range(40)]),
            write_route(tmp_path / "foggy", brightness=0.6, seed=2,
                        poses=[float(i) for i in range(40)]))


def test_sad_matching_imports_neither_torch_nor_hydra_nor_pandas(drives, tmp_path):
    """pandas costs 0.2 s of start-up; a folder without ``poses.csv`` never needs it, even when
    match draws its figures."""
    bare = [tmp_path / "bare_a", tmp_path / "bare_b"]
    for drive, folder in zip(drives, bare):
        folder.mkdir()
        for frame in drive.glob("*.png"):
            (folder / frame.name).write_bytes(frame.read_bytes())
    script = ("import sys\n"
              "from cmal_lcd.commands import main\n"
              f"assert main(['match', {str(bare[0])!r}, {str(bare[1])!r}, '--out', "
              f"{str(tmp_path / 'out')!r}]) == 0\n"
              "print(sorted(m for m in ('torch', 'torchvision', 'hydra', 'pandas') "
              "if m in sys.modules))\n")
    assert python_output(script).strip().splitlines()[-1] == "[]"


def test_quantised_sad_is_switched_on_by_its_flag_and_recorded(drives, tmp_path):
    for name, flags, metric in (("float", [], "sad"), ("bytes", ["--quantise-sad"], "sad_u8")):
        assert main(["match", *map(str, drives), "--out", str(tmp_path / name), "--no-figures",
                     *flags]) == 0
        params = json.loads((tmp_path / name / "metrics.json").read_text())["params"]
        assert params["metric"] == metric
        assert params["sad"]["quantise"] is (metric == "sad_u8")


def test_quantised_sad_is_refused_with_codes(drives, tmp_path, capsys):
    assert main(["match", *map(str, drives), "--features", "dnn", "--quantise-sad",
                 "--out", str(tmp_path / "out")]) == 2
    assert "--quantise-sad: only with --features sad, got 'dnn'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["match", "loops"])
def test_help_gives_defaults_of_values_not_of_on_off_flags(command, capsys):
    """argparse would print ``--no-enhance ... (default: True)``: the default of ``enhance``,
    read as if the flag were on."""
    with pytest.raises(SystemExit):
        main([command, "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "look-back length" in help_text and "(default: 10)" in help_text
    assert "(default: True)" not in help_text and "(default: False)" not in help_text


@pytest.mark.parametrize("workers", [1, 2, 5])
def test_parallel_decoding_gives_the_librarys_frames(drives, workers):
    expected = read_frame_folder(drives[0], workers=1)
    got = read_frame_folder(drives[0], workers=workers)
    np.testing.assert_array_equal(got.images, expected.images)
    assert got.names == expected.names
    assert got.poses.equals(expected.poses)


def test_parallel_decoding_names_the_first_bad_file_in_name_order(tmp_path):
    folder = write_route(tmp_path / "frames", brightness=1.0, seed=1)
    files = sorted(folder.glob("*.png"))
    assert cv2.imwrite(str(files[3]), np.zeros((16, 16), np.uint8))  # wrong size, first
    files[20].write_bytes(files[20].read_bytes()[:100])  # truncated, later
    for read in (lambda path: read_frame_folder(path, workers=1),
                 lambda path: read_frame_folder(path, workers=4)):
        with pytest.raises(FrameReadError, match=f"{files[3]}: image size 16x16"):
            read(folder)


def test_the_timing_split_is_written_and_printed(drives, tmp_path, capsys):
    assert main(["match", *map(str, drives), "--out", str(tmp_path / "out")]) == 0
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    wall, cpu = metrics["timing"], metrics["timing_cpu"]
    assert set(TIMING_KEYS) == {"decode", "features", "match", "figures", "total"}
    assert set(cpu) == set(TIMING_KEYS) and set(wall) == set(TIMING_KEYS) | set(MATCH_PARTS)
    for timing in (wall, cpu):
        assert all(value >= 0 for value in timing.values())
        assert timing["total"] >= sum(timing[k] for k in TIMING_KEYS if k != "total")
    # the parts of match: difference and search measured inside the matching, metrics the rest
    assert wall["difference"] > 0 and wall["search"] > 0
    assert sum(wall[k] for k in MATCH_PARTS) == pytest.approx(wall["match"], rel=1e-9)
    assert metrics["seconds"] == wall["features"] + wall["match"]
    printed = capsys.readouterr().out
    assert "time (s, wall/cpu): decode " in printed and ", total " in printed
    assert f"(difference {wall['difference']:.2f}, search {wall['search']:.2f}, metrics " \
        in printed


def test_match_parts_are_what_the_matching_measured_and_the_rest():
    assert match_parts(2.0, {"difference": 0.5, "search": 1.0}) == \
        {"difference": 0.5, "search": 1.0, "metrics": 0.5}
    assert match_parts(1.0, {"difference": 0.6, "search": 0.5})["metrics"] == 0.0  # clock noise


def test_matching_reports_the_seconds_of_its_two_phases():
    rng = np.random.default_rng(1)
    reference = rng.normal(size=(60, 16)).astype(np.float32)
    result = match_sequences(reference, reference[:40], metric="sad", chunk_size=7)
    assert set(result.seconds) == {"difference", "search"}
    assert all(seconds > 0 for seconds in result.seconds.values())
    # timings never make two results unequal
    again = match_sequences(reference, reference[:40], metric="sad", chunk_size=7)
    assert dataclasses.replace(again, seconds={"difference": 9.0}) == again


@pytest.mark.parametrize("metric", ["sad", "sqeuclidean"])
@pytest.mark.parametrize("enhance", [True, False])
def test_the_figure_shows_every_kth_cell_of_the_searched_matrices(metric, enhance):
    rng = np.random.default_rng(0)
    reference = rng.normal(size=(57, 16)).astype(np.float32)
    query = (reference[:45] + 0.3 * rng.normal(size=(45, 16))).astype(np.float32)
    params = SeqSLAMParams.defaults(enhance=enhance, r_window=6)
    full = match_sequences(reference, query, metric=metric, params=params, keep_matrices=True)
    D, D_hat, k = figure_matrices(reference, query, metric=metric, params=params, side=10)
    assert k == 6 and D.shape == D_hat.shape == (10, 8)
    np.testing.assert_allclose(D, full.D[::k, ::k], rtol=1e-6)
    # eq. 14's values, up to the one shift that makes the shown cells >= 0
    offset = D_hat - full.D_hat[::k, ::k]
    np.testing.assert_allclose(offset, offset.flat[0], atol=1e-5)


@pytest.mark.parametrize("side, kept", [(600, True), (8, False)])
def test_the_searched_matrices_are_kept_only_when_the_figure_shows_every_frame(
        drives, tmp_path, monkeypatch, side, kept):
    """Keeping 3,600 x 3,600 matrices cost more (0.5-0.9 s) than computing the figure's every
    k-th column again (0.1-0.2 s); 40 frames fit a 600-frame figure, not an 8-frame one."""
    from cmal_lcd.reports import match_figures
    from cmal_lcd.evaluation import loop_closure

    monkeypatch.setattr(match_figures, "DISPLAY_SIDE", side)
    seen = []
    real = loop_closure.evaluate_pair
    monkeypatch.setattr(loop_closure, "evaluate_pair",
                        lambda *a, **kw: seen.append(kw["keep_matrices"]) or real(*a, **kw))
    assert main(["match", *map(str, drives), "--out", str(tmp_path / "out")]) == 0
    assert seen == [kept]
    assert cv2.imread(str(tmp_path / "out" / "difference_matrices.png")) is not None
