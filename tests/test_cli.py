"""``cmal-lcd match``: a user's two folders of frames in, metrics and figures out."""

import json

import cv2
import numpy as np
import pytest

from cmal_lcd.commands import build_parser, main
from cmal_lcd.workflows.match_folders import MATCH_OUTPUTS
from cmal_lcd.matching import matching_defaults
from cmal_lcd.matching import SeqSLAMParams
from subprocess_helpers import python_output

N_FRAMES = 40


def write_route(folder, *, brightness, seed, poses=None):
    """Frames cropped along a long random panorama (a route), under a given brightness."""
    rng = np.random.default_rng(seed)
    panorama = cv2.GaussianBlur(np.random.default_rng(0).random((32, 64 + 4 * N_FRAMES)), (0, 0), 2)
    folder.mkdir()
    for i in range(N_FRAMES):
        crop = panorama[:, 4 * i:4 * i + 64] * brightness + 0.05 * rng.random((32, 64))
        grey = np.clip(255 * crop / panorama.max(), 0, 255).astype(np.uint8)
        assert cv2.imwrite(str(folder / f"frame-{i:04d}.png"), grey)
    if poses is not None:
        lines = ["name,x,y"] + [f"frame-{i:04d}.png,{x},0" for i, x in enumerate(poses)]
        (folder / "poses.csv").write_text("\n".join(lines) + "\n")
    return folder


@pytest.fixture
def folders(tmp_path):
    return (write_route(tmp_path / "sunny", brightness=1.0, seed=1),
            write_route(tmp_path / "foggy", brightness=0.6, seed=2))


def test_match_writes_metrics_and_figures_and_prints_them(folders, tmp_path, capsys):
    reference, query = folders
    out = tmp_path / "out"
    assert main(["match", str(reference), str(query), "--out", str(out)]) == 0
    for name in MATCH_OUTPUTS:
        assert (out / name).stat().st_size > 0, name
    assert cv2.imread(str(out / "pr_curve.png")) is not None
    assert cv2.imread(str(out / "difference_matrices.png")) is not None
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("n_reference", "n_query", "auc_pr", "auc_roc", "recall_at_100p", "recall_at_1",
                "single_frame_recall_at_1", "seconds"):
        assert key in metrics, key
    assert f"wrote {', '.join(MATCH_OUTPUTS)}" in capsys.readouterr().out
    assert metrics["n_reference"] == metrics["n_query"] == N_FRAMES
    assert metrics["n_scored"] == N_FRAMES - SeqSLAMParams.defaults().ds
    assert metrics["recall_at_1"] > 0.8 and metrics["seconds"] > 0
    params = metrics["params"]
    assert {k: params[k] for k in SeqSLAMParams.defaults().as_dict()} == SeqSLAMParams.defaults().as_dict()
    assert params["d_thresh"] == matching_defaults()["d_thresh"] and params["features"] == "sad"
    assert params["ground_truth"] == "frame index"


def test_printed_summary_lists_every_metric(folders, tmp_path, capsys):
    reference, query = folders
    main(["match", str(reference), str(query), "--out", str(tmp_path / "out")])
    printed = capsys.readouterr().out
    for key in ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1", "single_frame_recall_at_1",
                "seconds", "n_reference", "n_query"):
        assert key in printed


def test_defaults_come_from_the_library():
    args = build_parser().parse_args(["match", "a", "b"])
    d = SeqSLAMParams.defaults()
    assert (args.ds, args.v_min, args.v_max, args.v_step, args.r_window, args.enhance,
            args.score) == (d.ds, d.v_min, d.v_max, d.v_step, d.r_window, d.enhance, d.score)
    # features None: sad for folders, the descriptors themselves for descriptor files
    assert args.d_thresh == matching_defaults()["d_thresh"] and args.features is None
    assert str(args.out) == "match_out"


