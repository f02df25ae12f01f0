"""SeqSLAM parameters (paper Table I) and the trajectory offsets they imply.

The matching defaults live in ``conf/matching/seqslam.yaml`` only. The stages read them from the
composed config (``SeqSLAMParams.from_config(cfg.matching)``); direct calls from Python read the
same file through :func:`matching_defaults` (no Hydra: SAD matching stays light), e.g.
``SeqSLAMParams.defaults()``. The ``match`` and ``loops`` commands, whose ``--config`` may
change them, ask :func:`cmal_lcd.config.command_matching`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np


def matching_defaults() -> dict[str, Any]:
    """The ``matching`` node of ``conf/matching/seqslam.yaml``, checked and typed by the schema.

    The one source of the matching defaults of direct calls (``SeqSLAMParams.defaults()``, a
    library function's Table I). Read with PyYAML and checked with
    :func:`cmal_lcd.schema.validate`: no Hydra import.

    Returns
    -------
    dict
        Plain values (``ds``, ``v_min``, ..., ``d_thresh``, ``pose_tolerance``, ``sad``, ...);
        a fresh copy on every call.

    Raises
    ------
    ValueError
        Naming the file and the key (``.../seqslam.yaml: matching.d_thresh: ...``).
    """
    import copy

    return copy.deepcopy(_read_matching_defaults())


@functools.cache
def _read_matching_defaults() -> dict[str, Any]:
    from cmal_lcd.schema import group_option

    return group_option("matching", "seqslam")


@dataclasses.dataclass(frozen=True)
class SeqSLAMParams:
    """Parameters of the sequence search (paper Table I, section III-C).

    Attributes
    ----------
    ds : int
        Look-back length: the trajectory for query ``T`` uses the ``ds + 1`` query frames
        ``T - ds .. T`` (paper eq. 15). Queries ``T < ds`` are not scored.
    v_min, v_max, v_step : float
        Trajectory velocities, in reference frames per query frame: ``v_min, v_min + v_step, ...``
        up to and including ``v_max`` (Table I: 0.8, 0.9, 1.0, 1.1).
    r_window : int
        Local contrast enhancement window (eq. 14): rows ``i - r_window//2 .. i + r_window//2``
        inclusive; also the uniqueness exclusion window around the best match. ``0`` turns the
        enhancement off (and excludes only the matched row from the uniqueness ratio).
    enhance : bool
        Apply the local contrast enhancement (eq. 14). ``False`` is the ``plain`` ablation; the
        uniqueness window still uses ``r_window``.
    score : {"ratio", "sum"}
        Which per-query value the PR threshold sweeps: the uniqueness ratio (as OpenSeqSLAM) or the
        raw sequence score. Lower is more confident for both.

    Every field is required: the configured defaults (``conf/matching/seqslam.yaml``; Table I)
    are :meth:`defaults`. Each value is checked by the ``matching`` schema's rules
    (:func:`cmal_lcd.fields.check_values`), the same check as a composed config's.
    """

    ds: int
    v_min: float
    v_max: float
    v_step: float
    r_window: int
    enhance: bool
    score: str

    def __post_init__(self) -> None:
        for name, checked in check_matching(**dataclasses.asdict(self)).items():
            object.__setattr__(self, name, checked)

    @classmethod
    def defaults(cls, **changes: Any) -> "SeqSLAMParams":
        """The configured parameters (:func:`matching_defaults`), with ``changes``
        (``SeqSLAMParams.defaults(enhance=False)``)."""
        return dataclasses.replace(cls.from_config(matching_defaults()), **changes)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> "SeqSLAMParams":
        """Build from a mapping such as the composed ``matching`` config node (typed or not).

        Keys that are not fields (``d_thresh``, ``sad``, ...) are ignored.
        """
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: cfg[k] for k in cfg.keys() if k in names})

    def as_dict(self) -> dict[str, Any]:
        """The fields as a plain dict (for JSON outputs)."""
        return dataclasses.asdict(self)

    @property
    def enhancement_window(self) -> int:
        """The enhancement window actually applied (0 when the enhancement is off)."""
        return self.r_window if self.enhance else 0

    def velocities(self) -> np.ndarray:
        """The trajectory velocities, see :func:`trajectory_velocities`."""
        return trajectory_velocities(v_min=self.v_min, v_max=self.v_max, v_step=self.v_step)

    def offsets(self) -> np.ndarray:
        """The trajectory offsets, see :func:`trajectory_offsets`."""
        return trajectory_offsets(ds=self.ds, velocities=self.velocities())


def velocity_count(*, v_min: float, v_max: float, v_step: float) -> int:
    """How many velocities ``v_min, v_min + v_step, .. <= v_max`` there are."""
    return int(math.floor(round((v_max - v_min) / v_step, 9))) + 1


def check_matching(**values: Any) -> dict[str, Any]:
    """Check ``matching`` values (``ds=0``, ``v_step=...``) by the schema's rules
    (:class:`cmal_lcd.schema.MatchingSchema`): the one check of each; ``ValueError`` naming the
    field (``ds: must be >= 1, got 0``). Returns them as the schema's types."""
    from cmal_lcd.fields import check_values
    from cmal_lcd.schema import MatchingSchema

    return check_values(MatchingSchema, values)


def trajectory_velocities(*, v_min: float, v_max: float, v_step: float) -> np.ndarray:
    """Velocities ``v_min + i * v_step`` for ``i = 0, 1, ...`` while ``<= v_max``.

    Each value is rounded to 9 decimals, so ``0.8 + 3 * 0.1`` is ``1.1`` exactly and is kept
    when ``v_max = 1.1``.

    Returns
    -------
    numpy.ndarray
        ``float64 (n_v,)``, ascending.
    """
    check_matching(v_min=v_min, v_max=v_max, v_step=v_step)
    count = velocity_count(v_min=v_min, v_max=v_max, v_step=v_step)
    return np.array([round(v_min + i * v_step, 9) for i in range(count)], dtype=np.float64)


def trajectory_offsets(*, ds: int, velocities: np.ndarray) -> np.ndarray:
    """Reference-row offsets of every look-back trajectory.

    The trajectory of velocity ``v`` that ends at reference row ``s`` at query column ``T`` visits
    row ``s - offsets[v, j]`` at column ``T - j`` for ``j = 0 .. ds``, with
    ``offsets[v, j] = floor(round(v * j, 9))`` (the rounding keeps ``0.1 * 10`` from flooring
    to 0).

    Returns
    -------
    numpy.ndarray
        ``int64 (n_v, ds + 1)``, non-decreasing along ``j``, ``offsets[:, 0] == 0``.
    """
    check_matching(ds=ds)
    velocities = np.asarray(velocities, dtype=np.float64)
    out = np.empty((velocities.size, ds + 1), dtype=np.int64)
    for i, v in enumerate(velocities):
        for j in range(ds + 1):
            out[i, j] = math.floor(round(float(v) * j, 9))
    return out
