"""Loop closure within one drive on a looping route: lap 1 then lap 2 as one sequence.

A looping traversal of a test route is built from two drives of the dataset
(``dataset.json`` ``loops``: ``[route, lap1_drive, lap2_drive, name]``): the frames of lap 1,
then those of lap 2, concatenated in time order (the return leg between the laps is not
rendered, so the sequence jumps from the end of lap 1 to the start of lap 2). Every frame is
matched against the frames older than the exclusion zone
(:func:`cmal_lcd.matching.loops.match_loops`) and scored against the poses
(:func:`cmal_lcd.evaluation.loops.evaluate_loops`): lap-1 frames have no revisit (negatives),
lap-2 frames on the stretch lap 1 drove have one.

The method's matching protocol (chosen on the validation drives) applies as in the two-drive
evaluation (:func:`cmal_lcd.matching.normalise.normalise_pair` with lap 1 as the reference
drive: ``centre="reference"`` subtracts lap 1's mean code, the map a robot has when lap 2
starts; its ``enhance`` and ``r_window`` replace the config's).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd

from cmal_lcd.evaluation.loop_closure import drive_rows
from cmal_lcd.evaluation.loops import LoopEvaluation, evaluate_loops
from cmal_lcd.evaluation.protocol import MatchingProtocol
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.matching.loops import exclusion_limits, match_loops
from cmal_lcd.matching.normalise import normalise_pair


def loop_sequence(frames: pd.DataFrame, lap1: str, lap2: str) -> tuple[np.ndarray, int]:
    """Rows (positions into ``frames``) of the looping sequence and the length of lap 1.

    Parameters
    ----------
    frames : DataFrame
        A split's frame table (index ``0..n-1``), column ``drive``.
    lap1, lap2 : str
        Drive names of the first and second lap.

    Returns
    -------
    rows : ndarray, int64 (N,)
        Lap 1's frames in time order, then lap 2's.
    n_lap1 : int

    Raises
    ------
    ValueError
        When a lap names a drive with no frames, or both laps are the same drive.
    """
    if lap1 == lap2:
        raise ValueError(f"a loop needs two drives, got {lap1!r} twice")
    first, second = drive_rows(frames, lap1), drive_rows(frames, lap2)
    for name, rows in ((lap1, first), (lap2, second)):
        if len(rows) == 0:
            raise ValueError(f"loop: the drive {name!r} has no frames")
    return np.concatenate([first, second]).astype(np.int64), len(first)


def evaluate_loop_route(codes: np.ndarray, frames: pd.DataFrame, lap1: str, lap2: str, *,
                        metric: str, params: SeqSLAMParams, exclude_frames: int,
                        pose_tolerance: float, d_thresh: int,
                        protocol: MatchingProtocol | None = None,
                        train_means: np.ndarray | None = None) -> LoopEvaluation:
    """Loop closure metrics of one looping traversal (lap 1 then lap 2).

    Parameters
    ----------
    codes : ndarray (n, F)
        One row per frame of ``frames``.
    frames : DataFrame
        The split's frame table (columns ``drive, x, y``).
    lap1, lap2 : str
        Drive names of the laps.
    metric : {"sad", "sad_u8", "sqeuclidean", "sqeuclidean_f32"}
    params : SeqSLAMParams
    exclude_frames : int
        Exclusion zone: a frame only matches frames more than this many frames older.
    pose_tolerance : float
        Metres: an older frame this close is a revisit.
    d_thresh : int
        Frames: a match this close to a revisit is correct.
    protocol : MatchingProtocol, optional
        Normalisation (lap 1 = the reference drive) and enhancement; None: codes and
        ``params`` as given.
    train_means : ndarray (K, F), optional
        Training-set mean code per condition (``centre="condition"``).

    Returns
    -------
    LoopEvaluation
        Its ``metrics`` also hold ``n_lap1`` and ``n_lap2`` (frames per lap).
    """
    rows, n_lap1 = loop_sequence(frames, lap1, lap2)
    first, second = codes[rows[:n_lap1]], codes[rows[n_lap1:]]
    if protocol is not None:
        first, second = normalise_pair(first, second, protocol.normalisation,
                                       train_means=train_means)
        params = protocol.seqslam(params)
    sequence = np.concatenate([np.asarray(first), np.asarray(second)])
    n_allowed = exclusion_limits(len(rows), frames=exclude_frames)
    result = match_loops(sequence, metric=metric, params=params, n_allowed=n_allowed)
    xy = frames.iloc[rows][["x", "y"]].to_numpy(np.float64)
    evaluation = evaluate_loops(result, xy, pose_tolerance=pose_tolerance, d_thresh=d_thresh)
    evaluation.metrics.update(n_lap1=int(n_lap1), n_lap2=int(len(rows) - n_lap1))
    return evaluation


def loops_of(meta: dict) -> list[Sequence[str]]:
    """``dataset.json`` ``loops`` (``[route, lap1_drive, lap2_drive, name]``); ``[]`` when the
    dataset has no looping route (folder datasets, a world without ``data.test.loops``)."""
    return [list(loop) for loop in meta.get("loops") or []]
