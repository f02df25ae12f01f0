"""Frame-folder reader: order, conversions to uint8 RGB, poses.csv, and errors naming the file."""


import cv2
import numpy as np
import pytest

from cmal_lcd.data.frames import FrameReadError, list_frame_files, read_frame_folder
from image_files import png_header_only


def write_rgb(path, rgb):
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))


@pytest.fixture
def frames(tmp_path):
    """Four 8x12 RGB frames named out of order, plus an unrelated text file."""
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (4, 8, 12, 3), dtype=np.uint8)
    for name, image in zip(["f10.png", "f02.png", "f03.PNG", "f01.png"], images):
        write_rgb(tmp_path / name, image)
    (tmp_path / "notes.txt").write_text("not a frame")
    return tmp_path, dict(zip(["f10.png", "f02.png", "f03.PNG", "f01.png"], images))


def test_frames_are_read_as_rgb_sorted_by_name(frames):
    folder, images = frames
    result = read_frame_folder(folder)
    assert result.names == ["f01.png", "f02.png", "f03.PNG", "f10.png"]
    assert result.images.dtype == np.uint8 and result.images.shape == (4, 8, 12, 3)
    for name, image in zip(result.names, result.images):
        np.testing.assert_array_equal(image, images[name])  # PNG is lossless, channels RGB
    assert result.poses is None and len(result) == 4


def test_jpeg_files_are_read(tmp_path):
    write_rgb(tmp_path / "a.jpg", np.full((8, 8, 3), (200, 30, 30), np.uint8))
    write_rgb(tmp_path / "b.JPEG", np.full((8, 8, 3), (30, 30, 200), np.uint8))
    result = read_frame_folder(tmp_path)
    assert result.names == ["a.jpg", "b.JPEG"]
    assert result.images[0, 4, 4, 0] > 150 and result.images[1, 4, 4, 2] > 150  # RGB order


def test_grey_rgba_and_16_bit_images_become_8_bit_rgb(tmp_path):
    assert cv2.imwrite(str(tmp_path / "1_grey.png"), np.full((4, 4), 90, np.uint8))
    bgra = np.zeros((4, 4, 4), np.uint8)
    bgra[..., 2], bgra[..., 3] = 250, 7  # red, nearly transparent
    assert cv2.imwrite(str(tmp_path / "2_rgba.png"), bgra)
    assert cv2.imwrite(str(tmp_path / "3_deep.png"), np.full((4, 4, 3), 65535, np.uint16))
    assert cv2.imwrite(str(tmp_path / "4_deep_grey.png"), np.full((4, 4), 257 * 100, np.uint16))
    images = read_frame_folder(tmp_path).images
    assert (images[0] == 90).all()
    assert (images[1][..., 0] == 250).all() and (images[1][..., 1:] == 0).all()
    assert (images[2] == 255).all() and (images[3] == 100).all()


def test_poses_are_aligned_with_the_sorted_frames(frames):
    folder, _ = frames
    (folder / "poses.csv").write_text(
        "name,x,y,heading\nf10.png,10,1,0.5\nf01.png,1,1,0\nf03.PNG,3,1,0\nf02.png,2,1,0\n")
    poses = read_frame_folder(folder).poses
    assert list(poses["name"]) == ["f01.png", "f02.png", "f03.PNG", "f10.png"]
    np.testing.assert_array_equal(poses["x"], [1, 2, 3, 10])
    assert list(poses.columns) == ["name", "x", "y", "heading"]


def test_poses_frame_column_accepts_stems_or_positions(frames):
    folder, _ = frames
    (folder / "poses.csv").write_text("frame,x,y\nf01,0,0\nf02,1,0\nf03,2,0\nf10,3,0\n")
    np.testing.assert_array_equal(read_frame_folder(folder).poses["x"], [0, 1, 2, 3])
    (folder / "poses.csv").write_text("frame,x,y\n3,30,0\n2,20,0\n1,10,0\n0,0,0\n")
    np.testing.assert_array_equal(read_frame_folder(folder).poses["x"], [0, 10, 20, 30])


@pytest.mark.parametrize("text, message", [
    ("name,x,y\nf01.png,0,0\nf02.png,1,0\nf03.PNG,2,0\n", "no pose for 1 frame.*f10.png"),
    ("name,x,y\nf01.png,0,0\nf02.png,,0\nf03.PNG,2,0\nf10.png,3,0\n", "line 3: x"),
    ("name,x,y\nf01.png,0,0\nf01.png,1,0\nf03.PNG,2,0\nf10.png,3,0\n", "duplicate.*f01.png"),
    ("name,x,y\nf01.png,0,0\nf02.png,1,0\nf03.PNG,2,0\nf10.png,3,0\nzz.png,4,0\n",
     "'zz.png' is not an image"),
    ("name,east,north\nf01.png,0,0\n", "needs columns"),
])
def test_bad_poses_raise_naming_the_file_and_problem(frames, text, message):
    folder, _ = frames
    (folder / "poses.csv").write_text(text)
    with pytest.raises(FrameReadError, match=message) as info:
        read_frame_folder(folder)
    assert "poses.csv" in str(info.value)


def test_missing_folder(tmp_path):
    with pytest.raises(FrameReadError, match="no such frame folder"):
        read_frame_folder(tmp_path / "absent")


def test_empty_folder(tmp_path):
    (tmp_path / "readme.txt").write_text("no images here")
    with pytest.raises(FrameReadError, match="no image files"):
        read_frame_folder(tmp_path)


