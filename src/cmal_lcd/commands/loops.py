"""``cmal-lcd loops FOLDER``: loop closures within one traversal of a user's own frames,
through :func:`cmal_lcd.workflows.loops_folder.loops_folder` (what it writes is said there).

Bad input (missing folder, corrupt image, bad ``poses.csv``, bad option) prints one line naming
the file, folder or option and exits with code 2. Imports stay inside the functions:
``cmal-lcd --help`` stays fast.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

def add_loops_parser(subparsers, conf: dict) -> argparse.ArgumentParser:
    """Register ``loops``; matching defaults come from ``conf``, the ``matching`` node of
    ``conf/`` (as for ``match``)."""
    from cmal_lcd.commands.arguments import (DefaultsHelpFormatter, add_config_argument,
                                             add_seqslam_arguments)
    from cmal_lcd.matching.loops import DEFAULT_EXCLUDE_FRAMES

    p = subparsers.add_parser(
        "loops", help="loop closures within one folder of frames (one traversal)",
        description="Match every frame of FOLDER against its older frames (outside an "
                    "exclusion zone) with SeqSLAM and write loops.csv, loops.png and, when "
                    "FOLDER has poses.csv, metrics.json (a revisit is an older frame within "
                    "--poses-tolerance metres).",
        formatter_class=DefaultsHelpFormatter)
    p.add_argument("folder", type=Path, help="folder of frames (*.png, *.jpg), optional "
                                             "poses.csv (name, x, y)")
    p.add_argument("--features", default="sad",
                   help="sad, or another method: dnn, dnn_head, bigan, cmal, cmal_untrained, "
                        "or one of `extractors` in conf/config.yaml")
    p.add_argument("--model-dir", type=Path, default=None,
                   help="folder holding <name>/model.pt for bigan/cmal, e.g. models/")
    p.add_argument("--exclude-frames", type=int, default=DEFAULT_EXCLUDE_FRAMES,
                   help="a frame only matches frames more than this many frames older")
    p.add_argument("--exclude-metres", type=float, default=None,
                   help="also more than this many metres of travel back (needs poses.csv)")
    add_config_argument(p)
    add_seqslam_arguments(
        p, conf=conf, ds_help="look-back length, frames",
        r_window_help="enhancement and uniqueness window, frames",
        enhance_help="skip the local contrast enhancement (eq. 14)",
        score_help="confidence: uniqueness ratio or raw sequence score (lower = surer)")
    p.add_argument("--threshold", type=float, default=None,
                   help="list only loop closures with score <= this (default: every scored "
                        "frame)")
    p.add_argument("--d-thresh", type=int, default=conf["d_thresh"],
                   help="frames: a match this close to a revisit is correct")
    p.add_argument("--poses-tolerance", type=float, default=conf["pose_tolerance"],
                   help="metres: an older frame this close is a revisit")
    p.add_argument("--out", type=Path, default=Path("loops_out"), help="output folder")
    p.set_defaults(func=run_loops)
    return p


def run_loops(args: argparse.Namespace) -> int:
    """``cmal-lcd loops``: run :func:`loops_folder`, print a summary; bad input -> one line, 2."""
    from cmal_lcd.commands.arguments import seqslam_params
    from cmal_lcd.data.frames import FrameReadError
    from cmal_lcd.workflows.loops_folder import LOOPS_OUTPUTS, loops_folder

    try:
        params = seqslam_params(args)
        record = loops_folder(args.folder, features=args.features, params=params,
                              exclude_frames=args.exclude_frames,
                              exclude_metres=args.exclude_metres, threshold=args.threshold,
                              d_thresh=args.d_thresh, poses_tolerance=args.poses_tolerance,
                              out_dir=args.out, model_dir=args.model_dir,
                              config_overrides=args.config)
    except (FrameReadError, ValueError) as exc:
        message = " ".join(str(exc).split())
        print(f"cmal-lcd loops: error: {message}", file=sys.stderr)
        return 2
    print(f"{record['n_frames']} frames, {record['n_scored']} scored, "
          f"{record['n_detections']} loop closures listed")
    for key in ("auc_pr", "auc_roc", "recall_at_100p", "recall_at_1",
                "single_frame_recall_at_1"):
        if key in record:
            print(f"{key:>26}: {record[key]:.4f}")
    written = [name for name in LOOPS_OUTPUTS if name != "metrics.json" or "auc_pr" in record]
    print(f"wrote {', '.join(written)} to {args.out}")
    return 0