def test_options_reach_the_matching(folders, tmp_path):
    reference, query = folders
    out = tmp_path / "opts"
    assert main(["match", str(reference), str(query), "--out", str(out), "--ds", "5",
                 "--no-enhance", "--score", "sum", "--d-thresh", "3", "--r-window", "4",
                 "--v-min", "0.9", "--v-max", "1.0", "--v-step", "0.1"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    params = metrics["params"]
    assert (params["ds"], params["enhance"], params["score"], params["d_thresh"],
            params["r_window"], params["v_min"], params["v_max"]) == (5, False, "sum", 3, 4,
                                                                      0.9, 1.0)
    assert metrics["n_scored"] == N_FRAMES - 5


def test_ground_truth_comes_from_poses_when_both_folders_have_them(tmp_path):
    # the query drive starts 10 frames (metres) later along the route than the reference
    reference = write_route(tmp_path / "ref", brightness=1.0, seed=1,
                            poses=[float(i) for i in range(N_FRAMES)])
    query = write_route(tmp_path / "qry", brightness=0.7, seed=3,
                        poses=[float(i + 10) for i in range(N_FRAMES)])
    out = tmp_path / "out"
    assert main(["match", str(reference), str(query), "--out", str(out), "--d-thresh", "0",
                 "--poses-tolerance", "0.5"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["params"]["ground_truth"] == "poses"
    assert metrics["params"]["poses_tolerance"] == 0.5
    # images of query i show reference place i, but poses say place i + 10: nothing is correct
    # except where poses agree, and the last 10 query places are absent from the reference
    assert metrics["n_positive"] == N_FRAMES - 10 - SeqSLAMParams.defaults().ds
    assert metrics["recall_at_1"] < 0.2


def test_bad_folder_exits_with_an_error_naming_it(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    code = main(["match", str(tmp_path / "empty"), str(tmp_path / "empty"),
                 "--out", str(tmp_path / "out")])
    assert code == 2
    assert "empty" in capsys.readouterr().err
    assert not (tmp_path / "out" / "metrics.json").exists()


def test_too_few_query_frames_for_the_look_back_is_an_error(folders, tmp_path, capsys):
    reference, query = folders
    assert main(["match", str(reference), str(query), "--ds", str(N_FRAMES),
                 "--out", str(tmp_path / "out")]) == 2
    assert "ds" in capsys.readouterr().err


def test_invalid_parameter_is_an_error_naming_it(folders, tmp_path, capsys):
    reference, query = folders
    assert main(["match", str(reference), str(query), "--v-step", "0",
                 "--out", str(tmp_path / "out")]) == 2
    assert "--v-step: must be > 0.0, got 0.0" in capsys.readouterr().err


def test_large_inputs_draw_the_matrix_figure_from_every_kth_frame(folders, tmp_path,
                                                                   monkeypatch):
    from cmal_lcd.reports import match_figures

    monkeypatch.setattr(match_figures, "DISPLAY_SIDE", 8)  # every 5th of 40 frames
    reference, query = folders
    out = tmp_path / "big"
    assert main(["match", str(reference), str(query), "--out", str(out)]) == 0
    assert cv2.imread(str(out / "difference_matrices.png")) is not None
    assert json.loads((out / "metrics.json").read_text())["recall_at_1"] > 0.8


def test_the_installed_script_returns_mains_code_and_freezes_the_collector(monkeypatch):
    """``console_main`` (the ``cmal-lcd`` script) is ``main`` plus ``gc.freeze`` before exit,
    even when ``main`` raises; ``main`` itself (what library callers use) leaves gc alone."""
    import gc

    import cmal_lcd.commands as cli

    monkeypatch.setattr(cli, "main", lambda: 3)
    monkeypatch.setattr(cli, "load_cython_blas_alone", lambda: False)  # see the test below
    gc.unfreeze()
    try:
        assert cli.console_main() == 3
        assert gc.get_freeze_count() > 0

        def failing():
            raise KeyboardInterrupt

        gc.unfreeze()
        monkeypatch.setattr(cli, "main", failing)
        with pytest.raises(KeyboardInterrupt):
            cli.console_main()
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()


def test_the_script_gives_numba_its_blas_without_importing_scipy_linalg():
    """numba's BLAS probe finds ``scipy.linalg.cython_blas`` loaded alone: numba's ``np.dot``
    still works, ``scipy.linalg`` is not imported for it, and importing it later still works."""
    out = python_output(
        "import sys\n"
        "import numpy as np\n"
        "from numba import njit\n"
        "from cmal_lcd.commands import load_cython_blas_alone\n"
        "assert load_cython_blas_alone()\n"
        "dot = njit(lambda a, b: np.dot(a, b))\n"
        "a = np.arange(12.0).reshape(3, 4)\n"
        "assert np.allclose(dot(a, a.T), a @ a.T)\n"
        "print('scipy.linalg' in sys.modules)\n"
        "import scipy.linalg\n"
        "from scipy.linalg import cython_blas\n"
        "assert cython_blas is sys.modules['scipy.linalg.cython_blas']\n"
        "assert np.allclose(scipy.linalg.solve(np.eye(3) * 2, np.ones(3)), 0.5)\n"
        "assert not load_cython_blas_alone()  # scipy.linalg is imported now: nothing to do\n")
    assert out.split() == ["False"]


def test_a_sad_match_through_the_script_never_imports_scipy_linalg(folders, tmp_path):
    reference, query = folders
    out = python_output(
        "import sys\n"
        "from cmal_lcd import commands as cli\n"
        f"sys.argv = ['cmal-lcd', 'match', {str(reference)!r}, {str(query)!r},"
        f" '--out', {str(tmp_path / 'out')!r}, '--no-figures']\n"
        "assert cli.console_main() == 0\n"
        "print('scipy.linalg' in sys.modules, 'numba' in sys.modules)\n")
    assert out.split()[-2:] == ["False", "True"]


def test_main_does_not_freeze_the_collector(folders, tmp_path):
    import gc

    gc.unfreeze()
    reference, query = folders
    assert main(["match", str(reference), str(query), "--out", str(tmp_path / "out"),
                 "--no-figures"]) == 0
    assert gc.get_freeze_count() == 0
