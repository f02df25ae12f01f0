"""``cmal-lcd match REFERENCE QUERY``: loop closure between two folders of frames (or two
descriptor files), through :func:`cmal_lcd.workflows.match_folders.match_folders`.

Which protocol applies is :func:`cmal_lcd.evaluation.chosen_protocol.choose_protocol`'s rule
(printed, and recorded under ``params.protocol``); which ground truth,
:func:`cmal_lcd.evaluation.pair_truth.checked_ground_truth`'s. A failure is one line on stderr
naming the file, folder or option, exit code 2 (raised as a ``ValueError``;
:func:`cmal_lcd.commands.main` prints it). Imports stay inside the functions: ``cmal-lcd --help``
stays fast and SAD matching never imports torch.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: ``match`` warns when fewer queries than this are scored (the metrics then rest on a
#: handful of decisions: ``--ds 39`` on 40 frames scores one query, whose R@100P is 0 or 1).
DEFAULT_MIN_SCORED_QUERIES = 10


def add_match_parser(subparsers, conf: dict) -> argparse.ArgumentParser:
    """Register ``match``; every matching default comes from ``conf``, the ``matching`` node
    of ``conf/`` (:func:`cmal_lcd.config.command_matching`, with the ``--config``
    overrides)."""
    from cmal_lcd.commands.arguments import (DefaultsHelpFormatter, add_config_argument,
                                             add_seqslam_arguments)

    p = subparsers.add_parser(
        "match", help="loop closure between two folders of frames or two descriptor files",
        description="Match QUERY against REFERENCE (two folders of frames, or two files of "
                    "precomputed descriptors) with SeqSLAM (paper Table I defaults) under a "
                    "matching protocol (code normalisation and enhancement, as the evaluate "
                    "stage), print the sequence and single-frame metrics and the timing, and "
                    "write metrics.json, matches.csv, candidates.npz, pr_curve.png and "
                    "difference_matrices.png into --out (replaced as a whole once complete; "
                    "docs/ground_truth.md). Ground truth: --ground-truth FILE "
                    "when given (docs/ground_truth.md), else from poses when both folders have "
                    "poses.csv, else frame (row) i of the query is frame i of the reference.",
        formatter_class=DefaultsHelpFormatter)
    p.add_argument("reference_dir", metavar="REFERENCE", type=Path,
                   help="folder of reference frames (*.png, *.jpg; sorted by name, by integer "
                        "value when every name is an integer; a Mapillary SLS side, "
                        "<city>/database, in seq_info.csv order, its sequences matched apart), "
                        "or a descriptor file (.npy, .npz, .mat, .h5: one row per frame, in "
                        "sequence order)")
    p.add_argument("query_dir", metavar="QUERY", type=Path,
                   help="folder of query frames, or a descriptor file (as REFERENCE)")
    p.add_argument("--features", default=None,
                   help="for folders: sad (default), or an extractor: dnn, dnn_head, bigan, "
                        "cmal, cmal_untrained, or one of `extractors` in conf/config.yaml. "
                        "Descriptor files are matched as given "
                        "(squared Euclidean distance, eq. 13)")
    p.add_argument("--descriptor-key", default=None,
                   help="the array to read from both descriptor files: an .npz key, a MATLAB "
                        "variable or struct.field, an HDF5 path with '.' for '/'. Default: "
                        "the file's only 2-D numeric array")
    p.add_argument("--ground-truth", default=None,
                   help="ground-truth file: VPR-Bench ground_truth_new.npy, or VPR_Tutorial "
                        "GThard (+ GTsoft, ignored entries) reference x query matrices in "
                        ".npz, .mat (v5, v7.3) or .h5; or 'utm': positions in the frames' "
                        "@UTM_east@UTM_north@...@.jpg names (VPR-methods-evaluation); or "
                        "'msls': easting/northing of two Mapillary SLS sides' "
                        "postprocessed.csv; both within --positive-dist-threshold "
                        "(docs/ground_truth.md). Its own tolerance applies: --d-thresh and "
                        "poses.csv then play no part")
    p.add_argument("--positive-dist-threshold", type=float, default=None,
                   help="metres, with --ground-truth utm or msls (default: "
                        "positive_dist_threshold of conf/data/folders.yaml; "
                        "VPR-methods-evaluation and MSLS's evaluate.py use 25)")
    p.add_argument("--model-dir", type=Path, default=None,
                   help="folder holding <name>/model.pt for bigan/cmal, e.g. models/; its "
                        "parent is the checkout searched for the protocol")
    p.add_argument("--protocol", default=None,
                   help="a data/protocol/<method>.json (select_protocol stage), or 'raw' (codes "
                        "as extracted, enhancement from --no-enhance/--r-window). Default: raw "
                        "for sad; for other features <checkout>/data/protocol/<method>.json "
                        "when it exists, else raw (with a warning)")
    p.add_argument("--train-features", type=Path, default=None,
                   help="features folder (data/features/<method>) whose training codes give "
                        "the centring means of a centre=condition protocol; default: "
                        "data/features/<method> beside the protocol file's data/protocol")
    add_config_argument(p)
    add_seqslam_arguments(
        p, conf=conf, ds_help="look-back length, query frames",
        r_window_help="enhancement and uniqueness window, reference frames (raw protocol)",
        enhance_help="skip the local contrast enhancement (eq. 14) (raw protocol)",
        score_help="PR threshold on the uniqueness ratio or the raw sequence score")
    p.add_argument("--d-thresh", type=int, default=conf["d_thresh"],
                   help="frames: a match this close to the true place is correct")
    p.add_argument("--poses-tolerance", type=float, default=conf["pose_tolerance"],
                   help="metres: ground-truth radius when both folders have poses.csv "
                        "(matching.pose_tolerance of conf/matching/seqslam.yaml)")
    p.add_argument("--min-scored-queries", type=int, default=DEFAULT_MIN_SCORED_QUERIES,
                   help="warn when fewer queries than this are scored")
    p.add_argument("--out", type=Path, default=Path("match_out"),
                   help="output folder (created; replaced as a whole; refused when it holds "
                        "files match did not write)")
    p.add_argument("--no-figures", dest="figures", action="store_false",
                   help="no PR curve and no matrix figure (faster; the numbers and the other "
                        "files are the same)")
    p.add_argument("--save-descriptors", action="store_true",
                   help="also write descriptors.npz: the reference and query features as "
                        "extracted (rows = frames)")
    p.add_argument("--save-matrix", action="store_true",
                   help="also write difference_matrix.npz: D and the searched D_hat, float32 "
                        "reference x query")
    p.add_argument("--float32-codes", action="store_true",
                   help="squared Euclidean distances of codes computed in float32 (metric "
                        "sqeuclidean_f32): about twice as fast on large maps; distances carry "
                        "an error of about 1e-6 |code|^2 (benchmarks/README.md). No effect "
                        "on sad")
    p.add_argument("--quantise-sad", action="store_true",
                   help="SAD on z-scores rounded to one byte each (metric sad_u8, "
                        "matching.sad.quantise of conf/matching/seqslam.yaml): about twice as "
                        "fast; on the Nordland pairs AUC-PR and R@100P moved by at most 0.004 "
                        "(benchmarks/README.md). Only with --features sad")
    p.set_defaults(func=run_match)
    return p


def run_match(args: argparse.Namespace) -> int:
    """``cmal-lcd match``: unpack the arguments, run :func:`match_folders`, print the results.

    A failure propagates to :func:`cmal_lcd.commands.main`, which prints it as one line (exit 2).
    """
    from cmal_lcd.commands.arguments import seqslam_params
    from cmal_lcd.workflows.match_folders import match_folders, outputs_written
    if args.min_scored_queries < 0:
        raise ValueError(f"--min-scored-queries: must be >= 0, got {args.min_scored_queries}")
    params = seqslam_params(args)
    record = match_folders(args.reference_dir, args.query_dir, features=args.features,
                           descriptor_key=args.descriptor_key,
                           ground_truth=args.ground_truth,
                           positive_dist_threshold=args.positive_dist_threshold,
                           params=params, d_thresh=args.d_thresh,
                           poses_tolerance=args.poses_tolerance, out_dir=args.out,
                           model_dir=args.model_dir, protocol=args.protocol,
                           train_features=args.train_features, figures=args.figures,
                           float32_codes=args.float32_codes, quantise_sad=args.quantise_sad,
                           save_descriptors=args.save_descriptors,
                           save_matrix=args.save_matrix, config_overrides=args.config)
    chosen = record["params"]["protocol"]
    if chosen.get("warning"):
        print(f"cmal-lcd match: warning: {chosen['warning']}", file=sys.stderr)
    warn_if_few_scored(record, minimum=args.min_scored_queries)
    print(f"protocol: {chosen['label']} ({chosen['source']})")
    print(f"ground truth: {record['ground_truth']['source']} "
          f"(tolerance: {record['ground_truth']['tolerance']})")
    print(format_metrics(record))
    print(format_timing(record["timing"], record["timing_cpu"]))
    written = outputs_written(figures=args.figures, save_descriptors=args.save_descriptors,
                              save_matrix=args.save_matrix)
    print(f"wrote {', '.join(written)} to {args.out}")
    return 0


def warn_if_few_scored(metrics: dict, *, minimum: int) -> bool:
    """Print a warning when fewer than ``minimum`` queries were scored; return whether it did."""
    n_scored, n_query = metrics.get("n_scored"), metrics.get("n_query")
    if n_scored is None or n_scored >= minimum:
        return False
    print(f"cmal-lcd match: warning: only {n_scored} of {n_query} queries scored (fewer than "
          f"--min-scored-queries {minimum}); the metrics rest on too few decisions (lower --ds "
          f"or use longer folders)", file=sys.stderr)
    return True


def format_metrics(metrics: dict) -> str:
    """Human-readable lines for the printed summary."""
    keys = ("n_reference", "n_query", "auc_pr", "auc_roc", "recall_at_100p", "recall_at_1",
            "single_frame_recall_at_1", "seconds")
    lines = []
    for key in keys:
        value = metrics[key]
        lines.append(f"{key:>26}: {value:.4f}" if isinstance(value, float) else
                     f"{key:>26}: {value}")
    single = metrics.get("single_frame") or {}
    side_by_side = [key for key in ("auc_pr", "recall_at_100p", "recall_at_1", "recall_at_5",
                                    "recall_at_10", "recall_at_20", "n_scored")
                    if key in metrics and key in single]
    if side_by_side:
        lines.append(f"{'':>26}  {'sequence':>10}  {'single frame':>12}")
        for key in side_by_side:
            lines.append(f"{key:>26}  {_number(metrics[key]):>10}  {_number(single[key]):>12}")
    return "\n".join(lines)


def _number(value) -> str:
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def format_timing(wall: dict, cpu: dict) -> str:
    """``time (s, wall/cpu): decode 0.41/0.70, ..., match 1.20/2.10 (difference 0.50,
    search 0.40, metrics 0.30), ..., total 2.71/3.90`` (the steps that ran; parts: wall)."""
    from cmal_lcd.workflows.match_folders import MATCH_PARTS, TIMING_KEYS

    parts = ", ".join(f"{k} {wall[k]:.2f}" for k in MATCH_PARTS if k in wall)
    steps = [f"{k} {wall[k]:.2f}/{cpu[k]:.2f}" + (f" ({parts})" if k == "match" and parts else "")
             for k in TIMING_KEYS if k in wall]
    return "time (s, wall/cpu): " + ", ".join(steps)
