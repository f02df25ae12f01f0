"""A dataset in the store format from folders of real frames (``data.kind: folders``).

Layout read (see docs/real_data.md)::

    <train.dir>/<condition>/*.png      training frames, labelled by their sub-folder's name
    <test.dir>/<reference>/*.png       the reference drive of the one test route
    <test.dir>/<query>/*.png           the query drive (optionally ``poses.csv`` in each)

Frames of a folder are taken in frame order (:func:`cmal_lcd.data.frames.list_frame_files`:
sorted names, integer names by value; a Mapillary SLS side in ``seq_info.csv`` row order, its
drives recorded per test drive, :func:`drive_sequence_starts`) and selected by
``range: [first, last]`` (1-based positions in that order,
inclusive; ``last: null`` = to the end) and/or ``pattern`` (an ``fnmatch`` glob on the file
name). One folder may serve both splits (Nordland: frames 1-1,200 train, 1,201-1,800 test); a
frame selected by both splits is an error (:class:`FolderDatasetError`) naming the folder.

Documented behaviour on real-data problems:

- corrupt, truncated, zero-byte or non-image file: :class:`~cmal_lcd.data.frames.FrameReadError`
  naming the file (only selected files are read);
- frames of another size than ``image_size`` are resized (``cv2.INTER_AREA``); grey -> RGB;
- near-black (tunnel) frames are kept as they are; the matching library gives constant
  windows an infinite difference, so they never make a NaN (their count is logged and stored in
  ``dataset.json`` under ``dark_frames``);
- reference and query with different frame counts: ground truth by index pairs query ``q``
  with reference ``q`` when ``q < n_reference``; extra query frames have no true place
  (negatives); extra reference frames are simply never the true place;
- fewer than ``min_conditions`` training conditions (2 when CMAL is run): error naming the
  folder ("CMAL needs at least two conditions");
- a test drive whose folder name is not a training condition: error (every frame's condition
  must have a label).
"""

from __future__ import annotations

import fnmatch
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf

from cmal_lcd.data.frames import FrameReadError, list_frame_files, read_image, read_poses
from cmal_lcd.data.msls import is_msls_side
from cmal_lcd.data.store import FRAME_COLUMNS
from cmal_lcd.names import check_name, check_names
from cmal_lcd.schema import FOLDERS_KIND as KIND
from cmal_lcd.schema import GROUND_TRUTH_KINDS

logger = logging.getLogger(__name__)

#: A frame whose mean grey level is below this (0..255) is counted as dark (tunnel).
DARK_MEAN_LEVEL = 10.0


class FolderDatasetError(ValueError):
    """The frame folders or their configuration cannot make a dataset."""


# ----------------------------------------------------------------------------- paths

def resolve_folder(path: str | os.PathLike, *, root: str | os.PathLike | None = None) -> Path:
    """Resolve a configured folder.

    An absolute path is kept. A relative one is taken against ``root`` when given; otherwise
    against the working directory if it exists there, else against the repository root
    (:data:`cmal_lcd.config.REPO_ROOT`), so ``../shared/...`` works from DVC (cwd = repo root),
    the Hydra app (``job.chdir: false``) and tests run from anywhere.

    Returns
    -------
    Path
        The resolved path (not checked for existence when neither candidate exists: the reader
        then names it in its error).
    """
    from cmal_lcd.checkout import REPO_ROOT

    path = Path(os.path.expanduser(str(path)))
    if path.is_absolute():
        return path
    if root is not None:
        return resolve_folder(Path(os.path.expanduser(str(root))) / path)
    if path.exists():
        return path.resolve()
    return (REPO_ROOT / path).resolve()


# ----------------------------------------------------------------------------- selection

