"""``cmal-lcd loops FOLDER``: one traversal of a looping route in, loop closures out."""

import json

import cv2
import numpy as np
import pandas as pd
import pytest

from cmal_lcd.commands import main

N_LAP = 30
ARGS = ["--exclude-frames", "10", "--ds", "5", "--r-window", "6", "--d-thresh", "2",
        "--poses-tolerance", "3"]


def write_circuit(folder, *, laps=2, poses=True, seed=0):
    """A circuit of ``N_LAP`` places driven ``laps`` times: frames cropped from one panorama at
    the place's position (second lap darker and noisier), poses on a 30 m circle."""
    rng = np.random.default_rng(seed)
    panorama = cv2.GaussianBlur(np.random.default_rng(0).random((32, 64 + 4 * N_LAP)), (0, 0), 2)
    folder.mkdir()
    names = []
    for i in range(N_LAP * laps):
        place, lap = i % N_LAP, i // N_LAP
        crop = panorama[:, 4 * place:4 * place + 64] * (1.0 - 0.3 * lap)
        crop = crop + 0.05 * rng.random(crop.shape)
        grey = np.clip(255 * crop / panorama.max(), 0, 255).astype(np.uint8)
        names.append(f"frame-{i:04d}.png")
        assert cv2.imwrite(str(folder / names[-1]), grey)
    if poses:
        angle = 2 * np.pi * (np.arange(N_LAP * laps) % N_LAP) / N_LAP
        lines = ["name,x,y"] + [f"{n},{30 * np.cos(a):.6f},{30 * np.sin(a):.6f}"
                                for n, a in zip(names, angle)]
        (folder / "poses.csv").write_text("\n".join(lines) + "\n")
    return folder


