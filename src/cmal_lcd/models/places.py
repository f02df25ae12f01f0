"""Place supervision (an extension; the paper trains with weather labels only).

Which training frames show the same place under another weather, and the contrastive term
that pulls their codes together. The positives of a frame are the training frames of *another*
condition whose pose lies within ``radius`` (the units of ``frames.csv`` ``x, y``: metres in
the rendered world, frame positions for folders paired by index) and whose heading differs by
at most ``heading_deg`` (not tested where a heading is NaN). The loop draws one positive per
frame of a batch (:func:`draw_positives`); frames with none take no part in the term.

The term (:func:`info_nce`) is InfoNCE (van den Oord et al. 2018) over the batch, symmetric as
in CLIP: the codes are L2-normalised, each anchor's positive is its own drawn partner and the
other anchors' partners are its negatives.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch.nn import functional as F

from cmal_lcd.models.cmal_config import PlaceConfig

def place_positives(poses: np.ndarray, labels: np.ndarray, rule: PlaceConfig) -> list[np.ndarray]:
    """For each frame, the frames of another condition at the same place.

    Parameters
    ----------
    poses : ndarray, float, shape (M, 3)
        ``x, y, heading`` (radians) of each training frame; a frame with NaN ``x`` or ``y`` has
        no positives and is nobody's.
    labels : ndarray, int, shape (M,)
        Condition of each frame.
    rule : PlaceConfig

    Returns
    -------
    list of ndarray, int64
        ``M`` sorted arrays of positions into ``poses``.
    """
    from scipy.spatial import cKDTree

    poses = np.asarray(poses, dtype=np.float64)
    labels = np.asarray(labels)
    if poses.ndim != 2 or poses.shape[1] != 3 or len(poses) != len(labels):
        raise ValueError(f"poses: expected shape ({len(labels)}, 3) (x, y, heading), got "
                         f"{poses.shape}")
    known = np.flatnonzero(np.isfinite(poses[:, :2]).all(axis=1))
    empty = np.zeros(0, np.int64)
    out = [empty] * len(poses)
    if len(known) == 0:
        return out
    tree = cKDTree(poses[known, :2])
    max_turn = math.radians(rule.heading_deg)
    for i, near in zip(known, tree.query_ball_point(poses[known, :2], r=rule.radius)):
        near = known[np.asarray(near, dtype=np.int64)]
        near = near[labels[near] != labels[i]]
        turn = np.abs(np.angle(np.exp(1j * (poses[near, 2] - poses[i, 2]))))
        near = near[~(turn > max_turn)]  # NaN headings are not tested
        out[i] = np.sort(near).astype(np.int64)
    return out


def draw_positives(positives: list[np.ndarray], positions: np.ndarray,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One positive per anchor, uniformly among its positives.

    Parameters
    ----------
    positives : list of ndarray
        From :func:`place_positives`.
    positions : ndarray, int64, shape (B,)
        The anchors (positions into ``positives``).

    Returns
    -------
    partner : ndarray, int64, shape (B,)
        The drawn positive (the anchor itself where it has none).
    has_positive : ndarray, bool, shape (B,)
    """
    counts = np.asarray([len(positives[p]) for p in positions], dtype=np.int64)
    picks = np.floor(rng.random(len(positions)) * np.maximum(counts, 1)).astype(np.int64)
    partner = np.asarray([positives[p][k] if n else p
                          for p, k, n in zip(positions, picks, counts)], dtype=np.int64)
    return partner, counts > 0


def info_nce(anchor: torch.Tensor, positive: torch.Tensor, *, temperature: float) -> torch.Tensor:
    """Symmetric InfoNCE of paired codes: row ``i`` of ``positive`` is anchor ``i``'s positive,
    every other row a negative.

    Parameters
    ----------
    anchor, positive : Tensor, shape (B, D)
        Codes (L2-normalised here). ``B < 2`` gives a zero loss (no negative).

    Returns
    -------
    Tensor, scalar
        ``(CE(sim / t, I) + CE(sim.T / t, I)) / 2`` with ``sim`` the cosine similarities.
    """
    if len(anchor) < 2:
        return anchor.sum() * 0.0
    a, p = F.normalize(anchor.float(), dim=1), F.normalize(positive.float(), dim=1)
    logits = a @ p.T / temperature
    target = torch.arange(len(a), device=a.device)
    return 0.5 * (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target))
