"""User-facing failures of ``cmal-lcd`` and the stage modules: one line, exit code 2.

Each case names the file, folder or config key; ``cmal-lcd --verbose`` adds the traceback.
Misleading successes (a result that looks fine but rests on the wrong input) are refused or
warned about.
"""

from __future__ import annotations

import argparse
import subprocess
import sys

import cv2
import numpy as np
import pytest

from cmal_lcd.commands import build_parser, main
from cmal_lcd.commands.match import DEFAULT_MIN_SCORED_QUERIES
from cmal_lcd.config import compose
from image_files import png_header_only

N_FRAMES = 40


def write_frames(folder, n=N_FRAMES, *, poses=False):
    """``n`` frames cropped along a blurred panorama (a route), optional ``poses.csv``."""
    panorama = cv2.GaussianBlur(np.random.default_rng(0).random((32, 64 + 4 * n)), (0, 0), 2)
    folder.mkdir(parents=True)
    for i in range(n):
        grey = np.clip(255 * panorama[:, 4 * i:4 * i + 64] / panorama.max(), 0, 255)
        assert cv2.imwrite(str(folder / f"f{i:03d}.png"), grey.astype(np.uint8))
    if poses:
        rows = ["name,x,y"] + [f"f{i:03d}.png,{float(i)},0" for i in range(n)]
        (folder / "poses.csv").write_text("\n".join(rows) + "\n")
    return folder


@pytest.fixture
def drives(tmp_path):
    return write_frames(tmp_path / "ref"), write_frames(tmp_path / "qry")


def one_line_error(capsys) -> str:
    """The single stderr line of a failed command (asserting there is exactly one)."""
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err], err
    assert "Traceback" not in err
    return err


# ------------------------------------------------------------------------------ outputs


def test_an_out_folder_that_cannot_be_created_is_one_line_naming_it(drives, tmp_path, capsys):
    assert main(["match", *map(str, drives), "--out", "/proc/x"]) == 2
    assert "/proc/x" in one_line_error(capsys)


def test_a_file_in_the_way_of_the_out_folder_is_one_line_naming_it(drives, tmp_path, capsys):
    blocker = tmp_path / "out"
    blocker.write_text("not a folder")
    assert main(["match", *map(str, drives), "--out", str(blocker)]) == 2
    assert str(blocker) in one_line_error(capsys)
    assert blocker.read_text() == "not a folder"


def test_a_folder_where_pr_curve_png_goes_is_refused_before_anything_is_written(
        drives, tmp_path, capsys):
    (tmp_path / "out" / "pr_curve.png").mkdir(parents=True)
    assert main(["match", *map(str, drives), "--out", str(tmp_path / "out")]) == 2
    assert str(tmp_path / "out" / "pr_curve.png") in one_line_error(capsys)
    assert not (tmp_path / "out" / "metrics.json").exists()


def test_aggregate_of_a_missing_sweep_folder_is_one_line_naming_it(tmp_path, capsys):
    missing = tmp_path / "multirun" / "nothing"
    assert main(["aggregate", str(missing), "--name", "x", "--out", str(tmp_path / "o")]) == 2
    assert str(missing) in one_line_error(capsys)
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------ model files


@pytest.mark.parametrize("content", ["corrupt", "hostile"])
def test_an_unreadable_model_file_is_one_line_naming_it(drives, tmp_path, capsys, content):
    import torch

    model = tmp_path / "models" / "cmal" / "model.pt"
    model.parent.mkdir(parents=True)
    if content == "corrupt":
        model.write_bytes(b"PK\x03\x04 this is not a torch archive")
    else:  # an object torch's weights-only loader refuses (it could run code when unpickled)
        torch.save({"name": "cmal", "payload": argparse.Namespace(cmd="echo X")}, model)
    assert main(["match", *map(str, drives), "--features", "cmal", "--model-dir",
                 str(tmp_path / "models"), "--out", str(tmp_path / "out")]) == 2
    err = one_line_error(capsys)
    assert str(model) in err and "weights_only=False" not in err


# ------------------------------------------------------------------------------ config


def test_a_seed_that_is_not_an_integer_is_one_line_naming_the_key(tmp_path, capsys):
    output = tmp_path / "params.yaml"
    assert main(["compose-params", "debug=tiny", "seed=banana", "--output", str(output)]) == 2
    err = one_line_error(capsys)
    assert "seed" in err and "'banana'" in err and "invalid literal" not in err
    assert not output.exists()


def test_the_match_pose_tolerance_default_is_the_configs():
    args = build_parser().parse_args(["match", "a", "b"])
    assert args.poses_tolerance == compose().matching.pose_tolerance == 5.0