def select_files(files: Sequence[Path], *, frame_range: Sequence[int | None] | None = None,
                 pattern: str | None = None, where: str = "range") -> list[Path]:
    """The files of a folder selected by position range and/or name pattern.

    Parameters
    ----------
    files : sequence of Path
        Sorted file list of one folder.
    frame_range : [first, last] or None
        1-based positions, inclusive; ``last`` ``None`` = to the end. ``None``: every file.
    pattern : str or None
        ``fnmatch`` glob on the file name, applied after the range.
    where : str
        The parameter name used in errors (e.g. ``data.train.range``).

    Raises
    ------
    FolderDatasetError
        When the range is malformed or beyond the files, or nothing is selected.
    """
    files = list(files)
    folder = files[0].parent if files else Path("?")
    if frame_range is not None:
        if len(frame_range) != 2:
            raise FolderDatasetError(f"{where}: expected [first, last], got {list(frame_range)}")
        first, last = frame_range
        last = len(files) if last is None else last
        if not (isinstance(first, (int, np.integer)) and isinstance(last, (int, np.integer))):
            raise FolderDatasetError(f"{where}: first and last must be integers, got "
                                     f"{list(frame_range)}")
        if first < 1 or last < first:
            raise FolderDatasetError(f"{where}: need 1 <= first <= last, got [{first}, {last}]")
        if last > len(files):
            raise FolderDatasetError(f"{where}: [{first}, {last}] goes beyond the {len(files)} "
                                     f"frames of {folder} (use null as last for 'to the end')")
        files = files[first - 1:last]
    if pattern:
        files = [f for f in files if fnmatch.fnmatch(f.name, pattern)]
    if not files:
        raise FolderDatasetError(f"{where}: selects no frame of {folder} "
                                 f"(range {frame_range}, pattern {pattern!r})")
    return files


def check_disjoint(train: Mapping[Path, Sequence[Path]], test: Mapping[Path, Sequence[Path]],
                   *, keys: tuple[str, str] = ("data.train.range", "data.test.range")) -> None:
    """No file is selected for both training and test.

    Parameters
    ----------
    train, test : mapping folder -> selected files
    keys : (str, str)
        The config keys of the two selections, named in the error.

    Raises
    ------
    FolderDatasetError
        Naming the folder, the number of shared frames and the first one.
    """
    for folder, test_files in test.items():
        shared = sorted({f.resolve() for f in test_files}
                        & {f.resolve() for f in train.get(folder, ())})
        if shared:
            raise FolderDatasetError(
                f"{keys[0]} / {keys[1]}: the selections overlap: {len(shared)} "
                f"frame(s) of {folder} are selected by both (first {shared[0].name}); no test "
                f"or validation frame may be seen in training, nor a test frame in validation")


# ----------------------------------------------------------------------------- images

def load_frames(files: Sequence[Path], *, image_size: Sequence[int]) -> np.ndarray:
    """Read frames and bring them to ``image_size``.

    Parameters
    ----------
    files : sequence of Path
    image_size : [H, W]

    Returns
    -------
    ndarray, uint8 (N, H, W, 3)
        RGB (grey repeated over channels); frames of another size resized with
        ``cv2.INTER_AREA``.

    Raises
    ------
    FrameReadError
        Naming a corrupt or unreadable file.
    """
    import cv2

    h, w = (int(v) for v in image_size)
    out = np.empty((len(files), h, w, 3), np.uint8)
    resized = 0
    for i, file in enumerate(files):
        image = read_image(file)
        if image.shape[:2] != (h, w):
            image = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
            resized += 1
        out[i] = image
    if resized:
        logger.info("resized %d of %d frames to %dx%d (HxW)", resized, len(files), h, w)
    return out


def dark_frame_mask(images: np.ndarray, *, level: float = DARK_MEAN_LEVEL) -> np.ndarray:
    """Near-black (tunnel) frames: mean over pixels and channels below ``level``.

    Parameters
    ----------
    images : ndarray, uint8 (N, H, W, 3)

    Returns
    -------
    ndarray, bool (N,)
    """
    if len(images) == 0:
        return np.zeros(0, bool)
    return np.asarray(images, np.float32).reshape(len(images), -1).mean(axis=1) < level


# ----------------------------------------------------------------------------- config

def _recorded(folder: Path) -> str:
    """A folder as written to ``dataset.json``: relative to the repository root (portable)."""
    from cmal_lcd.checkout import REPO_ROOT

    return os.path.relpath(folder, REPO_ROOT)


def _plain(cfg: Any) -> dict:
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)
    return dict(cfg)


def _require(node: Mapping[str, Any], key: str, *, where: str) -> Any:
    value = node.get(key)
    if value is None or value == "???":
        raise FolderDatasetError(f"{where}.{key}: required (set it in conf/data/ or override "
                                 f"it, e.g. {where}.{key}=...)")
    return value


