"""The ground truth of a user's pair, and how ``metrics.json`` describes it.

In this order (:func:`checked_ground_truth`): a ground-truth file or position keyword
(``--ground-truth``: :mod:`cmal_lcd.data.gt_files`, ``docs/ground_truth.md``; ``msls`` by
default for two Mapillary SLS sides); else ``poses.csv`` of both folders; else by frame index
(query frame ``i`` is reference frame ``i``), the ``evaluate`` stage's conventions.
"""

from __future__ import annotations

import logging
import os
from typing import TYPE_CHECKING

from cmal_lcd.data.pair_inputs import DescriptorFile, check_lengths, check_poses_in_both

if TYPE_CHECKING:  # imported lazily at run time
    from cmal_lcd.data.frames import FrameFolder

logger = logging.getLogger(__name__)

def checked_ground_truth(reference_dir, reference: FrameFolder | DescriptorFile, query_dir,
                          query: FrameFolder | DescriptorFile, *, ds: int,
                          poses_tolerance: float, ground_truth: str | os.PathLike | None = None,
                          positive_dist_threshold: float | None = None):
    """``(truth_kind, truth)`` after checking the lengths and that both or neither folder has
    poses: ``"file"`` and the :class:`~cmal_lcd.data.ground_truth.ReferenceSets` of
    ``ground_truth`` (``msls`` by default for two Mapillary SLS sides), or ``"poses"`` or
    ``"index"`` and the ground truth of every query (the evaluate stage's conventions;
    ``"index"`` uses the lengths)."""
    from cmal_lcd.evaluation.loop_closure import ground_truth_for_pair

    from cmal_lcd.data import gt_files

    check_lengths(reference_dir, len(reference), query_dir, len(query), ds=ds)
    if ground_truth is None and all(side.sequences is not None for side in (reference, query)):
        ground_truth = gt_files.MSLS  # two Mapillary SLS sides carry their positions
    keyword = str(ground_truth) if str(ground_truth) in gt_files.POSITION_KEYWORDS else None
    if positive_dist_threshold is not None and keyword is None:
        raise ValueError(f"--positive-dist-threshold: only with --ground-truth "
                         f"{' or '.join(gt_files.POSITION_KEYWORDS)}")
    if keyword is not None and isinstance(reference, DescriptorFile):
        raise ValueError(f"--ground-truth {keyword}: positions come from the frame folders, "
                         f"but {reference_dir} is a descriptor file")
    if keyword == gt_files.MSLS:
        return "file", gt_files.msls_ground_truth(reference_dir, query_dir,
                                                  radius=positive_dist_threshold)
    if keyword == gt_files.UTM:
        from cmal_lcd.data.frames import ORDER_NAME, frame_order

        for folder, side in ((reference_dir, reference), (query_dir, query)):
            if frame_order(side.names) == ORDER_NAME:
                logger.warning("%s: frames without a timestamp in their names are ordered by "
                               "name, i.e. by UTM east, not in travel order; sequence "
                               "matching assumes travel order", folder)
        return "file", gt_files.utm_ground_truth(reference.names, query.names,
                                                 reference_dir=reference_dir,
                                                 query_dir=query_dir,
                                                 radius=positive_dist_threshold)
    if ground_truth is not None:
        return "file", gt_files.read_ground_truth_file(ground_truth,
                                                       n_reference=len(reference),
                                                       n_query=len(query))
    check_poses_in_both(reference_dir, reference.poses is not None,
                        query_dir, query.poses is not None)
    truth_kind = "poses" if reference.poses is not None else "index"
    truth = ground_truth_for_pair(
        reference.poses if truth_kind == "poses" else reference.names,
        query.poses if truth_kind == "poses" else query.names,
        kind=truth_kind, pose_tolerance=poses_tolerance)
    return truth_kind, truth


def ground_truth_record(truth_kind: str, truth, reference, query, *, d_thresh: int,
                         poses_tolerance: float) -> dict:
    """``metrics.json``'s ``ground_truth``: ``kind, source, tolerance, frame_order`` and
    ``n_query_without_reference`` (plus the pair counts of a file)."""
    import numpy as np

    from cmal_lcd.data.gt_files import describe_ground_truth

    order = ("rows of the descriptor files" if isinstance(reference, DescriptorFile)
             else reference.order)
    if not isinstance(query, DescriptorFile) and query.order != order:
        order = f"reference: {order}; query: {query.order}"
    if truth_kind == "file":
        return {"kind": truth_kind, **describe_ground_truth(truth), "frame_order": order}
    if truth_kind == "poses":
        source, tolerance = ("poses.csv of both folders (nearest reference pose)",
                             f"{poses_tolerance:g} m to a reference pose, then {d_thresh} "
                             f"frames of it")
    else:
        source, tolerance = "frame index: query frame i is reference frame i", \
            f"{d_thresh} frames"
    return {"kind": truth_kind, "source": source, "tolerance": tolerance,
            "frame_order": order,
            "n_query_without_reference": int(np.sum(np.asarray(truth) < 0))}
