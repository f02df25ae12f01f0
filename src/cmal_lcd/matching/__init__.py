"""SeqSLAM sequence matching: SAD thumbnails, difference matrix, contrast enhancement, search.

Pure functions, no I/O. ``D[r, q]``: rows = reference frames, columns = query frames; lower =
more alike. The conventions (windows, look-back trajectories, uniqueness ratio, excluded
constant windows) are written once in :mod:`cmal_lcd.matching.seqslam`; the SAD thumbnail
conventions in :mod:`cmal_lcd.matching.sad`; the metrics in :mod:`cmal_lcd.matching.difference`.

Typical use::

    from cmal_lcd.matching import SeqSLAMParams, match_sequences, sad_thumbnails
    result = match_sequences(sad_thumbnails(ref_images), sad_thumbnails(query_images),
                             metric="sad", params=SeqSLAMParams.defaults())
    result.match, result.confidence_score   # (Q,), lower = more confident
"""

from cmal_lcd.matching.difference import METRICS, difference_matrix
from cmal_lcd.matching.params import (
    SeqSLAMParams,
    check_matching,
    matching_defaults,
    trajectory_offsets,
    trajectory_velocities,
)
from cmal_lcd.matching.sad import sad_metric, sad_thumbnails, thumbnail_options
from cmal_lcd.matching.seqslam import (
    MatchResult,
    SequenceBlocks,
    SequenceMatches,
    enhance_contrast,
    match_sequences,
    sequence_search,
    single_frame_matches,
)

__all__ = [
    "METRICS",
    "MatchResult",
    "SeqSLAMParams",
    "SequenceBlocks",
    "SequenceMatches",
    "check_matching",
    "difference_matrix",
    "enhance_contrast",
    "match_sequences",
    "matching_defaults",
    "sad_metric",
    "sad_thumbnails",
    "sequence_search",
    "single_frame_matches",
    "thumbnail_options",
    "trajectory_offsets",
    "trajectory_velocities",
]