def test_frame_read_error_is_a_value_error():
    assert issubclass(FrameReadError, ValueError)


@pytest.mark.parametrize("make, message", [
    (lambda data: b"", "zero-byte"),
    (lambda data: data[: len(data) // 2], "truncated or corrupt PNG"),
    (lambda data: b"hello, I am text", "not a PNG or JPEG"),
    (lambda data: data[:8] + b"\x00" * 40 + data[-12:], "corrupt PNG"),
])
def test_bad_image_files_raise_naming_the_file(frames, make, message):
    folder, _ = frames
    data = (folder / "f02.png").read_bytes()
    (folder / "f02.png").write_bytes(make(data))
    with pytest.raises(FrameReadError, match=message) as info:
        read_frame_folder(folder)
    assert "f02.png" in str(info.value)


def test_truncated_jpeg_raises(tmp_path):
    rng = np.random.default_rng(1)
    write_rgb(tmp_path / "a.jpg", rng.integers(0, 256, (32, 32, 3), dtype=np.uint8))
    data = (tmp_path / "a.jpg").read_bytes()
    (tmp_path / "a.jpg").write_bytes(data[: len(data) - 200])
    with pytest.raises(FrameReadError, match="a.jpg.*truncated or corrupt JPEG"):
        read_frame_folder(tmp_path)


def test_mixed_sizes_name_the_first_odd_file_and_both_sizes(frames):
    folder, _ = frames
    write_rgb(folder / "f05.png", np.zeros((9, 12, 3), np.uint8))
    with pytest.raises(FrameReadError, match=r"f05.png.*12x9.*12x8.*f01.png"):
        read_frame_folder(folder)


def test_integer_names_sort_by_value_as_vpr_bench(tmp_path):
    """VPR-Bench's ``ref/``/``query/`` hold ``0.jpg, 1.jpg, ..., 10.jpg``: sorted by value
    (``evaluate_vpr_techniques.py``), not as strings; other names stay in name order."""
    for i in (0, 2, 10, 1):
        assert cv2.imwrite(str(tmp_path / f"{i}.png"), np.full((4, 4), 20 * i, np.uint8))
    assert list_frame_files(tmp_path) == [tmp_path / f"{i}.png" for i in (0, 1, 2, 10)]
    assert cv2.imwrite(str(tmp_path / "a.png"), np.zeros((4, 4), np.uint8))
    names = [p.name for p in list_frame_files(tmp_path)]
    assert names == ["0.png", "1.png", "10.png", "2.png", "a.png"]


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
@pytest.mark.parametrize("shape", [(8, 12, 3), (37, 5, 3), (300, 641, 3)])
def test_the_header_gives_the_size_the_decoder_finds(tmp_path, suffix, shape):
    from cmal_lcd.data.frames import header_size, read_image

    path = tmp_path / f"a{suffix}"
    write_rgb(path, np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8))
    assert header_size(path.read_bytes()) == shape[:2] == read_image(path).shape[:2]


def test_a_huge_first_frame_is_refused_from_its_header_naming_folder_and_sizes(tmp_path,
                                                                              monkeypatch):
    """A 20000 x 20000 PNG sorted first set the shape of the whole stack: numpy then said only
    "Unable to allocate 68.2 GiB" (issue 38). Its header says the size; nothing is decoded."""
    import cmal_lcd.data.frames as frames_module

    png_header_only(tmp_path / "0000.png", 20000, 20000)
    for i in range(1, 4):
        write_rgb(tmp_path / f"{i:04d}.png", np.zeros((8, 8, 3), np.uint8))
    monkeypatch.setattr(frames_module, "available_memory", lambda: 2 * 2**30)
    with pytest.raises(FrameReadError) as err:
        read_frame_folder(tmp_path)
    message = str(err.value)
    assert message.startswith(f"{tmp_path / '0000.png'}: an image of 20000x20000")
    assert "GiB of pixels, more than the 2.0 GiB of memory available" in message


def test_a_folder_too_large_for_memory_is_refused_before_its_stack_is_allocated(tmp_path,
                                                                                monkeypatch):
    import cmal_lcd.data.frames as frames_module

    for i in range(5):
        write_rgb(tmp_path / f"{i:04d}.png", np.zeros((100, 200, 3), np.uint8))
    # room for one frame's decode (11 bytes a pixel), not for the 5 x 60,000 bytes of the stack
    monkeypatch.setattr(frames_module, "available_memory", lambda: 250_000)
    with pytest.raises(FrameReadError, match=(
            rf"^{tmp_path}: 5 frames of 200x100 \(as 0000.png\): 293.0 KiB of pixels, more "
            r"than the 244.1 KiB of memory available; resize the frames first")):
        read_frame_folder(tmp_path)
    monkeypatch.setattr(frames_module, "available_memory", lambda: 300_000)
    assert read_frame_folder(tmp_path).images.shape == (5, 100, 200, 3)


def test_a_frame_of_another_size_is_refused_from_its_header_before_decoding(tmp_path):
    """The second frame claims 20000 x 20000 and holds no pixels: the size, not the decoder's
    failure, is what the message says."""
    write_rgb(tmp_path / "a.png", np.zeros((8, 8, 3), np.uint8))
    png_header_only(tmp_path / "b.png", 20000, 20000)
    with pytest.raises(FrameReadError, match=(
            rf"^{tmp_path / 'b.png'}: image size 20000x20000 \(width x height\) differs from "
            r"8x8 of a.png")):
        read_frame_folder(tmp_path)