def _range(value: Any) -> list | None:
    return None if value is None else list(value)


def training_conditions(train_dir: Path, conditions: Sequence[str] | None) -> list[str]:
    """Condition names in label order: the configured list, else sorted sub-folder names.

    Raises
    ------
    FolderDatasetError
        When the folder is missing, or a configured condition has no sub-folder.
    """
    if not train_dir.is_dir():
        raise FolderDatasetError(f"data.train.dir: {train_dir} is not a folder")
    if conditions:
        names = [str(c) for c in conditions]
        if len(set(names)) != len(names):
            raise FolderDatasetError(f"data.conditions: duplicate names in {names}")
        missing = [c for c in names if not (train_dir / c).is_dir()]
        if missing:
            raise FolderDatasetError(f"data.conditions: no sub-folder {missing} in {train_dir}")
        return names
    return sorted(p.name for p in train_dir.iterdir()
                  if p.is_dir() and not p.name.startswith("."))


# ----------------------------------------------------------------------------- checks

def _checked_settings(cfg: Mapping[str, Any]) -> tuple[list[int], str]:
    """``(image_size [H, W], ground_truth)`` after checking ``data.kind``, both, and that
    ``ground_truth: file`` names its ``ground_truth_file``."""
    kind = cfg.get("kind", KIND)
    if kind != KIND:
        raise FolderDatasetError(f"data.kind: expected {KIND!r}, got {kind!r}")
    image_size = [int(v) for v in _require(cfg, "image_size", where="data")]
    if len(image_size) != 2 or min(image_size) < 1:
        raise FolderDatasetError(f"data.image_size: expected [H, W] > 0, got {image_size}")
    ground_truth = cfg.get("ground_truth", "index")
    if ground_truth not in GROUND_TRUTH_KINDS:
        raise FolderDatasetError(f"data.ground_truth: expected one of {GROUND_TRUTH_KINDS}, "
                                 f"got {ground_truth!r}")
    if ground_truth == "file":
        _require(cfg, "ground_truth_file", where="data")
    return image_size, ground_truth


# ----------------------------------------------------------------------------- ground truth

def pair_ground_truth(cfg: Mapping[str, Any], *, ground_truth: str, test_dir: Path,
                      names: tuple[str, str], listed: _Selection,
                      splits: Sequence[tuple[str, str, _Selection]]
                      ) -> tuple[dict, list[dict]]:
    """``(ground_truth_source, ground_truth_sets)`` of ``dataset.json`` for ``file``, ``utm``
    and ``msls`` ground truth (``({}, [])`` otherwise).

    The file (or the UTM names, or the MSLS CSVs) describes the whole reference and query
    folders; each split's
    pair gets the part between its selected frames, renumbered from 0
    (:meth:`~cmal_lcd.data.ground_truth.ReferenceSets.subset`).

    Raises
    ------
    FolderDatasetError
        Naming ``data.ground_truth_file`` (unreadable, other frame counts) or the file whose
        name carries no UTM coordinates.
    """
    if ground_truth not in ("file", "utm", "msls"):
        return {}, []
    from cmal_lcd.data import gt_files

    ref_folder, query_folder = (test_dir / name for name in names)
    n_ref, n_query = len(listed[ref_folder]), len(listed[query_folder])
    described: dict[str, Any] = {}
    try:
        if ground_truth == "file":
            path = resolve_folder(cfg["ground_truth_file"], root=cfg.get("root"))
            full = gt_files.read_ground_truth_file(path, n_reference=n_ref, n_query=n_query,
                                                   name=_recorded(path))
            described["sha256"] = _sha256(path)
        elif ground_truth == "msls":
            full = gt_files.msls_ground_truth(
                ref_folder, query_folder, radius=cfg.get("positive_dist_threshold"),
                names=(_recorded(ref_folder), _recorded(query_folder)))
        else:
            full = gt_files.utm_ground_truth(
                [f.name for f in listed[ref_folder]], [f.name for f in listed[query_folder]],
                reference_dir=_recorded(ref_folder), query_dir=_recorded(query_folder),
                radius=cfg.get("positive_dist_threshold"))
    except ValueError as err:
        raise FolderDatasetError(f"data.ground_truth_file: {err}" if ground_truth == "file"
                                 else f"data.ground_truth: {err}") from None
    described = {**gt_files.describe_ground_truth(full), **described}
    entries = []
    for _, split_route, selection in splits:
        if not selection:
            continue
        rows = [_positions(listed[folder], selection[folder])
                for folder in (ref_folder, query_folder)]
        arrays = full.subset(*rows).to_arrays()
        entries.append({"reference": f"{split_route}/{names[0]}",
                        "query": f"{split_route}/{names[1]}",
                        **{key: value.tolist() for key, value in arrays.items()}})
    return described, entries


