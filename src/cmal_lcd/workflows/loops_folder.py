"""Loop closures within one traversal of a user's own frames (what ``cmal-lcd loops`` runs).

Every frame of a folder (sorted file names, :func:`cmal_lcd.data.frames.read_frame_folder`)
is matched against the frames older than the exclusion zone with SeqSLAM
(:func:`cmal_lcd.matching.loops.match_loops`). :func:`loops_folder` writes into its output
folder:

- ``loops.csv``: one row per detected loop closure (every scored frame, or those with
  ``score <= threshold``): ``query_frame, query_name, matched_frame, matched_name, score``
  (lower = more confident: the uniqueness ratio, or the sequence score with ``score="sum"``),
  plus ``has_revisit, correct`` with poses;
- ``metrics.json`` (only with ``poses.csv``): AUC-PR, AUC-ROC, R@100P, R@1, single-frame R@1
  over the frames that have a revisit (:func:`cmal_lcd.evaluation.loops.evaluate_loops`), the
  counts and every parameter;
- ``loops.png`` (:func:`cmal_lcd.reports.loops_figure.plot_loops`): the trajectory from the
  poses with correct and false detections marked (with poses), and the self-difference matrix
  the search used with the exclusion zone shaded.

The output folder is replaced as a whole once every file is written (old or new, never a mix),
and a folder holding anything else is refused, as ``cmal-lcd match`` does. Bad input is one
``ValueError`` (or :class:`~cmal_lcd.data.frames.FrameReadError`) naming the file, folder or
option.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

#: Files ``loops`` writes (``metrics.json`` only with poses).
LOOPS_OUTPUTS = ("loops.csv", "metrics.json", "loops.png")

#: Up to this many matrix cells (4,096 x 4,096) ``loops`` keeps the self-difference matrix of
#: the search for its figure; above, the figure's cells are computed again for every k-th frame.
MAX_KEPT_CELLS = 16 * 2**20


def loops_folder(folder: str | os.PathLike, *, features: str = "sad", params=None,
                 exclude_frames: int | None = None, exclude_metres: float | None = None,
                 threshold: float | None = None, d_thresh: int | None = None,
                 poses_tolerance: float | None = None,
                 out_dir: str | os.PathLike = "loops_out",
                 model_dir: str | os.PathLike | None = None,
                 config_overrides: Sequence[str] = ()) -> dict:
    """Loop closures within one folder of frames; writes ``loops.csv``, ``loops.png`` and
    (with poses) ``metrics.json`` into ``out_dir``.

    Parameters
    ----------
    folder : path-like
        Frames in time (sorted file-name) order, optional ``poses.csv``.
    features : str
        ``sad`` or a learned extractor name (as ``cmal-lcd match``).
    params : SeqSLAMParams, optional
        Default Table I.
    exclude_frames : int, optional
        Exclusion zone in frames (default :data:`~cmal_lcd.matching.loops.
        DEFAULT_EXCLUDE_FRAMES`).
    exclude_metres : float, optional
        Exclusion zone in metres of travel (needs poses).
    threshold : float, optional
        List only loop closures with ``score <= threshold``.
    d_thresh : int, optional
        Tolerance in frames (default ``matching.d_thresh`` of the config,
        :func:`cmal_lcd.config.command_matching`).
    poses_tolerance : float, optional
        Revisit radius, metres (default: ``matching.pose_tolerance`` of the config,
        :func:`cmal_lcd.config.command_matching`).
    out_dir, model_dir : path-like
    config_overrides : sequence of str
        Hydra overrides of ``conf/`` (``loops --config``): the defaults of the arguments left as
        None and the extractor's config come from ``conf/`` composed with them (as
        :func:`cmal_lcd.workflows.match_folders.match_folders`).

    Returns
    -------
    dict
        ``n_frames, n_scored, n_detections, seconds, params`` and, with poses, every metric of
        :func:`~cmal_lcd.evaluation.loops.evaluate_loops` (as in ``metrics.json``).
    """
    from cmal_lcd.io import staged_output_folder
    from cmal_lcd.config import command_matching

    params, exclude_frames, d_thresh, poses_tolerance = _checked_loops_options(
        params, exclude_frames=exclude_frames, exclude_metres=exclude_metres,
        threshold=threshold, d_thresh=d_thresh, poses_tolerance=poses_tolerance,
        conf=command_matching(config_overrides))

    with staged_output_folder(out_dir, LOOPS_OUTPUTS, command="loops",
                              inputs=(folder,)) as staging:
        return _loops_into(staging, folder, features=features, params=params,
                           exclude_frames=exclude_frames, exclude_metres=exclude_metres,
                           threshold=threshold, d_thresh=d_thresh,
                           poses_tolerance=poses_tolerance, model_dir=model_dir,
                           config_overrides=config_overrides)


def _loops_into(out_dir: Path, folder, *, features: str, params, exclude_frames: int,
                exclude_metres: float | None, threshold: float | None, d_thresh: int,
                poses_tolerance: float, model_dir, config_overrides: Sequence[str]) -> dict:
    """:func:`loops_folder`'s work, its files written into the empty folder ``out_dir``."""
    from cmal_lcd.evaluation.loops import evaluate_loops

    frames, xy, n_allowed = _read_loop_frames(folder, ds=params.ds, exclude_frames=exclude_frames,
                                              exclude_metres=exclude_metres)
    codes, metric, extractor_info, result, keep, seconds = _search_loops(
        frames.images, features=features, model_dir=model_dir, params=params,
        n_allowed=n_allowed, config_overrides=config_overrides)
    detected = _listed_closures(result, threshold)
    evaluation = None if xy is None else evaluate_loops(
        result, xy, pose_tolerance=poses_tolerance, d_thresh=d_thresh)
    _write_loops_csv(out_dir / "loops.csv", frames.names, result, detected, evaluation)
    record = _loops_record(result, detected, evaluation, seconds=seconds, params=_loops_params(
        params, extractor_info, exclude_frames=exclude_frames, exclude_metres=exclude_metres,
        threshold=threshold, folder=folder, evaluated=evaluation is not None,
        d_thresh=d_thresh, poses_tolerance=poses_tolerance, config_overrides=config_overrides))
    if evaluation is not None:
        from cmal_lcd.io import atomic_write_json

        atomic_write_json(out_dir / "metrics.json", record)
    title = _loops_title(extractor_info.get("label", features), folder, len(frames),
                         exclude_frames=exclude_frames, exclude_metres=exclude_metres)
    _write_loops_figure(out_dir / "loops.png", result, codes, metric=metric, params=params,
                        n_allowed=n_allowed, detected=detected, evaluation=evaluation, xy=xy,
                        keep=keep, title=title)
    return record


