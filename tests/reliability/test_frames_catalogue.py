"""Catalogue: bad frame folders (docs/reliability.md, section "Frames").

Every bad folder or file is rejected by `read_frame_folder` with a `FrameReadError` (a
`ValueError`) whose message names the offending folder or file; the tolerated variations
(grey, RGBA, 16-bit, one frame) are read as documented.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from cmal_lcd.workflows.match_folders import match_folders
from cmal_lcd.data import frames as frames_module
from cmal_lcd.data.frames import FrameReadError, read_frame_folder
from cmal_lcd.matching import SeqSLAMParams


def write_png(path: Path, image: np.ndarray) -> Path:
    """Write an RGB(A) or grey image as PNG (OpenCV wants BGR)."""
    if image.ndim == 3 and image.shape[2] == 3:
        image = image[:, :, ::-1]
    elif image.ndim == 3 and image.shape[2] == 4:
        image = image[:, :, [2, 1, 0, 3]]
    assert cv2.imwrite(str(path), image)
    return path


def rgb(seed: int, shape=(12, 16)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape + (3,), dtype=np.uint8)


def folder_of(tmp_path: Path, n: int, *, name: str = "frames") -> Path:
    folder = tmp_path / name
    folder.mkdir()
    for i in range(n):
        write_png(folder / f"img-{i:03d}.png", rgb(i))
    return folder


def raises_naming(path: Path, pattern: str):
    """`pytest.raises` for a FrameReadError naming ``path`` and matching ``pattern``."""
    return pytest.raises(FrameReadError, match=re.escape(str(path)) + ".*" + pattern)


def test_missing_folder_is_named(tmp_path):
    with raises_naming(tmp_path / "nope", "no such frame folder"):
        read_frame_folder(tmp_path / "nope")


def test_empty_folder_is_named(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("not a frame")
    with raises_naming(tmp_path / "empty", "no image files"):
        read_frame_folder(tmp_path / "empty")


def test_zero_byte_file_is_named(tmp_path):
    folder = folder_of(tmp_path, 2)
    (folder / "img-001.png").write_bytes(b"")
    with raises_naming(folder / "img-001.png", "zero-byte"):
        read_frame_folder(folder)


@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_truncated_image_is_named(tmp_path, ext):
    folder = folder_of(tmp_path, 1)
    ok, data = cv2.imencode(ext, rgb(5, (64, 64)))
    assert ok
    bad = folder / f"img-002{ext}"
    bad.write_bytes(data.tobytes()[: len(data) // 2])
    with raises_naming(bad, "truncated"):
        read_frame_folder(folder)


@pytest.mark.parametrize("ext", [".png", ".jpeg", ".JPG"])
def test_non_image_with_image_extension_is_named(tmp_path, ext):
    folder = folder_of(tmp_path, 1)
    bad = folder / f"img-009{ext}"
    bad.write_text("this is a text file, not a picture\n" * 10)
    with raises_naming(bad, "not a PNG or JPEG"):
        read_frame_folder(folder)


def test_corrupt_body_with_valid_header_and_end_is_named(tmp_path):
    folder = folder_of(tmp_path, 1)
    ok, data = cv2.imencode(".png", rgb(3, (12, 16)))
    raw = bytearray(data.tobytes())
    raw[40:-20] = b"\x00" * (len(raw) - 60)  # keep signature and IEND, destroy the chunks
    bad = folder / "img-001.png"
    bad.write_bytes(bytes(raw))
    with raises_naming(bad, r"corrupt PNG \(its '.*' chunk fails its CRC check\)"):
        read_frame_folder(folder)


def test_mixed_sizes_name_the_first_odd_file_and_both_sizes(tmp_path):
    folder = folder_of(tmp_path, 2)
    write_png(folder / "img-002.png", rgb(9, (10, 16)))
    with raises_naming(folder / "img-002.png", r"16x10 .*differs from 16x12 of img-000.png"):
        read_frame_folder(folder)


def test_grey_and_rgba_mixed_with_rgb_become_rgb(tmp_path):
    folder = folder_of(tmp_path, 1)
    grey = rgb(1)[:, :, 0]
    rgba = np.dstack([rgb(2), np.full((12, 16), 7, np.uint8)])
    write_png(folder / "img-001.png", grey)
    write_png(folder / "img-002.png", rgba)
    frames = read_frame_folder(folder)
    assert frames.images.shape == (3, 12, 16, 3) and frames.images.dtype == np.uint8
    np.testing.assert_array_equal(frames.images[1], np.repeat(grey[:, :, None], 3, axis=2))
    np.testing.assert_array_equal(frames.images[2], rgba[:, :, :3])  # alpha dropped
    np.testing.assert_array_equal(frames.images[0], rgb(0))


def test_16_bit_png_is_scaled_to_8_bits(tmp_path):
    folder = tmp_path / "deep"
    folder.mkdir()
    values = np.array([0, 1, 128, 257, 32767, 65535], np.uint16)
    image16 = np.broadcast_to(values[None, :, None], (2, 6, 3)).copy()
    write_png(folder / "a.png", image16)
    frames = read_frame_folder(folder)
    expected = np.round(values.astype(np.float64) * 255 / 65535).astype(np.uint8)
    np.testing.assert_array_equal(frames.images[0, 0, :, 0], expected)


def test_unreadable_file_is_named(tmp_path, monkeypatch):
    """The OS refusal is simulated (a chmod test would pass its open as root, i.e. in CI)."""
    folder = folder_of(tmp_path, 2)
    locked = folder / "img-001.png"

    def deny(path, *args, **kwargs):
        if Path(path) == locked:
            raise PermissionError(13, "Permission denied", str(path))
        return open(path, *args, **kwargs)

    monkeypatch.setattr(frames_module, "open", deny, raising=False)
    with raises_naming(locked, "permission denied"):
        read_frame_folder(folder)


def test_folder_of_one_frame_is_read(tmp_path):
    frames = read_frame_folder(folder_of(tmp_path, 1))
    assert frames.images.shape == (1, 12, 16, 3) and frames.names == ["img-000.png"]


def test_fewer_query_frames_than_ds_is_rejected_naming_the_folder_and_ds(tmp_path):
    reference = folder_of(tmp_path, 8, name="ref")
    query = folder_of(tmp_path, 4, name="qry")
    with pytest.raises(ValueError, match=re.escape(str(query)) + r".*ds=5"):
        match_folders(reference, query, params=SeqSLAMParams.defaults(ds=5, r_window=2),
                      out_dir=tmp_path / "out")
    assert not (tmp_path / "out" / "metrics.json").exists()


def test_match_command_reports_a_bad_folder_without_a_traceback(tmp_path, capsys):
    from cmal_lcd.commands import main

    reference = folder_of(tmp_path, 8, name="ref")
    code = main(["match", str(reference), str(tmp_path / "missing"), "--out",
                 str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code != 0
    assert str(tmp_path / "missing") in err and "Traceback" not in err
