"""Old-or-new folders (``cmal_lcd.io.staged_folder``, ``staged_entries``): an exception
leaves the previous outputs, a SIGKILL at any rename leaves the previous outputs or the new
ones (or, inside the final renames, a committed swap the next run finishes), and entries
the writer does not own are never touched."""

from __future__ import annotations

import os
import shutil
import signal
from pathlib import Path

import pytest

from cmal_lcd import io
from cmal_lcd.io import (MANIFEST, recover_entries, recover_folder, staged_entries,
                         staged_folder)

NAMES = ("README.md", "metrics.json", "tables", "figures", "summary")
OLD = {"README.md": "old readme", "metrics.json": "{}", "tables/a.md": "old a",
       "tables/b.md": "old b", "summary/x.json": "old x"}  # no figures/
NEW = {"README.md": "new readme", "metrics.json": "{\"n\": 1}", "tables/a.md": "new a",
       "figures/f.png": "new f"}  # no summary/, no tables/b.md
FOREIGN = {"world/difficulty.json": "someone else's", "seeds/0.json": "mine"}


def write_tree(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)


def tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` (hidden temporary folders included)."""
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*"))
            if p.is_file()}


def write_new(staging: Path) -> None:
    """The new outputs through the atomic writers, as a stage writes them."""
    for name, text in NEW.items():
        io.atomic_write_text(staging / name, text)


@pytest.fixture
def reports(tmp_path):
    root = tmp_path / "reports"
    write_tree(root, {**OLD, **FOREIGN})
    return root


def test_staged_entries_replace_the_named_entries_together_and_nothing_else(reports):
    with staged_entries(reports, NAMES, tag="report") as staging:
        assert staging.parent == reports and staging.name.startswith(".report.new-")
        write_new(staging)
        assert tree(reports).items() >= {**OLD, **FOREIGN}.items()  # old until complete
    assert tree(reports) == {**NEW, **FOREIGN}


def test_an_exception_while_writing_leaves_the_previous_entries_and_no_temporary_folder(
        reports):
    with pytest.raises(OSError, match="No space"):
        with staged_entries(reports, NAMES, tag="report") as staging:
            write_new(staging)
            raise OSError(28, "No space left on device")
    assert tree(reports) == {**OLD, **FOREIGN}


def test_an_entry_outside_the_named_ones_is_refused_before_anything_changes(reports):
    with pytest.raises(ValueError, match="'world' is not one of the entries"):
        with staged_entries(reports, NAMES, tag="report") as staging:
            write_new(staging)
            io.atomic_write_text(staging / "world" / "difficulty.json", "overwritten")
    assert tree(reports) == {**OLD, **FOREIGN}


@pytest.mark.parametrize("failing", range(1, 9))
def test_a_failing_rename_while_swapping_puts_the_previous_entries_back(reports, monkeypatch,
                                                                        failing):
    real_rename, calls = os.rename, []

    def rename(src, dst):
        calls.append(src)
        if len(calls) == failing:
            raise OSError(5, "Input/output error", str(src))
        return real_rename(src, dst)

    with pytest.raises(OSError, match="Input/output"):
        with staged_entries(reports, NAMES, tag="report") as staging:
            write_new(staging)
            monkeypatch.setattr(os, "rename", rename)
    monkeypatch.undo()
    assert tree(reports) == {**OLD, **FOREIGN}


def killed_child(action, kill_at: int) -> bool:
    """Run ``action`` in a forked child that SIGKILLs itself just before its ``kill_at``-th
    file-system step (a rename, replace or folder deletion). True when it was killed."""
    pid = os.fork()
    if pid == 0:  # the child: never returns to pytest
        try:
            steps = [0]

            def step(real):
                def wrapper(*args, **kwargs):
                    steps[0] += 1
                    if steps[0] == kill_at:
                        os.kill(os.getpid(), signal.SIGKILL)
                    return real(*args, **kwargs)
                return wrapper

            os.rename, os.replace = step(os.rename), step(os.replace)
            shutil.rmtree = step(shutil.rmtree)
            action()
        finally:
            os._exit(0)
    _, status = os.waitpid(pid, 0)
    return os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL


def test_a_kill_at_any_step_leaves_old_or_new_entries_or_a_swap_the_next_run_finishes(
        tmp_path):
    """Every step of a whole report write and swap, killed in turn (exhaustive)."""
    old, new = {**OLD, **FOREIGN}, {**NEW, **FOREIGN}
    seen = {"old": 0, "new": 0, "committed mix": 0}
    kill_at = 0
    while True:
        kill_at += 1
        root = tmp_path / f"k{kill_at}" / "reports"
        write_tree(root, old)

        def run():
            with staged_entries(root, NAMES, tag="report") as staging:
                write_new(staging)

        if not killed_child(run, kill_at):
            assert tree(root) == new
            break
        visible = {k: v for k, v in tree(root).items() if not k.startswith(".report.")}
        if visible == old:
            seen["old"] += 1
        elif visible == new:
            seen["new"] += 1
        else:  # only inside the final renames, after the commit point
            committed = list(root.glob(f".report.new-*/{MANIFEST}"))
            assert committed, f"kill at step {kill_at}: a mix without a committed swap"
            seen["committed mix"] += 1
        recover_entries(root, tag="report")  # what the next run does first
        assert tree(root) in (old, new), f"kill at step {kill_at}"
        if visible == new:
            assert tree(root) == new
    # every kind of kill point was reached, the swap's own renames included
    assert seen["old"] >= len(NEW) and seen["new"] >= 1 and seen["committed mix"] >= 1, seen


def test_a_kill_at_any_step_of_a_folder_swap_leaves_old_or_new(tmp_path):
    old, new = {"difficulty.json": "old", "stale.md": "old"}, {"difficulty.json": "new"}
    kill_at, outcomes = 0, set()
    while True:
        kill_at += 1
        out = tmp_path / f"k{kill_at}" / "world"
        write_tree(out, old)

        def run():
            with staged_folder(out, recover=True) as staging:
                io.atomic_write_text(staging / "difficulty.json", "new")

        killed = killed_child(run, kill_at)
        state = tree(out) if out.is_dir() else None
        if not killed:
            assert state == new and os.listdir(out.parent) == ["world"]
            break
        if state is None:  # between the two renames: both halves are beside it
            assert len(list(out.parent.glob(".world.old-*"))) == 1
        else:
            assert state in (old, new), f"kill at step {kill_at}"
        outcomes.add("nothing" if state is None else "old" if state == old else "new")
        recover_folder(out)
        assert tree(out) in (old, new) and os.listdir(out.parent) == ["world"]
    assert {"old", "new"} <= outcomes


def test_a_folder_swap_recovers_what_a_killed_run_left_before_writing(tmp_path):
    out = tmp_path / "world"
    write_tree(out, {"difficulty.json": "old"})
    (tmp_path / ".world.new-abc").mkdir()  # an unfinished write
    (tmp_path / ".world.old-def").mkdir()  # a finished swap, deletion pending
    with staged_folder(out, recover=True) as staging:
        io.atomic_write_text(staging / "difficulty.json", "new")
    assert tree(out) == {"difficulty.json": "new"}
    assert os.listdir(tmp_path) == ["world"]


def test_a_staged_write_removes_only_the_leftovers_of_the_same_output(tmp_path, caplog):
    """Default staged_folder (as ``cmal-lcd match`` calls it): what a killed write of ``out``
    left goes, one INFO line each; other outputs' staging folders, look-alike files and
    symbolic links stay, and no link is followed."""
    out = tmp_path / "out"
    write_tree(out, {"metrics.json": "old"})
    write_tree(tmp_path / ".out.new-abc", {"metrics.json": "half-written"})
    write_tree(tmp_path / ".out.old-def", {"metrics.json": "older"})
    keep = {".other.new-abc/metrics.json": "another output's",
            ".out.new-x.new-abc/metrics.json": "output out.new-x's",  # not ``.out.new-<id>``
            "out.new-abc": "a file, not hidden",
            "outside/precious.txt": "mine"}
    write_tree(tmp_path, keep)
    (tmp_path / ".out.new-link").symlink_to(tmp_path / "outside")
    (tmp_path / ".out.new-file").write_text("a file, not a staging folder")
    caplog.set_level("INFO", logger="cmal_lcd.io")
    with staged_folder(out) as staging:
        io.atomic_write_text(staging / "metrics.json", "new")
    assert tree(out) == {"metrics.json": "new"}
    assert not (tmp_path / ".out.new-abc").exists()
    assert not (tmp_path / ".out.old-def").exists()
    assert tree(tmp_path).items() >= keep.items()
    assert (tmp_path / ".out.new-link").is_symlink()
    assert (tmp_path / ".out.new-file").read_text() == "a file, not a staging folder"
    removed = [r.getMessage() for r in caplog.records if r.getMessage().startswith("removed ")]
    assert sorted(removed) == [
        f"removed {tmp_path / name}, left by an interrupted write of {out}"
        for name in (".out.new-abc", ".out.old-def")]


def test_a_killed_write_leaves_a_staging_folder_the_next_write_removes(tmp_path):
    out = tmp_path / "out"
    write_tree(out, {"metrics.json": "old"})

    def run():
        with staged_folder(out) as staging:
            io.atomic_write_text(staging / "metrics.json", "half")
            io.atomic_write_text(staging / "figure.png", "never written")

    assert killed_child(run, 2)  # SIGKILL before the second file's replace
    assert len(list(tmp_path.glob(".out.new-*"))) == 1 and tree(out) == {"metrics.json": "old"}
    with staged_folder(out) as staging:
        io.atomic_write_text(staging / "metrics.json", "new")
    assert os.listdir(tmp_path) == ["out"] and tree(out) == {"metrics.json": "new"}


def test_the_staging_folder_of_a_running_write_of_the_same_output_is_left_alone(tmp_path):
    """Two writes of one output at once (here nested): the second one's recovery sees the
    first one's staging folder locked and keeps it; the last swap wins, nothing is left."""
    out = tmp_path / "out"
    with staged_folder(out) as first:
        io.atomic_write_text(first / "metrics.json", "first")
        with staged_folder(out) as second:
            assert first.is_dir()
            io.atomic_write_text(second / "metrics.json", "second")
        assert tree(first) == {"metrics.json": "first"}
        recover_folder(out)
        assert tree(first) == {"metrics.json": "first"}
    assert tree(out) == {"metrics.json": "first"} and os.listdir(tmp_path) == ["out"]


def _fill_the_disk(*args, **kwargs):
    import errno

    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.mark.parametrize("where", ["inside", "atomic"])
def test_a_full_disk_names_the_output_and_keeps_the_previous_one(tmp_path, where):
    """Issue 38 item 11: ``[Errno 28] No space left on device`` named no file. The staged
    folder being written is named, whichever of its files filled the device."""
    from cmal_lcd.io import DiskFullError, atomic_write_text, staged_folder

    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("previous")
    with pytest.raises(DiskFullError, match=(
            rf"^{out}: no space left on the device to write it \(No space left on device\); "
            r"the previous outputs are kept")):
        with staged_folder(out) as staging:
            if where == "inside":
                _fill_the_disk()
            with pytest.MonkeyPatch.context() as patch:
                patch.setattr(os, "replace", _fill_the_disk)
                atomic_write_text(staging / "new.txt", "new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert [p.name for p in out.iterdir()] == ["old.txt"]


def test_a_full_disk_under_one_file_names_that_file(tmp_path, monkeypatch):
    from cmal_lcd.io import DiskFullError, atomic_write_text

    target = tmp_path / "metrics.json"
    target.write_text("previous")
    monkeypatch.setattr(os, "replace", _fill_the_disk)
    with pytest.raises(DiskFullError, match=rf"^{target}: no space left .*the previous file is"):
        atomic_write_text(target, "new")
    assert target.read_text() == "previous" and [p.name for p in tmp_path.iterdir()] == [
        "metrics.json"]
