"""Split manifests (cmal_lcd.data.manifest) and ``cmal-lcd verify-manifest``."""

from __future__ import annotations

import hashlib
import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from cmal_lcd.commands import main as cli_main
from cmal_lcd.data.manifest import (MANIFEST_COLUMNS, ManifestError, pixels_sha256,
                                    read_manifest, verify_manifest)
from cmal_lcd.data.store import load_dataset
from cmal_lcd.stages import make_dataset

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "stages"))
from test_folders import config, write_frames  # noqa: E402


def folder_cfg(root: Path, **changes):
    data = config(root, **changes)
    return OmegaConf.create({"seed": 0, "data": data, "methods": ["sad"]})


@pytest.fixture
def seasons(tmp_path) -> Path:
    root = tmp_path / "frames"
    write_frames(root / "summer", 12, seed=1)
    write_frames(root / "winter", 12, seed=2)
    return root


@pytest.fixture
def built(seasons, tmp_path):
    """A folder dataset (train 1-6, validation 7-8, test 9-12 of both seasons) + manifest."""
    cfg = folder_cfg(seasons, **{"test.range": [9, 12]})
    cfg.data.validation = {"range": [7, 8]}
    out = make_dataset.main(cfg, out_dir=tmp_path / "dataset", manifest=tmp_path / "m.csv")
    return seasons, out, tmp_path / "m.csv", cfg


def test_folder_manifest_lists_every_frame_with_split_role_and_hashes(built):
    root, dataset_dir, manifest_path, _ = built
    manifest = read_manifest(manifest_path)
    ds = load_dataset(dataset_dir)
    used = manifest[manifest["split"] != "unused"]
    assert tuple(manifest.columns) == MANIFEST_COLUMNS
    np.testing.assert_array_equal(used["frame"], np.arange(len(ds)))
    assert used["split"].tolist() == ds.frames["split"].tolist()
    assert (used.groupby("split").size().to_dict() == {"train": 12, "val": 4, "test": 8})
    test = used[used["split"] == "test"]
    assert test["role"].tolist() == ["reference"] * 4 + ["query"] * 4
    assert test["index"].tolist() == [0, 1, 2, 3] * 2
    assert test["path"].iloc[0] == "summer/img-00009.png"
    assert used[used["split"] == "train"]["role"].eq("").all()
    for row in used.itertuples():
        assert row.file_sha256 == hashlib.sha256((root / row.path).read_bytes()).hexdigest()
        assert row.pixels_sha256 == pixels_sha256(ds.images[row.frame])
    assert manifest[manifest["split"] == "unused"].empty  # 1-12 all used in both seasons


def test_unselected_files_are_listed_as_unused(seasons, tmp_path):
    cfg = folder_cfg(seasons, **{"test.range": [9, 10]})
    make_dataset.main(cfg, out_dir=tmp_path / "d", manifest=tmp_path / "m.csv")
    unused = read_manifest(tmp_path / "m.csv").query("split == 'unused'")
    assert sorted(unused["path"]) == [f"{s}/img-{i:05d}.png" for s in ("summer", "winter")
                                      for i in (7, 8, 11, 12)]
    assert (unused["frame"] == -1).all() and (unused["file_sha256"] == "").all()


def test_writing_the_manifest_leaves_the_dataset_bytes_unchanged(built, tmp_path):
    _, dataset_dir, _, cfg = built
    plain = make_dataset.main(cfg, out_dir=tmp_path / "plain")
    for name in ("images.npy", "frames.csv", "dataset.json"):
        assert (plain / name).read_bytes() == (dataset_dir / name).read_bytes(), name
    assert not (tmp_path / "plain" / "manifest.csv").exists()


def test_same_config_gives_the_same_manifest_bytes(built, tmp_path):
    _, _, manifest_path, cfg = built
    make_dataset.main(cfg, out_dir=tmp_path / "again", manifest=tmp_path / "again.csv")
    assert (tmp_path / "again.csv").read_bytes() == manifest_path.read_bytes()


# ------------------------------------------------------------------------------ verification


def test_an_identical_folder_and_dataset_verify(built):
    root, dataset_dir, manifest_path, _ = built
    manifest = read_manifest(manifest_path)
    assert verify_manifest(manifest, root).ok
    assert verify_manifest(manifest, dataset_dir).ok


def test_changed_missing_and_extra_files_are_reported(built, tmp_path):
    root, _, manifest_path, _ = built
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    write_frames(copy / "winter", 1, seed=9, start=3)          # overwrite: changed
    (copy / "summer" / "img-00010.png").unlink()                # missing
    write_frames(copy / "summer", 1, seed=5, start=99)          # a new file: extra
    result = verify_manifest(read_manifest(manifest_path), copy)
    assert not result.ok
    assert [c.split("(")[1] for c in result.changed] == ["train, winter/img-00003.png)"]
    assert result.missing == ["frame 13 (test, summer/img-00010.png)"]  # after 12 train
    assert result.extra == ["summer/img-00099.png"]