def drive_sequence_starts(folder: Path, listed: Sequence[Path],
                          selected: Sequence[Path]) -> list[int] | None:
    """Rows of a drive's ``selected`` frames where a sequence starts, when ``folder`` is a
    Mapillary SLS side (:mod:`cmal_lcd.data.msls`), else None (one sequence).

    A sequence starts at row 0, where the frame's MSLS sequence changes, and where the
    selection skips a frame (its frames would no longer be consecutive).
    """
    if not is_msls_side(folder):
        return None
    from cmal_lcd.data.msls import read_msls_side

    rows = _positions(listed, selected)
    numbers = read_msls_side(folder).sequences[rows]
    new = np.ones(len(rows), dtype=bool)
    new[1:] = (numbers[1:] != numbers[:-1]) | (np.diff(rows) != 1)
    return np.flatnonzero(new).tolist()


def _positions(listed: Sequence[Path], selected: Sequence[Path]) -> np.ndarray:
    """0-based positions of ``selected`` in ``listed`` (both in frame order)."""
    position = {f.name: i for i, f in enumerate(listed)}
    return np.asarray([position[f.name] for f in selected], dtype=np.int64)


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def _test_drive_names(test_cfg: Mapping[str, Any]) -> tuple[str, str, str]:
    """``(route, reference, query)`` of ``data.test``, each required and a safe name."""
    route = check_name(str(_require(test_cfg, "route", where="data.test")),
                       key="data.test.route")
    reference = check_name(str(_require(test_cfg, "reference", where="data.test")),
                           key="data.test.reference")
    query = check_name(str(_require(test_cfg, "query", where="data.test")),
                       key="data.test.query")
    return route, reference, query


def _labelled_conditions(train_dir: Path | None, configured: Sequence[str] | None, *,
                         reference: str, query: str, min_conditions: int) -> list[str]:
    """Training conditions in label order; enough of them, and labels for both test drives.
    Without training frames (``train_dir`` None): ``configured``, else the two test drives'
    folder names (reference, query)."""
    if train_dir is None:
        conditions = list(configured) if configured else [reference, query]
    else:
        conditions = training_conditions(train_dir, configured)
    check_names(conditions, key="data.conditions")
    if len(conditions) < min_conditions:
        raise FolderDatasetError(
            f"{train_dir}: {len(conditions)} condition sub-folder(s) {conditions}; CMAL needs at "
            f"least two conditions (one sub-folder per condition, e.g. summer/ and winter/)")
    if reference == query:
        raise FolderDatasetError(f"data.test.query: the same folder as the reference "
                                 f"({reference!r})")
    for name, where in ((reference, "reference"), (query, "query")):
        if name not in conditions:
            raise FolderDatasetError(f"data.test.{where}: {name!r} is not a training condition "
                                     f"{conditions}; every test frame needs a condition label")
    return conditions


# ----------------------------------------------------------------------------- split selection

_Selection = dict[Path, list[Path]]


def _list_and_select(parent: Path, names: Sequence[str], node: Mapping[str, Any], *,
                     where: str) -> tuple[_Selection, _Selection]:
    """``(listed, selected)``: every frame file of each ``parent/name`` and those that the
    ``range`` / ``pattern`` of ``node`` select, keyed by folder in ``names`` order."""
    listed: _Selection = {}
    selected: _Selection = {}
    for name in names:
        folder = parent / name
        listed[folder] = list_frame_files(folder)
        selected[folder] = select_files(listed[folder], frame_range=_range(node.get("range")),
                                        pattern=node.get("pattern"), where=where)
    return listed, selected


def _select_validation(val_cfg: Mapping[str, Any], listed: _Selection, *,
                       pattern: str | None) -> _Selection:
    """The ``data.validation.range`` frames of each test drive folder (``{}`` when unset)."""
    if not val_cfg:
        return {}
    return {folder: select_files(files, frame_range=_range(val_cfg.get("range")),
                                 pattern=pattern, where="data.validation.range")
            for folder, files in listed.items()}


