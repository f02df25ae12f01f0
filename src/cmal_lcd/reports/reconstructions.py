"""Paper Fig. 11's data: CMAL's reconstructions and weather translations of held-out frames.

The report computes the figure's arrays (:func:`reconstruction_examples`) from the trained
model ``<models>/cmal/model.pt`` and the dataset's training split:

1. the frames training held out (:func:`heldout_pool`: ``cmal_lcd.models.heldout_split``
   with ``models.cmal.heldout_fraction`` and ``seed``, as the train stage split them);
2. among them, ``count`` frames A and the condition B to translate each into
   (:func:`example_rows`, :func:`translation_pairs`: ordered condition pairs in turn);
3. for each, the training frame of condition B that sees A's place best
   (:func:`same_place_rows`, :func:`nearest_view`), a real view to compare the translation with;
4. the model reconstructs A under its own condition and decodes the same code under B
   (:func:`cmal_lcd.models.cmal.reconstruct_and_translate`).

torch is imported only by :func:`heldout_pool` and :func:`reconstruction_examples` (the report
imports this module whether or not a model exists).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

#: Rows of the Fig. 11 reproduction.
N_EXAMPLES = 6
#: Fig. 11's arrays, as :func:`reconstruction_examples` returns them.
EXAMPLE_KEYS = ("a", "recon_a", "translated_b", "b", "condition_a", "condition_b", "frame_a",
                "frame_b", "offset_b")


def translation_pairs(labels: np.ndarray, *, n_conditions: int, count: int,
                      seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames and condition pairs (A, B) for the reconstruction figure, reproducibly.

    Ordered pairs ``(A, B)``, ``A != B``, are visited in turn (``(0, 1), (0, 2), (1, 0)...``);
    for each, a frame of condition ``A`` not used yet is drawn at random.

    Parameters
    ----------
    labels : ndarray, int, shape (M,)
        Condition of each candidate frame.
    n_conditions : int
        At least 2.
    count : int
        Number of examples wanted.
    seed : int

    Returns
    -------
    positions : ndarray, int64, shape (n,)
        Positions into ``labels`` (``n <= count`` when a condition runs out of frames).
    cond_a, cond_b : ndarray, int64, shape (n,)
    """
    labels = np.asarray(labels)
    if n_conditions < 2:
        raise ValueError(f"n_conditions: translation needs at least 2, got {n_conditions}")
    rng = np.random.default_rng([seed, 4])
    pools = {k: list(rng.permutation(np.flatnonzero(labels == k))) for k in range(n_conditions)}
    pairs = [(a, b) for a in range(n_conditions) for b in range(n_conditions) if a != b]
    chosen: list[tuple[int, int, int]] = []
    for k in range(count * len(pairs)):
        if len(chosen) == count or not any(pools.values()):
            break
        a, b = pairs[k % len(pairs)]
        if pools[a]:
            chosen.append((int(pools[a].pop()), a, b))
    arr = np.asarray(chosen, dtype=np.int64).reshape(-1, 3)
    return arr[:, 0], arr[:, 1], arr[:, 2]


def nearest_view(xy: np.ndarray, heading: float, candidate_xy: np.ndarray,
                 candidate_heading: np.ndarray, *, max_heading_deg: float = 30.0) -> int:
    """The candidate frame that sees the place of pose ``(xy, heading)`` best.

    Among candidates whose heading is within ``max_heading_deg`` of ``heading``, the one
    nearest in position; when none is, the nearest in position overall.

    Parameters
    ----------
    xy : ndarray, shape (2,)
        Position, metres.
    heading : float
        Radians.
    candidate_xy : ndarray, shape (M, 2)
    candidate_heading : ndarray, shape (M,)

    Returns
    -------
    int
        Position into the candidates.
    """
    candidate_xy = np.asarray(candidate_xy, dtype=np.float64)
    if candidate_xy.ndim != 2 or candidate_xy.shape[1] != 2 or len(candidate_xy) == 0:
        raise ValueError(f"candidate_xy: expected shape (M>0, 2), got {candidate_xy.shape}")
    distance = np.linalg.norm(candidate_xy - np.asarray(xy, dtype=np.float64), axis=1)
    aligned = np.cos(np.asarray(candidate_heading) - heading) >= np.cos(np.radians(max_heading_deg))
    if aligned.any():
        distance = np.where(aligned, distance, np.inf)
    return int(np.argmin(distance))