def _checked_loops_options(params, *, exclude_frames, exclude_metres, threshold, d_thresh,
                           poses_tolerance, conf: Mapping[str, Any]):
    """``params, exclude_frames, d_thresh, poses_tolerance`` with defaults for None (from
    ``conf``, the ``matching`` node), after :func:`_check_options`."""
    from cmal_lcd.workflows.match_folders import with_matching_defaults
    from cmal_lcd.matching.loops import DEFAULT_EXCLUDE_FRAMES

    params, d_thresh, poses_tolerance = with_matching_defaults(params, d_thresh, poses_tolerance,
                                                               conf=conf)
    exclude_frames = DEFAULT_EXCLUDE_FRAMES if exclude_frames is None else exclude_frames
    _check_options(exclude_frames=exclude_frames, exclude_metres=exclude_metres,
                   threshold=threshold)
    return params, exclude_frames, d_thresh, poses_tolerance


def _read_loop_frames(folder, *, ds: int, exclude_frames: int, exclude_metres: float | None):
    """The frames of ``folder`` (more than ``ds``), their positions ``xy (N, 2)`` (None
    without poses) and the exclusion limits ``n_allowed int (N,)``."""
    import numpy as np

    from cmal_lcd.data.frames import read_frame_folder
    from cmal_lcd.matching.loops import exclusion_limits, travelled_distance

    frames = read_frame_folder(folder)
    xy = None if frames.poses is None else frames.poses[["x", "y"]].to_numpy(np.float64)
    if exclude_metres is not None and xy is None:
        raise ValueError(f"--exclude-metres: needs {Path(folder) / 'poses.csv'} (no such file)")
    N = len(frames)
    if N <= ds:
        raise ValueError(f"{folder}: {N} frames; the look-back search needs more than "
                         f"ds={ds}")
    n_allowed = exclusion_limits(N, frames=exclude_frames, metres=exclude_metres,
                                 travelled=None if xy is None else travelled_distance(xy))
    if not (n_allowed[ds:] > 0).any():
        option = "--exclude-metres" if exclude_metres is not None else "--exclude-frames"
        value = exclude_metres if exclude_metres is not None else exclude_frames
        raise ValueError(f"{option} {value}: leaves no older frame to match in the {N} frames "
                         f"of {folder}; nothing could be scored")
    return frames, xy, n_allowed


def _search_loops(images, *, features: str, model_dir, params, n_allowed,
                  config_overrides: Sequence[str] = ()):
    """Codes ``(N, F)`` of ``images``, their metric and extractor info, the SeqSLAM loop search
    result, whether it kept its matrices (``N * N <= MAX_KEPT_CELLS``) and the seconds both
    took."""
    from cmal_lcd.workflows.folder_features import feature_function
    from cmal_lcd.matching.loops import match_loops

    start = time.perf_counter()
    extract, metric, extractor_info = feature_function(features, model_dir=model_dir,
                                                       config_overrides=config_overrides)
    codes = extract(images)
    keep = len(images) ** 2 <= MAX_KEPT_CELLS
    result = match_loops(codes, metric=metric, params=params, n_allowed=n_allowed,
                         keep_matrices=keep)
    return codes, metric, extractor_info, result, keep, time.perf_counter() - start