def _check_splits_disjoint(train: _Selection, test: _Selection, validation: _Selection) -> None:
    """No frame selected by two of training, test and validation (folders compared resolved)."""
    resolved = {split: {k.resolve(): v for k, v in files.items()}
                for split, files in (("train", train), ("test", test),
                                     ("validation", validation))}
    check_disjoint(resolved["train"], resolved["test"])
    check_disjoint(resolved["train"], resolved["validation"],
                   keys=("data.train.range", "data.validation.range"))
    check_disjoint(resolved["validation"], resolved["test"],
                   keys=("data.validation.range", "data.test.range"))


# ----------------------------------------------------------------------------- dataset

def _rows(n: int, *, split: str, route: str, drive: str, condition: str,
          poses: pd.DataFrame | None) -> pd.DataFrame:
    nan = np.full(n, np.nan)
    table = {"frame": np.zeros(n, np.int64), "split": [split] * n, "route": [route] * n,
             "drive": [drive] * n, "condition": [condition] * n, "x": nan, "y": nan,
             "heading": nan, "time": nan, "s": nan}
    if poses is not None:
        for column in ("x", "y", "heading", "time"):
            if column in poses:
                table[column] = poses[column].to_numpy(np.float64)
    return pd.DataFrame(table, columns=list(FRAME_COLUMNS))


def _poses_for(folder: Path, all_files: Sequence[Path], selected: Sequence[Path], *,
               required: bool) -> pd.DataFrame | None:
    """Poses of the selected frames from ``folder/poses.csv`` (``None`` if absent, allowed)."""
    path = folder / "poses.csv"
    if not path.is_file():
        if required:
            raise FolderDatasetError(f"{folder}: data.ground_truth is 'poses' but the folder "
                                     f"has no poses.csv (columns name, x, y)")
        return None
    poses = read_poses(path, [f.name for f in all_files])
    position = {f.name: i for i, f in enumerate(all_files)}
    return poses.iloc[[position[f.name] for f in selected]].reset_index(drop=True)


def index_positions(all_files: Sequence[Path], selected: Sequence[Path]) -> pd.DataFrame:
    """Stand-in poses for folders paired by index: ``x`` = 1-based position, ``y = heading = 0``.

    With ``data.train.paired_by_index: true`` (the same place at the same sorted position in
    every condition folder, as on Nordland), training frames get these, so the CMAL
    reconstruction figure (Fig. 11) can show the real frame of the same place under the other
    condition. Units are frames, not metres; test frames never get them.

    Returns
    -------
    DataFrame
        Columns ``x, y, heading``, one row per selected file.
    """
    position = {f.name: i + 1 for i, f in enumerate(all_files)}
    x = np.asarray([position[f.name] for f in selected], np.float64)
    return pd.DataFrame({"x": x, "y": np.zeros_like(x), "heading": np.zeros_like(x)})


@dataclass
class _Parts:
    """The dataset in row order: image ``blocks`` (each uint8 (N_i, H, W, 3)), frame-row
    ``tables`` (one DataFrame per block), and the ``sources`` and ``drives`` of dataset.json."""

    blocks: list[np.ndarray] = field(default_factory=list)
    tables: list[pd.DataFrame] = field(default_factory=list)
    sources: list[dict] = field(default_factory=list)
    drives: list[dict] = field(default_factory=list)


def _load_selected(files: Sequence[Path], *, image_size: Sequence[int],
                   record: dict | None) -> np.ndarray:
    """The frames of ``files``, uint8 (N, H, W, 3); ``files`` appended to ``record["files"]``."""
    block = load_frames(files, image_size=image_size)
    if record is not None:
        record.setdefault("files", []).extend(files)
    return block


def _source(folder: Path, files: Sequence[Path], listed: Sequence[Path], **label: str) -> dict:
    """A ``sources`` entry: ``label`` items, then the folder, frame count, first and last file,
    and ``positions``: each frame's 0-based place among every frame file of the folder in frame
    order (``listed``), the row of a descriptor file made for the whole folder."""
    place = {f: i for i, f in enumerate(listed)}
    return {**label, "folder": _recorded(folder), "frames": len(files), "first": files[0].name,
            "last": files[-1].name, "positions": [place[f] for f in files]}


