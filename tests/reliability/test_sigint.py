"""Ctrl-C (SIGINT) ends a command with one line and exit code 130, never a traceback
(issue 38 item 12); what is on disk is the previous output or none (old-or-new writes)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import cv2
import numpy as np


def test_ctrl_c_during_match_is_one_line_and_exit_130(tmp_path):
    for side in ("ref", "qry"):
        folder = tmp_path / side
        folder.mkdir()
        rng = np.random.default_rng(0)
        for i in range(400):
            assert cv2.imwrite(str(folder / f"f{i:04d}.png"),
                               rng.integers(0, 256, (120, 160, 3), dtype=np.uint8))
    process = subprocess.Popen([sys.executable, "-m", "cmal_lcd.commands", "match", "ref", "qry",
                                "--features", "dnn", "--protocol", "raw", "--out", "out"],
                               cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".out.new-*")) and time.monotonic() < deadline:
        time.sleep(0.05)  # until match has begun its output (past every import)
    assert process.poll() is None, "match ended before it could be interrupted"
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    lines = err.strip().splitlines()
    assert process.returncode == 130, err
    assert lines[-1] == ("cmal-lcd match: interrupted (Ctrl-C); its outputs are the previous "
                         "ones or none"), err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()