def test_loops_with_poses_writes_closures_metrics_and_figure(tmp_path, capsys):
    folder = write_circuit(tmp_path / "circuit")
    out = tmp_path / "out"
    assert main(["loops", str(folder), *ARGS, "--out", str(out)]) == 0
    loops = pd.read_csv(out / "loops.csv")
    assert list(loops.columns) == ["query_frame", "query_name", "matched_frame",
                                   "matched_name", "score", "has_revisit", "correct"]
    assert (loops["matched_frame"] < loops["query_frame"] - 10).all()  # the exclusion zone
    second = loops[loops["query_frame"] >= N_LAP + 5]
    assert len(second) == N_LAP - 5
    assert (abs(second["matched_frame"] - (second["query_frame"] - N_LAP)) <= 2).all()
    assert second["correct"].all() and second["has_revisit"].all()
    assert not loops.loc[loops["query_frame"] < N_LAP, "has_revisit"].any()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["n_revisit"] == N_LAP and metrics["recall_at_1"] > 0.4
    assert metrics["n_positive"] == N_LAP  # every second-lap frame is scored and has a revisit
    assert metrics["params"]["exclude_frames"] == 10
    assert (out / "loops.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "auc_pr" in printed and "loops.csv" in printed


def test_loops_without_poses_lists_closures_and_draws_the_matrix(tmp_path):
    folder = write_circuit(tmp_path / "circuit", poses=False)
    out = tmp_path / "out"
    (out).mkdir()
    (out / "metrics.json").write_text("{}")  # stale, from an earlier run with poses
    assert main(["loops", str(folder), *ARGS, "--out", str(out)]) == 0
    loops = pd.read_csv(out / "loops.csv")
    assert list(loops.columns) == ["query_frame", "query_name", "matched_frame",
                                   "matched_name", "score"]
    assert len(loops) > N_LAP - 5
    assert not (out / "metrics.json").exists()
    assert (out / "loops.png").is_file()


def test_threshold_lists_only_confident_closures(tmp_path):
    folder = write_circuit(tmp_path / "circuit", poses=False)
    main(["loops", str(folder), *ARGS, "--out", str(tmp_path / "all")])
    every = pd.read_csv(tmp_path / "all" / "loops.csv")
    cut = float(every["score"].median())
    main(["loops", str(folder), *ARGS, "--threshold", str(cut), "--out", str(tmp_path / "some")])
    some = pd.read_csv(tmp_path / "some" / "loops.csv")
    assert 0 < len(some) < len(every) and (some["score"] <= cut).all()


def test_exclusion_in_metres_moves_the_zone(tmp_path):
    folder = write_circuit(tmp_path / "circuit")
    # 30 frames per lap of 188 m: 150 m of travel is about 24 frames
    assert main(["loops", str(folder), *ARGS, "--exclude-metres", "150",
                 "--out", str(tmp_path / "out")]) == 0
    loops = pd.read_csv(tmp_path / "out" / "loops.csv")
    assert (loops["query_frame"] - loops["matched_frame"] > 23).all()


@pytest.mark.parametrize("extra, needle", [
    (["--exclude-frames", "-1"], "--exclude-frames"),
    (["--ds", "0"], "--ds"),
    (["--v-min", "2"], "--v-min"),
    (["--poses-tolerance", "nan"], "--poses-tolerance"),
    (["--exclude-metres", "5"], "poses.csv"),
])
def test_bad_options_give_one_line_naming_them_and_exit_2(tmp_path, capsys, extra, needle):
    folder = write_circuit(tmp_path / "circuit", laps=1, poses=False)
    assert main(["loops", str(folder), *extra, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err and err.startswith("cmal-lcd loops:")


def test_missing_folder_and_corrupt_image_name_the_path(tmp_path, capsys):
    assert main(["loops", str(tmp_path / "nowhere")]) == 2
    assert "nowhere" in capsys.readouterr().err
    folder = write_circuit(tmp_path / "circuit", laps=1, poses=False)
    (folder / "frame-0003.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    assert main(["loops", str(folder), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "frame-0003.png" in err


def test_bad_poses_file_is_named(tmp_path, capsys):
    folder = write_circuit(tmp_path / "circuit", laps=1)
    (folder / "poses.csv").write_text("name,x\nframe-0000.png,1\n")
    assert main(["loops", str(folder), *ARGS, "--out", str(tmp_path / "out")]) == 2
    assert "poses.csv" in capsys.readouterr().err


@pytest.mark.parametrize("foreign", ["notes.txt", "pr_curve.png"])
def test_loops_refuses_an_out_folder_holding_files_it_did_not_write(tmp_path, capsys, foreign):
    """Issue 38 item 2: ``match A B --out o; loops F --out o`` removed match's metrics.json;
    a folder holding ``notes.txt`` was written into. Now refused in one line, nothing changed."""
    folder = write_circuit(tmp_path / "circuit", poses=False)
    out = tmp_path / "out"
    out.mkdir()
    (out / foreign).write_text("keep me")
    (out / "metrics.json").write_text('{"from": "match"}')
    assert main(["loops", str(folder), *ARGS, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--out holds an entry loops did not write (first {foreign!r})" in err
    assert len(err.splitlines()) == 1
    assert sorted(p.name for p in out.iterdir()) == sorted([foreign, "metrics.json"])
    assert (out / "metrics.json").read_text() == '{"from": "match"}'


def test_loops_replaces_its_outputs_old_or_new(tmp_path, monkeypatch):
    """Issue 38 item 3: a failure between its files left the new loops.csv beside the old
    loops.png. Now the folder is replaced only once every file is written."""
    import cmal_lcd.workflows.loops_folder as loops_command

    folder = write_circuit(tmp_path / "circuit")
    out = tmp_path / "out"
    assert main(["loops", str(folder), *ARGS, "--out", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def fail(*args, **kwargs):
        raise OSError("No space left on device")

    monkeypatch.setattr(loops_command, "_write_loops_figure", fail)
    assert main(["loops", str(folder), *ARGS, "--exclude-frames", "12", "--out", str(out)]) != 0
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out")] == []
