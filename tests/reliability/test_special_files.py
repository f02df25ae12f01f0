"""Special files never block a command (issue 38 item 6): a FIFO named like a frame, as
``poses.csv`` or as ``--protocol``, and links to ``/dev/zero`` or ``/dev/urandom``, are refused
in one line naming them, before they are opened. Each command runs in a subprocess under a
timeout, so a regression fails instead of hanging the suite."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

CLI = [sys.executable, "-m", "cmal_lcd.commands"]


def write_frames(folder: Path, n: int = 24) -> Path:
    panorama = cv2.GaussianBlur(np.random.default_rng(0).random((32, 64 + 4 * n)), (0, 0), 2)
    folder.mkdir(parents=True)
    for i in range(n):
        grey = np.clip(255 * panorama[:, 4 * i:4 * i + 64] / panorama.max(), 0, 255)
        assert cv2.imwrite(str(folder / f"f{i:03d}.png"), grey.astype(np.uint8))
    return folder


def run(args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run(CLI + [str(a) for a in args], cwd=cwd, capture_output=True, text=True,
                          timeout=60)


@pytest.mark.parametrize("case", ["fifo frame", "fifo poses", "fifo protocol", "dev zero frame",
                                  "dev urandom poses"])
def test_a_special_file_is_refused_in_one_line_without_blocking(tmp_path, case):
    reference, query = write_frames(tmp_path / "ref"), write_frames(tmp_path / "qry")
    extra = []
    if case == "fifo frame":
        victim = query / "f000.png"
        victim.unlink()
        os.mkfifo(victim)
    elif case in ("fifo poses", "dev urandom poses"):
        for folder in (reference, query):
            rows = [f"f{i:03d}.png,{float(i)},0" for i in range(24)]
            (folder / "poses.csv").write_text("\n".join(["name,x,y", *rows]) + "\n")
        victim = query / "poses.csv"
        victim.unlink()
        os.mkfifo(victim) if case == "fifo poses" else victim.symlink_to("/dev/urandom")
    elif case == "fifo protocol":
        victim = tmp_path / "protocol.json"
        os.mkfifo(victim)
        extra = ["--features", "sad", "--protocol", victim]
    else:
        victim = query / "f000.png"
        victim.unlink()
        victim.symlink_to("/dev/zero")
    done = run(["match", reference, query, "--out", tmp_path / "out", "--no-figures", *extra],
               tmp_path)
    err = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(err) == 1, done.stderr
    assert str(victim) in err[0] and "not a regular file" in err[0], err[0]
    assert not (tmp_path / "out").exists()