def _add_training(parts: _Parts, train_dir: Path | None, conditions: Sequence[str], listed: _Selection,
                  selected: _Selection, *, paired_by_index: Any, image_size: Sequence[int],
                  record: dict | None) -> None:
    """Append the training frames to ``parts``, condition by condition in label order
    (none when ``train_dir`` is None)."""
    for condition in conditions if train_dir is not None else ():
        folder = train_dir / condition
        files = selected[folder]
        parts.blocks.append(_load_selected(files, image_size=image_size, record=record))
        poses = _poses_for(folder, listed[folder], files, required=False)
        if poses is None and paired_by_index:
            poses = index_positions(listed[folder], files)
        parts.tables.append(_rows(len(files), split="train", route="", drive="",
                                  condition=condition, poses=poses))
        parts.sources.append(_source(folder, files, listed[folder], split="train",
                                     condition=condition))


def _add_drives(parts: _Parts, test_dir: Path, names: Sequence[str], listed: _Selection,
                splits: Sequence[tuple[str, str, _Selection]], *, ground_truth: str,
                image_size: Sequence[int], record: dict | None) -> None:
    """Append the drives ``names`` (reference, query) of each ``(split, route, selection)``
    in ``splits`` with a non-empty selection to ``parts``."""
    for split, split_route, selection in splits:
        for name in names if selection else ():
            folder = test_dir / name
            files = selection[folder]
            drive = f"{split_route}/{name}"
            parts.blocks.append(_load_selected(files, image_size=image_size, record=record))
            poses = _poses_for(folder, listed[folder], files,
                               required=ground_truth == "poses")
            parts.tables.append(_rows(len(files), split=split, route=split_route, drive=drive,
                                      condition=name, poses=poses))
            parts.sources.append(_source(folder, files, listed[folder], split=split, drive=drive))
            entry = {"name": drive, "route": split_route, "condition": name,
                     "frames": len(files)}
            starts = drive_sequence_starts(folder, listed[folder], files)
            if starts is not None:
                entry["sequence_starts"] = starts
            parts.drives.append(entry)


def _warn_unequal_drives(drives: Sequence[dict], ground_truth: str) -> None:
    """Warn when, paired by index, the test query has another frame count than the reference."""
    n_ref, n_query = drives[0]["frames"], drives[1]["frames"]
    if ground_truth == "index" and n_ref != n_query:
        logger.warning("reference %s has %d frames, query %s has %d: by index, query frames "
                       "from %d on have no true place (negatives)", drives[0]["name"], n_ref,
                       drives[1]["name"], n_query, n_ref)