def heldout_pool(n_frames: int, *, heldout_fraction: float, seed: int) -> np.ndarray:
    """The training rows Fig. 11 draws from: those training held out, every row when none is.

    Returns
    -------
    ndarray, int64, shape (n,)
        Sorted rows of the training split (:func:`cmal_lcd.models.heldout_split`).
    """
    from cmal_lcd.models import heldout_split

    _, heldout = heldout_split(n_frames, fraction=float(heldout_fraction), seed=int(seed))
    return heldout if len(heldout) else np.arange(n_frames, dtype=np.int64)


def example_rows(labels: np.ndarray, *, n_conditions: int, heldout_fraction: float, seed: int,
                 count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frames A of Fig. 11 and their conditions (A, B): :func:`translation_pairs` over the
    :func:`heldout_pool`.

    Parameters
    ----------
    labels : ndarray, int, shape (M,)
        Condition of each training frame.

    Returns
    -------
    rows_a : ndarray, int64, shape (n,)
        Rows of the training split, ``n <= count``.
    cond_a, cond_b : ndarray, int64, shape (n,)
    """
    pool = heldout_pool(len(labels), heldout_fraction=heldout_fraction, seed=seed)
    positions, cond_a, cond_b = translation_pairs(labels[pool], n_conditions=n_conditions,
                                                  count=count, seed=int(seed))
    return pool[positions], cond_a, cond_b


def same_place_rows(frames: pd.DataFrame, labels: np.ndarray, rows_a: np.ndarray,
                    cond_b: np.ndarray) -> np.ndarray:
    """For each frame A, the frame of condition B that sees its place best (:func:`nearest_view`).

    Parameters
    ----------
    frames : DataFrame
        Columns ``x, y, heading``, one row per frame.
    labels : ndarray, int, shape (M,)
        Condition of each frame.
    rows_a : ndarray, int, shape (n,)
        Rows of the frames A.
    cond_b : ndarray, int, shape (n,)
        The condition to find each one's view in (each must label some frame).

    Returns
    -------
    ndarray, int64, shape (n,)
        Rows of ``frames``.
    """
    xy = frames[["x", "y"]].to_numpy(dtype=np.float64)
    heading = frames["heading"].to_numpy(dtype=np.float64)
    rows_b = []
    for row, b in zip(rows_a, cond_b):
        candidates = np.flatnonzero(labels == b)
        rows_b.append(int(candidates[nearest_view(xy[row], heading[row], xy[candidates],
                                                  heading[candidates])]))
    return np.asarray(rows_b, dtype=np.int64)


def model_path(models_dir: Path) -> Path:
    """Where the train stage writes the CMAL model Fig. 11 is computed from."""
    return Path(models_dir) / "cmal" / "model.pt"


def model_missing(models_dir: Path) -> str | None:
    """Why there is no CMAL model to run (Markdown, one sentence), or None when there is one."""
    path = model_path(models_dir)
    if not path.is_file():
        shown = Path(Path(models_dir).name, "cmal", "model.pt")  # no machine-specific path
        return f"`{shown}` does not exist (no trained CMAL model in this run)."
    return None


def examples_missing(models_dir: Path, conditions: Sequence[str]) -> str | None:
    """Why Fig. 11 cannot be computed (Markdown, one sentence), or None when it can.

    Parameters
    ----------
    models_dir : Path
        The models folder (``models``).
    conditions : sequence of str
        The dataset's condition names.
    """
    missing = model_missing(models_dir)
    if missing is not None:
        return missing
    if len(conditions) < 2:
        return (f"the dataset has {len(conditions)} weather condition(s), so there is no other "
                "weather to translate into.")
    return None


def reconstruction_examples(models_dir: Path, dataset: Any, *, heldout_fraction: float,
                            seed: int, count: int = N_EXAMPLES, threads: int = 1
                            ) -> dict[str, np.ndarray] | None:
    """Fig. 11's arrays from ``<models_dir>/cmal/model.pt`` and ``dataset``'s training split.

    Parameters
    ----------
    models_dir : Path
        The models folder (``models``).
    dataset : cmal_lcd.data.store.Dataset
    heldout_fraction : float
        ``models.cmal.heldout_fraction``: the frames training held out are drawn from.
    seed : int
        The config's ``seed`` (the held-out split and the drawn frames).
    count : int
        Rows wanted (fewer when a condition runs out of held-out frames).
    threads : int
        torch threads for the model's forward passes (``runtime.threads``), with deterministic
        algorithms, as training and the features stage run; restored afterwards.

    Returns
    -------
    dict of ndarray, or None
        None when :func:`examples_missing` gives a reason. Otherwise, with ``n <= count`` and
        ``S`` the model's image size:
        ``a``, ``recon_a``, ``translated_b``: ``uint8 (n, S, S, 3)`` (the frame A, its
        reconstruction under A, its code decoded under B); ``b``: ``uint8 (n, S, S, 3)``, the
        training frame of condition B nearest to A's pose; ``condition_a``, ``condition_b``:
        ``str (n,)`` condition names; ``frame_a``, ``frame_b``: ``int64 (n,)`` frame ids
        (``frames.csv``).
    """
    conditions = list(dataset.conditions)
    if examples_missing(models_dir, conditions) is not None:
        return None
    images, frames = dataset.train()
    labels = np.asarray([dataset.condition_index(c) for c in frames["condition"]], np.int64)
    rows_a, cond_a, cond_b = example_rows(labels, n_conditions=len(conditions),
                                          heldout_fraction=heldout_fraction, seed=seed,
                                          count=count)
    rows_b = same_place_rows(frames, labels, rows_a, cond_b)
    views = _model_views(model_path(models_dir), images, rows_a=rows_a, rows_b=rows_b,
                         cond_a=cond_a, cond_b=cond_b, threads=threads)
    names = np.asarray(conditions)
    frame_ids = frames["frame"].to_numpy()
    metres = dataset.meta.get("ground_truth", "poses") == "poses"
    return {**views, "condition_a": names[cond_a], "condition_b": names[cond_b],
            "frame_a": np.asarray(frame_ids[rows_a], dtype=np.int64),
            "frame_b": np.asarray(frame_ids[rows_b], dtype=np.int64),
            "offset_b": view_offsets(frames, rows_a, rows_b, metres=metres)}


def view_offsets(frames: pd.DataFrame, rows_a: np.ndarray, rows_b: np.ndarray, *,
                 metres: bool) -> np.ndarray:
    """How far each view B is from its view A, as Fig. 11 labels it: ``"0.4 m, 3° away"``
    (poses in metres), or for folders paired by index (``x`` is the place's position)
    ``"same place index"`` / ``"2 places away"``.

    Parameters
    ----------
    frames : DataFrame
        Columns ``x, y, heading`` (radians), one row per frame.
    rows_a, rows_b : ndarray, int, shape (n,)

    Returns
    -------
    ndarray, str, shape (n,)
    """
    xy = frames[["x", "y"]].to_numpy(dtype=np.float64)
    distance = np.linalg.norm(xy[rows_a] - xy[rows_b], axis=1)
    if not metres:
        return np.asarray(["same place index" if round(d) == 0 else
                           f"{d:.0f} place{'' if round(d) == 1 else 's'} away" for d in distance])
    heading = frames["heading"].to_numpy(dtype=np.float64)
    turn = np.degrees(np.abs(np.angle(np.exp(1j * (heading[rows_a] - heading[rows_b])))))
    return np.asarray([f"{d:.1f} m, {a:.0f}° away" for d, a in zip(distance, turn)])


def _model_views(path: Path, images: np.ndarray, *, rows_a: np.ndarray, rows_b: np.ndarray,
                 cond_a: np.ndarray, cond_b: np.ndarray, threads: int) -> dict[str, np.ndarray]:
    """The trained CMAL at ``path`` run on the frames A of ``images`` ``uint8 (M, H, W, 3)``:
    ``a``, ``recon_a``, ``translated_b`` and the real views ``b`` (rows ``rows_b``), each
    ``uint8 (n, S, S, 3)`` at the model's image size ``S``."""
    from cmal_lcd.models import load_trained
    from cmal_lcd.models.cmal import reconstruct_and_translate
    from cmal_lcd.models.images import resize_images
    from cmal_lcd.models.training import torch_runtime

    model, meta = load_trained(path)
    with torch_runtime(threads=threads, deterministic=True):
        out = reconstruct_and_translate(model, images[rows_a], cond_a, cond_b)
    return {"a": out["a"], "recon_a": out["recon_a"], "translated_b": out["translated_b"],
            "b": resize_images(images[rows_b], image_size=int(meta["image_size"]))}
