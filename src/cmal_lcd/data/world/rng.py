"""Named random streams: every random draw of the world comes from ``(seed, stream names)``.

A stream is a :class:`numpy.random.Generator` seeded by ``SeedSequence(seed, spawn_key=...)``
where the spawn key is the CRC-32 of each name. Streams with different names are independent,
so adding frames to one split (a new name or a larger count) never changes another split.
"""

from __future__ import annotations

import zlib

import numpy as np


def stream_key(*names: str | int) -> tuple[int, ...]:
    """Spawn key of a stream: CRC-32 of each name (ints are used as they are).

    Parameters
    ----------
    *names : str or int
        Stream path, e.g. ``("train", "sunny", 17)``.

    Returns
    -------
    tuple of int
    """
    key = []
    for name in names:
        if isinstance(name, (int, np.integer)) and not isinstance(name, bool):
            if name < 0:
                raise ValueError(f"names: stream indices must be >= 0, got {name}")
            key.append(int(name))
        elif isinstance(name, str):
            key.append(zlib.crc32(name.encode("utf-8")))
        else:
            raise ValueError(f"names: expected str or int, got {type(name).__name__}")
    return tuple(key)


def stream_rng(seed: int, *names: str | int) -> np.random.Generator:
    """Independent generator for the stream ``names`` of the pipeline seed ``seed``.

    Parameters
    ----------
    seed : int
        The pipeline's top-level ``seed`` (>= 0).
    *names : str or int
        Stream path, e.g. ``("world", "terrain")``.

    Returns
    -------
    numpy.random.Generator
    """
    if int(seed) < 0:
        raise ValueError(f"seed: must be >= 0, got {seed}")
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=stream_key(*names)))
