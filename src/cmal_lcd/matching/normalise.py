"""Code normalisation before matching: centring and L2, with statistics a robot can have.

Learned codes carry a large per-weather offset (the mean code of a drive moves with its
weather far more than codes move from place to place), and squared Euclidean distances on raw
codes then match weather, not place. Two remedies are offered, each a switch:

- **centre** (:data:`CENTRES`):

  - ``none``: codes as extracted;
  - ``reference``: subtract the mean code of the *reference drive* (the map, known in full
    before any query arrives) from reference and query codes alike;
  - ``condition``: subtract from every frame the *training-set* mean code of its condition,
    the condition being the nearest training-condition mean in the method's own code space
    (:func:`nearest_condition`). Only training frames and the frame itself are used, so a
    query is normalised the moment it arrives ("condition directed" centring).

  Statistics never come from the query drive as a whole: a robot sees its queries one at a time.
- **l2**: divide every (centred) code by its Euclidean norm (a zero code stays zero).

The choice per method is made on a validation route by the ``select_protocol`` stage (see
:mod:`cmal_lcd.evaluation.protocol`), never on a test route.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cmal_lcd.schema import CENTRES  # the allowed values of CodeNormalisation.centre


@dataclass(frozen=True)
class CodeNormalisation:
    """How codes are normalised before the difference matrix.

    Attributes
    ----------
    centre : {"none", "reference", "condition"}
        Which mean is subtracted (see the module docstring).
    l2 : bool
        Scale every code to unit Euclidean norm after centring.
    """

    centre: str = "none"
    l2: bool = False

    def __post_init__(self) -> None:
        if self.centre not in CENTRES:
            raise ValueError(f"centre: expected one of {CENTRES}, got {self.centre!r}")
        if not isinstance(self.l2, (bool, np.bool_)):
            raise ValueError(f"l2: expected a bool, got {self.l2!r}")
        object.__setattr__(self, "l2", bool(self.l2))

    @property
    def label(self) -> str:
        """Short label for tables: ``raw``, ``centre(reference)+L2``, ..."""
        parts = [] if self.centre == "none" else [f"centre({self.centre})"]
        if self.l2:
            parts.append("L2")
        return "+".join(parts) or "raw"


def centring_sample(conditions: Sequence[str], frame_conditions: Sequence[str], *,
                    per_condition: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the training frames whose codes give the centring means, and their condition.

    Parameters
    ----------
    conditions : sequence of str
        Condition names in label order.
    frame_conditions : sequence of str (N,)
        Condition of every training frame.
    per_condition : int
        Frames per condition (fewer when a condition has fewer), evenly spaced.

    Returns
    -------
    rows : ndarray, int64 (M,)
        Ascending positions into the training frames.
    labels : ndarray, int64 (M,)
    """
    frame_conditions = np.asarray(frame_conditions)
    rows, labels = [], []
    for k, name in enumerate(conditions):
        own = np.flatnonzero(frame_conditions == name)
        if len(own) == 0:
            continue
        take = own[np.unique(np.linspace(0, len(own) - 1, min(per_condition, len(own)))
                             .round().astype(np.int64))]
        rows.append(take)
        labels.append(np.full(len(take), k, np.int64))
    if not rows:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    rows_all, labels_all = np.concatenate(rows), np.concatenate(labels)
    order = np.argsort(rows_all, kind="stable")
    return rows_all[order], labels_all[order]


def condition_means(codes: np.ndarray, labels: np.ndarray, n_conditions: int) -> np.ndarray:
    """Mean code of every condition over training frames.

    Parameters
    ----------
    codes : ndarray (N, F)
        Codes of training frames.
    labels : ndarray, int (N,)
        Condition index of every frame, in ``[0, n_conditions)``.
    n_conditions : int

    Returns
    -------
    ndarray, float64 (n_conditions, F)

    Raises
    ------
    ValueError
        When a condition has no frame (naming it by index).
    """
    codes = np.asarray(codes, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    if codes.ndim != 2 or labels.shape != (len(codes),):
        raise ValueError(f"codes/labels: expected (N, F) and (N,), got {codes.shape} and "
                         f"{labels.shape}")
    means = np.empty((n_conditions, codes.shape[1]))
    for k in range(n_conditions):
        rows = labels == k
        if not rows.any():
            raise ValueError(f"labels: condition {k} has no training frame")
        means[k] = codes[rows].mean(axis=0)
    return means


def nearest_condition(codes: np.ndarray, means: np.ndarray) -> np.ndarray:
    """Index of the nearest condition mean (Euclidean) for every code: ``int64 (N,)``.

    Each row depends only on that code and on ``means``.
    """
    codes = np.asarray(codes, dtype=np.float64)
    means = np.asarray(means, dtype=np.float64)
    d = (np.einsum("nf,nf->n", codes, codes)[:, None] - 2.0 * codes @ means.T
         + np.einsum("kf,kf->k", means, means)[None, :])
    return np.argmin(d, axis=1).astype(np.int64)


def l2_normalise(codes: np.ndarray) -> np.ndarray:
    """Rows scaled to unit Euclidean norm; zero rows stay zero. ``float32 (N, F)``."""
    codes = np.asarray(codes, dtype=np.float64)
    norm = np.linalg.norm(codes, axis=1, keepdims=True)
    return np.divide(codes, norm, out=np.zeros_like(codes), where=norm > 0).astype(np.float32)


def normalise_pair(reference: np.ndarray, query: np.ndarray, normalisation: CodeNormalisation,
                   *, train_means: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Normalise the codes of a reference drive and a query drive.

    Parameters
    ----------
    reference : ndarray (R, F)
    query : ndarray (Q, F)
    normalisation : CodeNormalisation
    train_means : ndarray (K, F), optional
        Training-set mean code per condition (:func:`condition_means`); required for
        ``centre="condition"``.

    Returns
    -------
    reference, query : ndarray, float32 (R, F) and (Q, F)
        With ``centre="none"`` and ``l2=False`` the inputs are returned unchanged (same dtype),
        so the paper's protocol sees exactly the extracted codes.

    Notes
    -----
    Row ``i`` of the normalised query depends only on ``query[i]``, the reference drive and
    the training statistics: permuting or truncating the query drive permutes or truncates
    the output and changes nothing else.
    """
    if normalisation.centre == "none" and not normalisation.l2:
        return reference, query
    ref = np.asarray(reference, dtype=np.float64)
    qry = np.asarray(query, dtype=np.float64)
    if normalisation.centre == "reference":
        mean = ref.mean(axis=0)
        ref, qry = ref - mean, qry - mean
    elif normalisation.centre == "condition":
        if train_means is None:
            raise ValueError("train_means: needed for centre='condition' (training-set mean "
                             "code per condition)")
        means = np.asarray(train_means, dtype=np.float64)
        if means.ndim != 2 or means.shape[1] != ref.shape[1]:
            raise ValueError(f"train_means: expected (K, {ref.shape[1]}), got {means.shape}")
        ref = ref - means[nearest_condition(ref, means)]
        qry = qry - means[nearest_condition(qry, means)]
    if normalisation.l2:
        return l2_normalise(ref), l2_normalise(qry)
    return ref.astype(np.float32), qry.astype(np.float32)