def _numbered_frames(tables: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """The frame rows of all blocks, ``frame`` numbered 0..N-1 in row order."""
    frames = pd.concat(tables, ignore_index=True)
    frames["frame"] = np.arange(len(frames), dtype=np.int64)
    return frames


def _count_dark_frames(images: np.ndarray, frames: pd.DataFrame) -> dict[str, int]:
    """Near-black frames of ``images`` uint8 (N, H, W, 3) per split (logged when any)."""
    dark = dark_frame_mask(images)
    dark_by_split = {s: int(dark[frames["split"].to_numpy() == s].sum())
                     for s in ("train", "test", "val")}
    if dark.any():
        logger.info("%d near-black (tunnel) frames kept (train %d, test %d)", int(dark.sum()),
                    dark_by_split["train"], dark_by_split["test"])
    return dark_by_split


def _metadata(cfg: dict, parts: _Parts, *, seed: int, image_size: list[int],
              ground_truth: str, conditions: list[str], route: str, val_route: str,
              pair: str, validation: bool, dark_by_split: dict[str, int],
              truth_sets: tuple[dict, list[dict]] = ({}, [])) -> dict:
    """``dataset.json``'s content (test drives are ``parts.drives[:2]``, validation ``[2:4]``)."""
    drives = parts.drives
    return {
        "kind": KIND,
        "image_size": image_size,
        "conditions": conditions,
        "routes": [route],
        "drives": drives,
        "pairs": [[route, drives[0]["name"], drives[1]["name"], pair]],
        "validation_routes": [val_route] if validation else [],
        "validation_pairs": ([[val_route, drives[2]["name"], drives[3]["name"], pair]]
                             if validation else []),
        "ground_truth": ground_truth,
        **({"ground_truth_source": truth_sets[0], "ground_truth_sets": truth_sets[1]}
           if truth_sets[1] else {}),
        "sources": parts.sources,
        "dark_frames": {"level": DARK_MEAN_LEVEL, **dark_by_split},
        "seed": int(seed),
        "config": cfg,
    }


def _log_summary(frames: pd.DataFrame, conditions: Sequence[str], drives: Sequence[dict]
                 ) -> None:
    """Log the training frame count and conditions and the two test drives' frame counts."""
    logger.info("folder dataset: %d training frames (%s), test %s %d + %s %d frames",
                int((frames["split"] == "train").sum()), ", ".join(conditions),
                drives[0]["name"], drives[0]["frames"], drives[1]["name"], drives[1]["frames"])


def _select_splits(cfg: Mapping[str, Any], train_cfg: Mapping[str, Any],
                   test_cfg: Mapping[str, Any], train_dir: Path | None, test_dir: Path,
                   conditions: Sequence[str], drives: Sequence[str]
                   ) -> tuple[_Selection, _Selection, _Selection, _Selection, _Selection]:
    """``(listed train, selected train, listed test, selected test, selected validation)``:
    the frame files of the condition and drive folders, the selections checked disjoint."""
    all_train, train_files = ({}, {}) if train_dir is None else _list_and_select(
        train_dir, conditions, train_cfg, where="data.train.range")
    all_test, test_files = _list_and_select(test_dir, drives, test_cfg,
                                            where="data.test.range")
    val_files = _select_validation(cfg.get("validation") or {}, all_test,
                                   pattern=test_cfg.get("pattern"))
    _check_splits_disjoint(train_files, test_files, val_files)
    return all_train, train_files, all_test, test_files, val_files


def _assembled(cfg: dict, parts: _Parts, *, seed: int, image_size: list[int],
               ground_truth: str, conditions: list[str], route: str, val_route: str,
               pair: str, validation: bool, truth_sets: tuple[dict, list[dict]] = ({}, [])
               ) -> tuple[np.ndarray, pd.DataFrame, dict]:
    """``(images uint8 (N, H, W, 3), frames, meta)`` from the loaded ``parts``; counts the dark
    frames and logs the summary."""
    images = np.concatenate(parts.blocks, axis=0)
    frames = _numbered_frames(parts.tables)
    dark_by_split = _count_dark_frames(images, frames)
    meta = _metadata(cfg, parts, seed=seed, image_size=image_size, ground_truth=ground_truth,
                     conditions=conditions, route=route, val_route=val_route, pair=pair,
                     validation=validation, dark_by_split=dark_by_split,
                     truth_sets=truth_sets)
    _log_summary(frames, conditions, parts.drives)
    return images, frames, meta


def _record_listed(record: dict, listings: Sequence[_Selection], *, dirs: list[Path]) -> None:
    """Set ``record["listed"]`` (every file of ``listings``' folders, in order) and
    ``record["dirs"]``."""
    record["listed"] = [f for listing in listings for listed in listing.values()
                        for f in listed]
    record["dirs"] = dirs


def build_folder_dataset(data_cfg: Mapping[str, Any], *, seed: int, min_conditions: int = 2,
                         record: dict | None = None
                         ) -> tuple[np.ndarray, pd.DataFrame, dict]:
    """Build the store's ``(images, frames, meta)`` from frame folders.

    Parameters
    ----------
    data_cfg : mapping
        The ``data`` node (conf/data/folders.yaml): ``image_size [H, W]``, ``root``,
        ``conditions``, ``ground_truth``, ``train {dir, range, pattern}`` (or ``train: null``:
        no training frames; the conditions are then ``conditions`` or the two test folders'
        names),
        ``test {dir, route, reference, query, range, pattern}``; ``train.paired_by_index``
        (see :func:`index_positions`).
    seed : int
        Recorded in ``meta`` (the selection itself is deterministic and draws nothing).
    min_conditions : int
        Fewest training conditions accepted (2 when CMAL is trained).
    record : dict, optional
        When given, receives the sources for a split manifest (:mod:`cmal_lcd.data.manifest`):
        ``files`` (the source file of every frame, in row order), ``listed`` (every image file
        of the folders read) and ``dirs`` (``[train_dir, test_dir]``). Outputs do not change.

    Returns
    -------
    images : ndarray, uint8 (N, H, W, 3)
        Training frames (condition by condition, in label order), then the reference drive,
        then the query drive.
    frames : DataFrame
        Columns :data:`cmal_lcd.data.store.FRAME_COLUMNS`; ``x, y`` (and ``heading, time``)
        from ``poses.csv`` when present, else from :func:`index_positions` for training frames
        of ``paired_by_index`` folders, else NaN; ``s`` NaN.
    meta : dict
        ``kind="folders"``, ``image_size``, ``conditions``, ``routes``, ``drives``, ``pairs``,
        ``ground_truth``, ``sources``, ``dark_frames``, ``seed``, ``config``.

    Raises
    ------
    FolderDatasetError
        For a bad configuration, too few conditions, or overlapping train/test selections.
    FrameReadError
        For a missing folder or a corrupt image.
    """
    cfg = _plain(data_cfg)
    image_size, ground_truth = _checked_settings(cfg)
    root = cfg.get("root")
    train_cfg = cfg.get("train") or {}
    test_cfg = cfg.get("test") or {}
    # data.train: null: no training frames (methods that train nothing)
    train_dir = None if cfg.get("train", {}) is None else resolve_folder(
        _require(train_cfg, "dir", where="data.train"), root=root)
    test_dir = resolve_folder(_require(test_cfg, "dir", where="data.test"), root=root)
    route, reference, query = _test_drive_names(test_cfg)
    conditions = _labelled_conditions(train_dir, cfg.get("conditions"), reference=reference,
                                      query=query, min_conditions=min_conditions)

    all_train, train_files, all_test, test_files, val_files = _select_splits(
        cfg, train_cfg, test_cfg, train_dir, test_dir, conditions, (reference, query))

    val_route = f"{route}_val"
    splits = (("test", route, test_files), ("val", val_route, val_files))
    truth_sets = pair_ground_truth(cfg, ground_truth=ground_truth, test_dir=test_dir,
                                   names=(reference, query), listed=all_test, splits=splits)
    parts = _Parts()
    _add_training(parts, train_dir, conditions, all_train, train_files,
                  paired_by_index=train_cfg.get("paired_by_index"), image_size=image_size,
                  record=record)
    _add_drives(parts, test_dir, (reference, query), all_test, splits,
                ground_truth=ground_truth, image_size=image_size, record=record)
    _warn_unequal_drives(parts.drives, ground_truth)

    images, frames, meta = _assembled(cfg, parts, seed=seed, image_size=image_size,
                                      ground_truth=ground_truth, conditions=conditions,
                                      route=route, val_route=val_route,
                                      pair=f"{reference}-{query}", validation=bool(val_files),
                                      truth_sets=truth_sets)
    if record is not None:
        _record_listed(record, (all_train, all_test),
                       dirs=[d for d in (train_dir, test_dir) if d is not None])
    return images, frames, meta


def main_folders(cfg: DictConfig, *, out_dir: str | Path, min_conditions: int,
                 record: dict | None = None) -> Path:
    """Stage ``dataset`` for ``data.kind: folders``: build and save the dataset to ``out_dir``.

    Parameters
    ----------
    cfg : DictConfig
        The composed config (``seed``, ``data``).
    out_dir : str or Path
    min_conditions : int
        Training conditions the folders must have: 2 when a configured method trains a model
        that learns every condition (:func:`cmal_lcd.features.needs_two_conditions`), else 1.
    record : dict, optional
        Filled with the manifest sources (see :func:`build_folder_dataset`).

    Returns
    -------
    Path
        ``out_dir``.
    """
    from cmal_lcd.data.store import save_dataset

    images, frames, meta = build_folder_dataset(
        cfg.data, seed=cfg.seed, min_conditions=min_conditions,
        record=record)
    save_dataset(out_dir, images, frames, meta)
    return Path(out_dir)


__all__ = ["FolderDatasetError", "FrameReadError", "build_folder_dataset", "check_disjoint",
           "dark_frame_mask", "index_positions", "load_frames", "main_folders", "resolve_folder",
           "select_files", "training_conditions"]
