"""Precomputed descriptors as a pipeline method: one descriptor file per frame folder.

A user's method node (:mod:`cmal_lcd.features.custom`) whose target is
:class:`DescriptorFolder` looks codes up instead of computing them::

    extractors:
      netvlad:
        _target_: cmal_lcd.features.precomputed.DescriptorFolder
        inputs: descriptors/netvlad     # the stage depends on this folder
        key: null                       # array key for .npz/.mat/.h5 (null: the only one)
        label: NetVLAD (precomputed)

``descriptors/netvlad/`` holds one file per frame folder of the dataset, named after the folder
(``ref.npy`` for ``<test.dir>/ref/``; any of ``.npy``, ``.npz``, ``.mat``, ``.h5``, read by
:func:`cmal_lcd.data.descriptors.read_descriptors`), whose row ``i`` is the folder's ``i``-th
frame file in frame order (as ``cmal-lcd match`` reads a folder), every file of the folder,
whatever ``range`` selects: the dataset records each frame's place in its folder
(``dataset.json`` ``sources[].positions``). Only ``data.kind: folders`` datasets have folders;
a training condition folder without a file gives no training codes (the matching protocol then
cannot centre by condition). Nothing is timed (Table III says so).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

#: Descriptor file suffixes looked for, in this order.
SUFFIXES = (".npy", ".npz", ".mat", ".h5")


class MissingDescriptorFile(LookupError):
    """No descriptor file for a frame folder (a :class:`LookupError`: the features stage then
    stores no training codes instead of failing)."""


class DescriptorFolder:
    """Codes of dataset frames from ``<inputs>/<folder name>.<suffix>`` files.

    Parameters
    ----------
    inputs : path
        The folder of descriptor files (relative: to the working directory, the checkout
        root for DVC stages).
    key : str, optional
        The array in each file (:func:`~cmal_lcd.data.descriptors.read_descriptors`).
    """

    def __init__(self, inputs: str, key: str | None = None) -> None:
        self.folder = Path(inputs)
        if not self.folder.is_dir():
            raise ValueError(f"inputs: {self.folder} is not a folder of descriptor files")
        self.key = key
        self._cache: dict[str, np.ndarray] = {}

    def file_for(self, name: str) -> Path | None:
        """The descriptor file of frame folder ``name``, or None."""
        found = [self.folder / f"{name}{suffix}" for suffix in SUFFIXES
                 if (self.folder / f"{name}{suffix}").is_file()]
        if len(found) > 1:
            raise ValueError(f"{self.folder}: {len(found)} descriptor files for folder "
                             f"{name!r} ({', '.join(p.name for p in found)}); keep one")
        return found[0] if found else None

    def descriptors(self, name: str) -> np.ndarray:
        """``(n_files, D)`` of frame folder ``name`` (read once)."""
        if name not in self._cache:
            from cmal_lcd.data.descriptors import read_descriptors

            path = self.file_for(name)
            if path is None:  # LookupError: the stage stores no training codes then
                raise MissingDescriptorFile(
                    f"{self.folder}: no descriptor file for frame folder {name!r} "
                    f"({' or '.join(name + s for s in SUFFIXES)})")
            self._cache[name] = read_descriptors(path, key=self.key)
        return self._cache[name]

    def codes(self, sources: Sequence[Mapping[str, Any]], frame_ids: np.ndarray) -> np.ndarray:
        """``float32 (len(frame_ids), D)``: the rows of the dataset frames ``frame_ids``.

        Parameters
        ----------
        sources : sequence of mapping
            ``dataset.json`` ``sources``, in frame order (each ``folder``, ``frames``,
            ``positions``).
        frame_ids : ndarray of int
            Global frame numbers (``frames.csv`` ``frame``).

        Raises
        ------
        MissingDescriptorFile
            Naming the folder without a file.
        ValueError
            Naming the folder or file: a file with fewer rows than the folder has frames, two
            folders of the same name, or a dataset without folders.
        """
        blocks, starts = _source_blocks(sources)
        frame_ids = np.asarray(frame_ids, dtype=np.int64)
        which = np.searchsorted(starts, frame_ids, side="right") - 1
        parts, dims = [], set()
        for b in np.unique(which):
            rows = frame_ids[which == b] - starts[b]
            source = blocks[b]
            name = Path(source["folder"]).name
            table = self.descriptors(name)
            positions = np.asarray(source["positions"], dtype=np.int64)[rows]
            if positions.size and positions.max() >= len(table):
                raise ValueError(f"{self.file_for(name)}: {len(table)} rows, but frame folder "
                                 f"{source['folder']} has a frame at position "
                                 f"{int(positions.max())} (rows are every frame file of the "
                                 f"folder, in frame order)")
            parts.append((which == b, table[positions]))
            dims.add(table.shape[1])
        if len(dims) > 1:
            raise ValueError(f"{self.folder}: descriptor files of different widths {sorted(dims)}")
        out = np.zeros((len(frame_ids), dims.pop() if dims else 0), dtype=np.float32)
        for mask, values in parts:
            out[mask] = values
        return out


def _source_blocks(sources: Sequence[Mapping[str, Any]]) -> tuple[list, np.ndarray]:
    """The source entries and the global frame number each starts at; ValueError without
    folders or positions, or when two folders share a name."""
    if not sources or any("positions" not in s for s in sources):
        raise ValueError("dataset.json: no frame folders with positions (precomputed "
                         "descriptors need data.kind: folders, built by this version)")
    seen: dict[str, str] = {}
    for source in sources:
        name, folder = Path(source["folder"]).name, str(source["folder"])
        if seen.setdefault(name, folder) != folder:
            raise ValueError(f"precomputed descriptors: folders {seen[name]} and {folder} share "
                             f"the name {name!r}; their descriptor files would too")
    counts = np.asarray([int(s["frames"]) for s in sources], dtype=np.int64)
    return list(sources), np.concatenate([[0], np.cumsum(counts)[:-1]])