def _listed_closures(result, threshold: float | None):
    """``bool (N,)``: scored frames, with ``score <= threshold`` when one is given."""
    scored = result.match >= 0
    return scored & (result.confidence_score <= threshold if threshold is not None else True)


def _loops_params(params, extractor_info: dict, *, exclude_frames, exclude_metres, threshold,
                  folder, evaluated: bool, d_thresh, poses_tolerance,
                  config_overrides: Sequence[str] = ()) -> dict:
    """The ``params`` of the record: matching, extractor and loop options (tolerances only
    when ``evaluated``)."""
    record = {**params.as_dict(), **extractor_info, "exclude_frames": exclude_frames,
              "exclude_metres": exclude_metres, "threshold": threshold, "folder": str(folder),
              "config_overrides": list(config_overrides)}
    if evaluated:
        record.update(d_thresh=d_thresh, poses_tolerance=poses_tolerance)
    return record


def _loops_title(label: str, folder, n_frames: int, *, exclude_frames: int,
                 exclude_metres: float | None) -> str:
    """The figure title: method, folder name, frame count and exclusion zone."""
    return (f"{label}: {Path(folder).name}, {n_frames} frames, "
            f"exclusion {exclude_frames} frames"
            + (f" / {exclude_metres} m" if exclude_metres is not None else ""))


def _loops_record(result, detected, evaluation, *, seconds: float, params: dict) -> dict:
    """What ``loops_folder`` returns (and writes as ``metrics.json`` with poses):
    ``n_frames, n_scored, n_detections, seconds``, every metric of ``evaluation`` if any, and
    ``params``."""
    record = {"n_frames": len(result.match), "n_scored": result.n_scored,
              "n_detections": int(detected.sum()), "seconds": seconds}
    if evaluation is not None:
        record.update(evaluation.metrics)
    record["params"] = params
    return record


def _write_loops_figure(path: Path, result, codes, *, metric: str, params, n_allowed,
                        detected, evaluation, xy, keep: bool, title: str) -> None:
    """``loops.png``: the (enhanced) self-difference matrix of ``codes (N, F)`` with the loop
    closures, kept by the search when ``keep``, else of every k-th frame."""
    import numpy as np

    from cmal_lcd.reports.loops_figure import plot_loops

    if keep:
        matrix, label = result.D_hat, ("enhanced self-difference (eq. 14)"
                                       if params.enhancement_window else "self-difference")
        shown_rows = np.arange(len(result.match))
    else:
        matrix, shown_rows = _subsampled_self_difference(codes, metric, n_allowed,
                                                         MAX_KEPT_CELLS)
        label = "self-difference, every k-th frame"
    plot_loops(path, matrix=matrix, shown=shown_rows, n_allowed=n_allowed,
               match=result.match, detected=detected, xy=xy,
               correct=None if evaluation is None else evaluation.correct,
               truth=None if evaluation is None else evaluation.truth,
               title=title, matrix_label=label)


def _check_options(*, exclude_frames, exclude_metres, threshold) -> None:
    """Reject option values the library would reject later, naming the ``--option``
    (``--d-thresh`` and ``--poses-tolerance`` are the schema's to check:
    :func:`~cmal_lcd.workflows.match_folders.with_matching_defaults`)."""
    import math

    if exclude_frames < 0:
        raise ValueError(f"--exclude-frames: must be >= 0, got {exclude_frames}")
    for option, value in (("--exclude-metres", exclude_metres), ("--threshold", threshold)):
        if value is not None and (not math.isfinite(value) or
                                  (value < 0 and option != "--threshold")):
            raise ValueError(f"{option}: must be a finite number >= 0, got {value}")


def _write_loops_csv(path: Path, names, result, detected, evaluation) -> None:
    import numpy as np
    import pandas as pd

    from cmal_lcd.io import atomic_path

    q = np.flatnonzero(detected)
    m = result.match[q]
    table = pd.DataFrame({"query_frame": q, "query_name": [names[i] for i in q],
                          "matched_frame": m, "matched_name": [names[i] for i in m],
                          "score": result.confidence_score[q]})
    if evaluation is not None:
        table["has_revisit"] = evaluation.truth[q] >= 0
        table["correct"] = evaluation.correct[q]
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        table.to_csv(tmp, index=False, lineterminator="\n", float_format="%.9g")


def _subsampled_self_difference(codes, metric, n_allowed, max_cells):
    """``D`` of every k-th frame (``+inf`` in the exclusion zone) and the frames shown."""
    import math

    import numpy as np

    from cmal_lcd.matching import difference_matrix

    k = max(1, math.ceil(math.sqrt(len(codes) ** 2 / max_cells)))
    shown = np.arange(0, len(codes), k)
    D = difference_matrix(codes[shown], codes[shown], metric=metric).astype(np.float32)
    D[shown[:, None] >= n_allowed[shown][None, :]] = np.inf
    return D, shown