def test_a_changed_dataset_frame_or_label_is_reported(built, tmp_path):
    _, dataset_dir, manifest_path, _ = built
    copy = tmp_path / "dataset_copy"
    shutil.copytree(dataset_dir, copy)
    images = np.load(copy / "images.npy")
    images[5, 0, 0, 0] ^= 1
    np.save(copy / "images.npy", images)
    result = verify_manifest(read_manifest(manifest_path), copy)
    assert len(result.changed) == 1 and result.changed[0].startswith("frame 5 ")
    manifest = read_manifest(manifest_path)
    result = verify_manifest(manifest[manifest["frame"] != 7], dataset_dir)
    assert result.extra == ["frame 7 (train)"]


def test_verify_manifest_command_exit_codes(built, tmp_path, capsys):
    root, dataset_dir, manifest_path, _ = built
    assert cli_main(["verify-manifest", str(manifest_path), str(root)]) == 0
    assert "OK" in capsys.readouterr().out
    (root / "winter" / "img-00001.png").unlink()
    assert cli_main(["verify-manifest", str(manifest_path), str(root)]) == 1
    out = capsys.readouterr().out
    assert "1 missing" in out and "winter/img-00001.png" in out
    assert cli_main(["verify-manifest", str(tmp_path / "none.csv"), str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "none.csv" in err
    assert cli_main(["verify-manifest", str(manifest_path), str(tmp_path / "nowhere")]) == 2
    assert "nowhere" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    assert cli_main(["verify-manifest", str(bad), str(dataset_dir)]) == 2
    assert "bad.csv" in capsys.readouterr().err


def test_a_world_manifest_cannot_be_checked_against_a_folder(tmp_path):
    manifest = pd.DataFrame([[0, "train", "", 0, "", "sunny", "", "", "00"]],
                            columns=MANIFEST_COLUMNS)
    (tmp_path / "x").mkdir()
    with pytest.raises(ManifestError, match="data/dataset"):
        verify_manifest(manifest, tmp_path / "x")


# ------------------------------------------------------------------------------- the world


def test_world_manifest_names_every_split_and_role(tmp_path):
    from test_make_dataset import tiny_cfg

    out = make_dataset.main(tiny_cfg(), out_dir=tmp_path / "dataset",
                            manifest=tmp_path / "m.csv")
    manifest = read_manifest(tmp_path / "m.csv")
    ds = load_dataset(out)
    assert len(manifest) == len(ds) and (manifest["path"] == "").all()
    roles = manifest.groupby("drive")["role"].first().to_dict()
    assert roles["route1/foggy"] == "reference"          # foggy-rainy, foggy-sunny
    assert roles["route1/rainy"] == "query;reference"    # query of foggy, reference of sunny
    assert roles["route1/sunny"] == "query"
    assert set(manifest["split"]) == {"train", "test", "val"}
    assert verify_manifest(manifest, out).ok


def test_stage_command_writes_the_manifest_beside_the_dataset_folder(seasons, tmp_path):
    params = tmp_path / "run" / "params.yaml"
    params.parent.mkdir()
    OmegaConf.save(folder_cfg(seasons), params)
    make_dataset.cli(["--params", str(params), "--out", str(tmp_path / "run" / "dataset")])
    manifest = read_manifest(tmp_path / "run" / "manifest.csv")
    assert verify_manifest(manifest, tmp_path / "run" / "dataset").ok
    assert verify_manifest(manifest, seasons).ok


@pytest.mark.parametrize("path", ["../../../../etc/passwd", "/etc/hostname",
                                  "summer/../../outside.png"])
def test_a_manifest_path_outside_its_root_is_refused_before_reading(built, tmp_path, capsys,
                                                                    path, monkeypatch):
    """Issue 38 item 8: ``path`` values ``../../../../etc/passwd`` and ``/etc/hostname`` were
    hashed and compared, and a folder outside the target was listed."""
    import pandas as pd

    root, _, manifest_path, _ = built
    table = pd.read_csv(manifest_path, dtype=str, keep_default_na=False)
    table.loc[0, "path"] = path
    table.to_csv(manifest_path, index=False)
    opened = []
    real_read = Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda self: opened.append(self) or real_read(self))
    assert cli_main(["verify-manifest", str(manifest_path), str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"manifest row 0 has path {path!r}" in err
    assert opened == []


@pytest.mark.parametrize("cell", ["abc", "-1", "2.5", ""])
@pytest.mark.parametrize("target", ["dataset", "folder"])
def test_a_frame_cell_that_is_not_a_frame_number_is_one_line_naming_its_line(
        built, tmp_path, capsys, cell, target):
    """Issue 38 item 11: a ``frame`` cell ``abc`` said only "invalid literal for int() with
    base 10: 'abc'"."""
    root, dataset_dir, manifest_path, _ = built
    lines = manifest_path.read_text().splitlines()
    used = next(n for n, line in enumerate(lines[1:], 1) if ",unused," not in line)
    lines[used] = cell + lines[used][lines[used].index(","):]
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    assert cli_main(["verify-manifest", str(bad),
                     str(dataset_dir if target == "dataset" else root)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and err.endswith(
        f"{bad}: line {used + 1}: frame {cell!r} is not a frame number (a non-negative "
        f"integer)"), err
