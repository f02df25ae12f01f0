"""``cmal-lcd match --out DIR`` holds the previous complete outputs or the new ones, never a mix.

Everything is written into a temporary folder beside ``DIR`` that replaces ``DIR`` once
complete; a failure at any step leaves ``DIR`` as it was and no temporary folder behind. A
``DIR`` holding files ``match`` did not write is refused (one line, exit code 2), never emptied.
"""

import json
import os

import pytest

from cmal_lcd.workflows import match_folders as match_module
from cmal_lcd.commands import main
from cmal_lcd.workflows.match_folders import FIGURE_OUTPUTS, MATCH_OUTPUTS
from cmal_lcd.reports import plots
from test_cli import write_route


@pytest.fixture
def drives(tmp_path):
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    return (write_route(inputs / "sunny", brightness=1.0, seed=1),
            write_route(inputs / "foggy", brightness=0.6, seed=2))


@pytest.fixture
def out(tmp_path):
    """The output folder, alone in its parent (so that leftovers are visible)."""
    parent = tmp_path / "results"
    parent.mkdir()
    return parent / "out"


def contents(folder):
    """``{name: bytes}`` of every file of ``folder``."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and "Traceback" not in err, err
    return err


def test_a_failing_figure_leaves_the_previous_outputs_unchanged_and_no_temporary_folder(
        drives, out, monkeypatch, capsys):
    assert main(["match", *map(str, drives), "--out", str(out)]) == 0
    before = contents(out)
    assert sorted(before) == sorted(MATCH_OUTPUTS)

    def failing_figure(D, D_hat, *, path, **kw):
        path.write_bytes(b"half a figure")
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(plots, "plot_difference_matrices", failing_figure)
    assert main(["match", *map(str, drives), "--out", str(out), "--ds", "5"]) == 2
    assert "No space left on device" in one_line_error(capsys)
    assert contents(out) == before
    assert os.listdir(out.parent) == ["out"]


def test_a_failure_before_any_output_leaves_no_folder_behind(drives, out, tmp_path):
    assert main(["match", str(drives[0]), str(tmp_path / "missing"), "--out", str(out)]) == 2
    assert os.listdir(out.parent) == []


def test_a_rerun_replaces_the_outputs_as_a_whole(drives, out):
    assert main(["match", *map(str, drives), "--out", str(out)]) == 0
    assert main(["match", *map(str, drives), "--out", str(out), "--ds", "5"]) == 0
    assert json.loads((out / "metrics.json").read_text())["params"]["ds"] == 5
    assert sorted(os.listdir(out)) == sorted(MATCH_OUTPUTS)
    assert os.listdir(out.parent) == ["out"]
    assert (out.stat().st_mode & 0o777) == 0o777 & ~current_umask()


def test_a_failure_while_swapping_puts_the_previous_folder_back(drives, out, monkeypatch):
    assert main(["match", *map(str, drives), "--out", str(out)]) == 0
    before = contents(out)
    real_rename = os.rename

    def rename(src, dst):
        if os.path.basename(str(src)).startswith(".out.new-"):
            raise OSError(5, "Input/output error", str(src))
        return real_rename(src, dst)

    monkeypatch.setattr(match_module.os, "rename", rename)
    assert main(["match", *map(str, drives), "--out", str(out), "--ds", "5"]) == 2
    assert contents(out) == before
    assert os.listdir(out.parent) == ["out"]


def test_an_out_folder_holding_other_files_is_refused_untouched(drives, out, capsys):
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "metrics.json").write_text("{}")
    assert main(["match", *map(str, drives), "--out", str(out)]) == 2
    err = one_line_error(capsys)
    assert f"{out}: --out holds an entry match did not write (first 'notes.txt')" in err
    assert contents(out) == {"metrics.json": b"{}", "notes.txt": b"mine"}
    assert os.listdir(out.parent) == ["out"]


def test_an_empty_out_folder_is_used(drives, out):
    out.mkdir()
    assert main(["match", *map(str, drives), "--out", str(out)]) == 0
    assert sorted(os.listdir(out)) == sorted(MATCH_OUTPUTS)


def current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_no_figures_writes_metrics_only_with_the_same_numbers(drives, out, tmp_path, capsys):
    assert main(["match", *map(str, drives), "--out", str(out)]) == 0
    with_figures = json.loads((out / "metrics.json").read_text())
    fast = tmp_path / "fast"
    assert main(["match", *map(str, drives), "--out", str(fast), "--no-figures"]) == 0
    data_files = [name for name in MATCH_OUTPUTS if name not in FIGURE_OUTPUTS]
    assert sorted(os.listdir(fast)) == sorted(data_files)
    assert capsys.readouterr().out.splitlines()[-1] == f"wrote {', '.join(data_files)} to {fast}"
    without = json.loads((fast / "metrics.json").read_text())
    assert "figures" not in without["timing"] and "figures" in with_figures["timing"]
    for record in (with_figures, without):
        del record["timing"], record["timing_cpu"], record["seconds"]
    assert without == with_figures
    # a later run with figures may reuse the folder: it holds only files match writes
    assert main(["match", *map(str, drives), "--out", str(fast)]) == 0
    assert sorted(os.listdir(fast)) == sorted(MATCH_OUTPUTS)


def test_the_first_match_after_an_install_says_it_compiles_the_kernels(monkeypatch, tmp_path):
    import cmal_lcd.matching.seqslam as seqslam
    from cmal_lcd.workflows import match_folders as match_module

    monkeypatch.setattr(seqslam, "__file__", str(tmp_path / "seqslam.py"))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    assert not match_module.kernels_cached()
    elsewhere = tmp_path / "numba_cache" / "cmal_lcd" / "matching"
    elsewhere.mkdir(parents=True)
    (elsewhere / "seqslam._viterbi-12.py311.nbi").touch()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba_cache"))
    assert match_module.kernels_cached()
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    (tmp_path / "__pycache__").mkdir()
    (tmp_path / "__pycache__" / "seqslam.best-3.py311.nbi").touch()
    assert match_module.kernels_cached()
    assert "about 10 s" in match_module.COMPILE_NOTICE