# ------------------------------------------------------------------------------ misleading success


def test_a_reference_shorter_than_ds_is_blamed_on_the_reference_folder(tmp_path, capsys):
    reference = write_frames(tmp_path / "short_ref", 3)
    query = write_frames(tmp_path / "qry")
    assert main(["match", str(reference), str(query), "--ds", "10",
                 "--out", str(tmp_path / "out")]) == 2
    err = one_line_error(capsys)
    assert str(reference) in err and "reference" in err and "ds=10" in err
    assert str(query) not in err


def test_too_few_scored_queries_are_warned_about(drives, tmp_path, capsys):
    assert main(["match", *map(str, drives), "--ds", "39", "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "1 of 40 queries scored" in err
    assert f"--min-scored-queries {DEFAULT_MIN_SCORED_QUERIES}" in err


def test_enough_scored_queries_give_no_warning(drives, tmp_path, capsys):
    assert main(["match", *map(str, drives), "--ds", "5", "--min-scored-queries", "30",
                 "--out", str(tmp_path / "o")]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("with_poses", ["ref", "qry"])
def test_poses_in_only_one_folder_are_refused_naming_the_folder_without(tmp_path, capsys,
                                                                        with_poses):
    reference = write_frames(tmp_path / "ref", poses=with_poses == "ref")
    query = write_frames(tmp_path / "qry", poses=with_poses == "qry")
    missing = query if with_poses == "ref" else reference
    assert main(["match", str(reference), str(query), "--out", str(tmp_path / "o")]) == 2
    err = one_line_error(capsys)
    assert f"{missing}: no poses.csv" in err
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------ --verbose, stages


def test_verbose_shows_the_traceback_before_the_one_line(tmp_path, capsys):
    missing = tmp_path / "nothing"
    assert main(["--verbose", "aggregate", str(missing), "--name", "x"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" in err and err.splitlines()[-1].startswith("cmal-lcd aggregate: error: ")


@pytest.mark.parametrize("stage, args", [
    ("evaluate", ["--method", "sad"]), ("evaluate_loops", ["--method", "sad"]),
    ("select_protocol", ["--method", "sad"]),
    ("make_dataset", []), ("analyse_codes", []), ("calibrate_world", []), ("report", [])])
def test_a_failing_stage_module_prints_one_line_and_exits_2(tmp_path, stage, args):
    missing = tmp_path / "missing.yaml"
    result = subprocess.run([sys.executable, "-m", f"cmal_lcd.stages.{stage}", *args,
                             "--params", str(missing)], cwd=tmp_path, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"cmal_lcd.stages.{stage}: error: {missing}: no such params file; compose it from "
        f"conf/ with `cmal-lcd compose-params`"]


# ---------------------------------------------------- sizes of the search (issue 38 item 5)


@pytest.mark.parametrize("command", ["match", "loops"])
@pytest.mark.parametrize("option, value, named", [
    ("--v-step", "1e-9", "--v-step: 1e-09 gives more than 1000 velocities"),
    ("--v-max", "1e300", "--v-max: must be <= 100.0, got 1e+300"),
])
def test_a_velocity_search_too_large_to_run_is_one_line_at_once(drives, tmp_path, capsys,
                                                                command, option, value, named):
    """``--v-step 1e-9`` and ``--v-max 1e300`` hung with growing memory; now refused before
    any frame is read."""
    inputs = list(map(str, drives)) if command == "match" else [str(drives[0])]
    out = tmp_path / "out"
    assert main([command, *inputs, option, value, "--out", str(out)]) == 2
    assert named in one_line_error(capsys)
    assert not out.exists()


@pytest.mark.parametrize("override, named", [
    ("matching.v_max=1e300", "matching.v_max: must be <= 100"),
    ("matching.v_step=1e-9", "matching.v_step: 1e-09 gives more than 1000 velocities"),
])
def test_a_velocity_search_too_large_is_refused_by_the_config(override, named):
    from cmal_lcd.matching import SeqSLAMParams

    with pytest.raises(ValueError, match=named):
        cfg = compose([override])  # the schema bounds v_max; the grid size needs all three
        SeqSLAMParams.from_config(cfg.matching)


def test_a_look_back_longer_than_the_queries_allocates_nothing_and_scores_none():
    """``matching.ds=10^9`` failed at allocation ("Unable to allocate 29.8 GiB"): a look-back
    no query can have scores none, at once."""
    from cmal_lcd.matching import SeqSLAMParams, match_sequences, sequence_search

    rng = np.random.default_rng(0)
    reference, query = rng.random((50, 8), dtype=np.float32), rng.random((30, 8), np.float32)
    result = match_sequences(reference, query, metric="sad", params=SeqSLAMParams.defaults(ds=10**9),
                             top_k=5)
    assert result.n_scored == 0 and (result.single_frame_match >= 0).all()
    assert (sequence_search(np.ones((5, 4)), ds=10**9).match == -1).all()


@pytest.mark.parametrize("case, named", [
    ("empty", "no job of a sweep in it"),
    ("default", "--default 'other': not one of the sweeps given (x)"),
])
def test_seeds_report_of_an_empty_sweep_writes_nothing(tmp_path, capsys, case, named):
    """Issue 38 item 4: ``seeds-report x=EMPTY --default x`` exited 0 and replaced the
    committed report with empty tables. Now one line, exit 2, the old files untouched."""
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    if case == "default":
        (sweep / "0" / ".hydra").mkdir(parents=True)
        (sweep / "0" / ".hydra" / "overrides.yaml").write_text("- seed=0\n")
    out = tmp_path / "seeds"
    out.mkdir()
    (out / "README.md").write_text("the committed report")
    default = "x" if case == "empty" else "other"
    assert main(["seeds-report", f"x={sweep}", "--default", default, "--out", str(out)]) == 2
    assert named in one_line_error(capsys)
    assert [p.name for p in out.iterdir()] == ["README.md"]
    assert (out / "README.md").read_text() == "the committed report"


@pytest.mark.parametrize("content, named", [
    ("ds: [unclosed\n", "seqslam.yaml:"),
    ("ds: -3\n", "matching.ds: must be >= 1, got -3"),
])
def test_a_broken_matching_config_is_one_line_for_every_command(tmp_path, capsys, monkeypatch,
                                                               content, named):
    """Issue 38 item 9: a broken ``conf/matching/seqslam.yaml`` made every command, ``--help``
    included, exit 1 with a traceback (defaults are read while the parser is built)."""
    import shutil

    import cmal_lcd.checkout
    from cmal_lcd.matching import params

    conf = tmp_path / "conf"
    shutil.copytree(cmal_lcd.checkout.CONF_DIR, conf)
    text = (conf / "matching" / "seqslam.yaml").read_text()
    lines = [line for line in text.splitlines() if not line.startswith("ds:")]
    (conf / "matching" / "seqslam.yaml").write_text(content + "\n".join(lines) + "\n")
    monkeypatch.setattr(cmal_lcd.checkout, "CONF_DIR", conf)
    params._read_matching_defaults.cache_clear()
    try:
        for argv in (["--help"], ["match", "a", "b"]):
            assert main(argv) == 2
            err = one_line_error(capsys)
            assert err.startswith("cmal-lcd: ") and named in err, err
    finally:
        params._read_matching_defaults.cache_clear()


@pytest.mark.parametrize("command", ["match", "loops"])
def test_a_tolerance_beyond_any_drive_is_one_line_naming_the_option(drives, tmp_path, capsys,
                                                                    command):
    """Issue 38 item 11: ``--d-thresh 1e20`` (as an integer) failed with "ufunc 'isfinite' not
    supported", naming nothing."""
    inputs = list(map(str, drives)) if command == "match" else [str(drives[0])]
    assert main([command, *inputs, "--d-thresh", str(10**20), "--out", str(tmp_path / "o")]) == 2
    assert "--d-thresh: must be <= 1000000000, got " in one_line_error(capsys)


@pytest.mark.parametrize("override, named", [
    ("seed=18446744073709551616", "seed: must be <= 9223372036854775807"),
    ("matching.d_thresh=100000000000000000000", "matching.d_thresh: must be <= 1000000000"),
])
def test_numbers_no_stage_can_use_are_refused_at_composition(override, named):
    """A 2^64 seed passed composition and failed after the dataset step (issue 38 item 11)."""
    with pytest.raises(ValueError, match=named):
        compose([override])


def test_a_negative_minimum_of_scored_queries_is_refused(drives, tmp_path, capsys):
    """Issue 38 item 12: ``--min-scored-queries -5`` was accepted without a word."""
    assert main(["match", *map(str, drives), "--min-scored-queries", "-5", "--out",
                 str(tmp_path / "o")]) == 2
    assert "--min-scored-queries: must be >= 0, got -5" in one_line_error(capsys)
    assert not (tmp_path / "o").exists()


def test_an_exclusion_zone_longer_than_the_drive_is_refused(drives, tmp_path, capsys):
    """Issue 38 item 12: ``loops --exclude-frames 100000`` reported "0 scored" with exit 0."""
    assert main(["loops", str(drives[0]), "--exclude-frames", "100000", "--out",
                 str(tmp_path / "o")]) == 2
    assert "--exclude-frames 100000: leaves no older frame to match in the 40 frames" in \
        one_line_error(capsys)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("where", ["cwd", "inside", "input"])
def test_an_out_folder_that_is_the_working_directory_or_an_input_is_refused(
        drives, tmp_path, capsys, monkeypatch, where):
    """Issue 38 item 12: ``--out .`` in an empty working directory replaced it; ``--out``
    inside an input folder was read back as input by the next run."""
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.chdir(empty)
    out = {"cwd": ".", "inside": str(drives[0] / "out"), "input": str(drives[1])}[where]
    assert main(["match", *map(str, drives), "--out", out]) == 2
    err = one_line_error(capsys)
    assert out in err, err  # an input itself is also refused for the frames it holds
    assert sorted(p.name for p in empty.iterdir()) == []
    assert not (drives[0] / "out").exists()


def test_control_characters_of_a_file_name_never_reach_the_terminal(tmp_path, capsys):
    """Issue 38 item 12: escape sequences in file names reached the terminal raw."""
    reference, query = write_frames(tmp_path / "ref"), write_frames(tmp_path / "qry")
    (query / "f000.png").unlink()
    (query / "f000\x1b[2J.png").write_bytes(b"not an image")
    assert main(["match", str(reference), str(query), "--out", str(tmp_path / "o")]) == 2
    err = one_line_error(capsys)
    assert "\x1b" not in err and "f000\\x1b[2J.png" in err, err


@pytest.mark.parametrize("command", ["match", "loops"])
def test_a_huge_frame_sorted_first_is_one_line_naming_it(drives, tmp_path, capsys, command):
    """Issue 38 item 11: a 20000 x 20000 PNG sorted first said only "Unable to allocate 68.2
    GiB". Its header says the size, so nothing is decoded or allocated (no monkeypatch: 200,000
    x 200,000 pixels exceed any machine's memory)."""
    huge = drives[1] / "a000.png"
    png_header_only(huge, 200_000, 200_000)
    inputs = [str(drives[1])] if command == "loops" else [str(drives[0]), str(drives[1])]
    assert main([command, *inputs, "--out", str(tmp_path / "o")]) == 2
    err = one_line_error(capsys)
    assert f"{huge}: an image of 200000x200000" in err and "of memory available" in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("damage, named", [
    ("idat", "corrupt PNG (its 'IDAT' chunk fails its CRC check)"),
    ("short_idat", "corrupt PNG (its 'IDAT' chunk fails its CRC check)"),
])
def test_a_corrupt_png_gets_only_the_projects_line(drives, tmp_path, capfd, damage, named):
    """Issue 38 item 12: libpng (``libpng error: IDAT: invalid stored block lengths``) and
    OpenCV (``[ WARN:0@0.25] ... PNG input buffer is incomplete``) printed their own lines
    before the project's. capfd sees what C libraries write to file descriptor 2."""
    frame = drives[1] / "f007.png"
    data = bytearray(frame.read_bytes())
    at = data.index(b"IDAT")
    if damage == "idat":
        data[at + 10] ^= 0xFF
    else:  # the chunk claims fewer bytes than it holds: the stream ends early
        length = int.from_bytes(data[at - 4:at], "big")
        data[at - 4:at] = (length // 2).to_bytes(4, "big")
    frame.write_bytes(bytes(data))
    assert main(["match", *map(str, drives), "--out", str(tmp_path / "o")]) == 2
    err = capfd.readouterr().err.strip()
    assert err.splitlines() == [f"cmal-lcd match: error: {frame}: {named}"], err


@pytest.mark.parametrize("argv, named", [
    (["match", "a", "b", "--d-thresh", "1e20"], "argument --d-thresh: invalid int value: '1e20'"),
    (["match"], "the following arguments are required: REFERENCE, QUERY"),
    (["loops", "a", "--ds", "x\x1b[2J"], "argument --ds: invalid int value: 'x\\x1b[2J'"),
    (["nope"], "argument COMMAND: invalid choice: 'nope'"),
])
def test_a_usage_error_is_one_line_without_the_usage_block(capsys, argv, named):
    """Issue 38 item 11: ``--d-thresh 1e20`` printed argparse's 14-line usage block first."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = one_line_error(capsys)
    assert named in err and err.endswith("--help)"), err
