"""The ``cmal-lcd`` command.

Sub-commands (one small function each, ``main(argv)`` dispatches):

- ``cmal-lcd match REFERENCE_DIR QUERY_DIR``: loop closure between two folders of frames (a
  user's own data): features, SeqSLAM with the paper's Table I parameters, metrics, figures.
- ``cmal-lcd compose-params [OVERRIDES...]``: write ``params.yaml`` from ``conf/`` (what DVC
  reads), e.g. ``cmal-lcd compose-params experiment=paper``.
- ``cmal-lcd aggregate SWEEP_DIR --name NAME``: a Hydra sweep folder -> ``reports/sweeps/NAME/``.

A failure is one line on stderr, ``cmal-lcd <command>: error: <message naming the file, folder
or key>``, with exit code 2 (:mod:`cmal_lcd.errors`); ``cmal-lcd --verbose`` adds the traceback.

The argparse namespace stops at the sub-command function, which calls a plain function
(:func:`match_folders`) with explicit arguments. Every default comes from one place:
:class:`~cmal_lcd.matching.SeqSLAMParams` (matching), :data:`~cmal_lcd.evaluation.
DEFAULT_D_THRESH` (tolerance), :data:`DEFAULT_POSES_TOLERANCE` and
:func:`~cmal_lcd.matching.sad_thumbnails` (thumbnail size); tests check them against
``conf/matching/seqslam.yaml``.
"""

from __future__ import annotations

import argparse
import logging
import os
import pickle
import sys
import zipfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported lazily at run time: `cmal-lcd --help` stays fast
    from cmal_lcd.matching import SeqSLAMParams

logger = logging.getLogger(__name__)

#: Default ground-truth tolerance in metres when both folders have ``poses.csv``: the config's
#: ``matching.pose_tolerance`` (one value; ``tests/reliability/test_cli_errors.py`` checks it).
DEFAULT_POSES_TOLERANCE = 5.0

#: ``match`` warns when fewer queries than this are scored (the metrics then rest on a
#: handful of decisions: ``--ds 39`` on 40 frames scores one query, whose R@100P is 0 or 1).
DEFAULT_MIN_SCORED_QUERIES = 10

#: Files written by ``match`` into its output folder.
MATCH_OUTPUTS = ("metrics.json", "pr_curve.png", "difference_matrices.png")

#: Above this many matrix cells (4,096 x 4,096) ``match`` does not keep ``D``/``D_hat`` for the
#: Fig. 6 image (keeping them costs about 20 bytes per cell); the figure is then drawn from the
#: matrices of every k-th frame instead.
MAX_KEPT_CELLS = 16 * 2**20


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``cmal-lcd``; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if not hasattr(args, "func"):
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except Exception as exc:  # noqa: BLE001 - the user-facing boundary: one line, exit 2
        from cmal_lcd.errors import report_failure

        prog = f"cmal-lcd {args.command}" if getattr(args, "command", None) else "cmal-lcd"
        return report_failure(prog, exc, verbose=args.verbose)


def build_parser() -> argparse.ArgumentParser:
    """The ``cmal-lcd`` parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog="cmal-lcd",
        description="CMAL loop closure detection: matching, pipeline helpers.")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log progress; on failure, print the traceback too")
    parser.add_argument("--version", action="version", version=_version_text())
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND", dest="command")
    add_match_parser(subparsers)
    add_compose_params_parser(subparsers)
    add_aggregate_parser(subparsers)
    add_seeds_report_parser(subparsers)
    from cmal_lcd.loops_command import add_loops_parser
    from cmal_lcd.manifest_command import add_verify_manifest_parser

    add_loops_parser(subparsers)  # cmal-lcd loops FOLDER (issue 15)
    add_verify_manifest_parser(subparsers)  # cmal-lcd verify-manifest MANIFEST TARGET
    return parser


# ---------------------------------------------------------------------------- compose-params


def add_compose_params_parser(subparsers) -> argparse.ArgumentParser:
    """``cmal-lcd compose-params [OVERRIDES...] [--output params.yaml]``."""
    p = subparsers.add_parser(
        "compose-params", help="write params.yaml from conf/ (plus Hydra overrides)",
        description="Compose conf/config.yaml with Hydra overrides and write it where DVC "
                    "reads it. Same output as `dvc exp run` with hydra.enabled.")
    p.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. experiment=paper")
    p.add_argument("--output", default=None, type=Path,
                   help="default: params.yaml of the checkout (--repo)")
    p.add_argument("--repo", default=None, type=Path,
                   help="the checkout whose conf/ is composed (default: $CMAL_LCD_REPO, else the "
                        "nearest folder at or above the working directory holding "
                        "conf/config.yaml)")
    p.set_defaults(func=run_compose_params)
    return p


def run_compose_params(args: argparse.Namespace) -> int:
    from cmal_lcd.config import checkout_root, compose_params_yaml

    root = checkout_root(args.repo)
    output = compose_params_yaml(args.overrides, output=args.output or root / "params.yaml",
                                 config_dir=root / "conf")
    print(f"wrote {output}")
    return 0


# --------------------------------------------------------------------------------- aggregate


def add_aggregate_parser(subparsers) -> argparse.ArgumentParser:
    """``cmal-lcd aggregate SWEEP_DIR --name NAME [--out reports/sweeps]``."""
    p = subparsers.add_parser(
        "aggregate", help="turn a Hydra sweep folder into reports/sweeps/<name>/",
        description="Collect every job of a `cmal-lcd-run -m ...` sweep (its overrides and "
                    "metrics) into results.csv, figures against each swept number and, when "
                    "seeds were swept, Table II with mean and 95%% CI over seeds.")
    p.add_argument("sweep_dir", type=Path, help="e.g. multirun/2026-11-22/10-00-00")
    p.add_argument("--name", required=True,
                   help="folder name under --out (letters, digits, '_', '.', '-')")
    p.add_argument("--out", default=Path("reports/sweeps"), type=Path)
    p.set_defaults(func=run_aggregate)
    return p


def run_aggregate(args: argparse.Namespace) -> int:
    from cmal_lcd.names import check_name, output_path
    from cmal_lcd.reports.sweeps import aggregate_sweep

    out = aggregate_sweep(args.sweep_dir,
                          output_path(args.out, check_name(args.name, key="--name")))
    print(f"wrote {out}")
    return 0


def add_seeds_report_parser(subparsers) -> argparse.ArgumentParser:
    """``cmal-lcd seeds-report NAME=SWEEP_DIR ... --default NAME [--out reports/seeds]``."""
    p = subparsers.add_parser(
        "seeds-report", help="compare CMAL objectives over seeds (validation) and write Table II "
                             "with 95%% CIs",
        description="Each argument NAME=SWEEP_DIR is a seed sweep (`cmal-lcd-run -m "
                    "experiment=seeds objective=NAME ...`). Writes README.md and CSVs: CMAL's "
                    "validation scores per objective, Table II mean [95%% CI] over seeds per "
                    "objective, paired differences and invariance.")
    p.add_argument("sweeps", nargs="+", help="objective=sweep folder, e.g. paper=multirun/a")
    p.add_argument("--default", required=True, help="the configuration's default objective")
    p.add_argument("--out", default=Path("reports/seeds"), type=Path)
    p.set_defaults(func=run_seeds_report)
    return p


def run_seeds_report(args: argparse.Namespace) -> int:
    from cmal_lcd.reports.sweeps import write_seeds_report

    sweeps = {}
    for item in args.sweeps:
        name, sep, folder = item.partition("=")
        if not sep or not name or not Path(folder).is_dir():
            print(f"cmal-lcd seeds-report: {item!r}: expected NAME=an existing sweep folder",
                  file=sys.stderr)
            return 2
        sweeps[name] = Path(folder)
    out = write_seeds_report(sweeps, args.out, default=args.default)
    print(f"wrote {out}")
    return 0


# ------------------------------------------------------------------------------------- match


def add_match_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``match``: every default is read from the library (one source)."""
    from cmal_lcd.evaluation import DEFAULT_D_THRESH
    from cmal_lcd.matching import SeqSLAMParams

    d = SeqSLAMParams()
    p = subparsers.add_parser(
        "match", help="loop closure between two folders of frames",
        description="Match QUERY_DIR frames against REFERENCE_DIR frames with SeqSLAM (paper "
                    "Table I defaults), print the metrics and write metrics.json, pr_curve.png "
                    "and difference_matrices.png into --out. Ground truth: from poses when both "
                    "folders have poses.csv, else frame i of the query is frame i of the "
                    "reference.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("reference_dir", type=Path, help="folder of reference frames (*.png, *.jpg)")
    p.add_argument("query_dir", type=Path, help="folder of query frames")
    p.add_argument("--features", default="sad",
                   help="sad, or a learned extractor: dnn, bigan, cmal, cmal_untrained")
    p.add_argument("--model-dir", type=Path, default=None,
                   help="folder holding <name>/model.pt for bigan/cmal, e.g. models/")
    p.add_argument("--ds", type=int, default=d.ds, help="look-back length, query frames")
    p.add_argument("--v-min", type=float, default=d.v_min, help="slowest trajectory velocity")
    p.add_argument("--v-max", type=float, default=d.v_max, help="fastest trajectory velocity")
    p.add_argument("--v-step", type=float, default=d.v_step, help="velocity step")
    p.add_argument("--r-window", type=int, default=d.r_window,
                   help="enhancement and uniqueness window, reference frames")
    p.add_argument("--no-enhance", dest="enhance", action="store_false", default=d.enhance,
                   help="skip the local contrast enhancement (eq. 14)")
    p.add_argument("--score", choices=("ratio", "sum"), default=d.score,
                   help="PR threshold on the uniqueness ratio or the raw sequence score")
    p.add_argument("--d-thresh", type=int, default=DEFAULT_D_THRESH,
                   help="frames: a match this close to the true place is correct")
    p.add_argument("--poses-tolerance", type=float, default=DEFAULT_POSES_TOLERANCE,
                   help="metres: ground-truth radius when both folders have poses.csv")
    p.add_argument("--min-scored-queries", type=int, default=DEFAULT_MIN_SCORED_QUERIES,
                   help="warn when fewer queries than this are scored")
    p.add_argument("--out", type=Path, default=Path("match_out"), help="output folder")
    p.set_defaults(func=run_match)
    return p


def run_match(args: argparse.Namespace) -> int:
    """``cmal-lcd match``: unpack the arguments, run :func:`match_folders`, print the metrics.

    A failure propagates to :func:`main`, which prints it as one line (exit code 2).
    """
    from cmal_lcd.matching import SeqSLAMParams

    params = SeqSLAMParams(ds=args.ds, v_min=args.v_min, v_max=args.v_max, v_step=args.v_step,
                           r_window=args.r_window, enhance=args.enhance, score=args.score)
    metrics = match_folders(args.reference_dir, args.query_dir, features=args.features,
                            params=params, d_thresh=args.d_thresh,
                            poses_tolerance=args.poses_tolerance, out_dir=args.out,
                            model_dir=args.model_dir)
    warn_if_few_scored(metrics, minimum=args.min_scored_queries)
    print(format_metrics(metrics))
    print(f"wrote {', '.join(MATCH_OUTPUTS)} to {args.out}")
    return 0


def match_folders(reference_dir: str | os.PathLike, query_dir: str | os.PathLike, *,
                  features: str = "sad", params: SeqSLAMParams | None = None,
                  d_thresh: int | None = None,
                  poses_tolerance: float = DEFAULT_POSES_TOLERANCE,
                  out_dir: str | os.PathLike = "match_out",
                  model_dir: str | os.PathLike | None = None) -> dict:
    """Match two frame folders and write ``metrics.json`` and the two figures into ``out_dir``.

    Parameters
    ----------
    reference_dir, query_dir : path-like
        Frame folders (see :func:`cmal_lcd.data.frames.read_frame_folder`).
    features : str
        ``sad`` (SeqSLAM thumbnails) or a name of :func:`cmal_lcd.features.build_extractor`.
    params : SeqSLAMParams, optional
        Matching parameters (default Table I).
    d_thresh : int, optional
        Tolerance in frames (default :data:`cmal_lcd.evaluation.DEFAULT_D_THRESH`).
    poses_tolerance : float
        Ground-truth radius in metres, used when both folders have ``poses.csv``.
    out_dir : path-like
        Output folder (created).
    model_dir : path-like, optional
        Folder holding ``<name>/model.pt`` for trained extractors (e.g. ``models/``).

    Returns
    -------
    dict
        ``n_reference, n_query, auc_pr, auc_roc, recall_at_100p, recall_at_1,
        single_frame_recall_at_1, seconds`` (feature extraction + matching wall time), plus
        ``n_scored, n_positive`` and ``params`` (everything used), as written to
        ``metrics.json``.
    """
    from cmal_lcd.data.frames import read_frame_folder
    from cmal_lcd.evaluation import (
        DEFAULT_D_THRESH,
        correct_matches,
        ground_truth_from_correspondence,
        ground_truth_from_poses,
        loop_closure_metrics,
        precision_recall_curve,
    )
    from cmal_lcd.io import atomic_write_json
    from cmal_lcd.matching import SeqSLAMParams, match_sequences
    from cmal_lcd.reports.plots import plot_difference_matrices, plot_pr_curves

    params = SeqSLAMParams() if params is None else params
    d_thresh = DEFAULT_D_THRESH if d_thresh is None else d_thresh
    out_dir = Path(out_dir)
    check_feature_name(features)
    reference = read_frame_folder(reference_dir)
    query = read_frame_folder(query_dir)
    if len(query) <= params.ds:
        raise ValueError(f"{query_dir}: {len(query)} query frames; the look-back search needs "
                         f"more than ds={params.ds}")
    if len(reference) < params.ds:
        raise ValueError(f"{reference_dir}: {len(reference)} reference frames; a sequence "
                         f"spans ds={params.ds} frames of the reference, so it needs at least "
                         f"ds frames")
    check_poses_in_both(reference_dir, reference.poses is not None,
                        query_dir, query.poses is not None)
    prepare_output_folder(out_dir, MATCH_OUTPUTS)

    start = time.perf_counter()
    extract, metric, extractor_info = _feature_function(features, model_dir=model_dir)
    logger.info("match: %s features of %d reference frames", features, len(reference))
    ref_features = extract(reference.images)
    logger.info("match: %s features of %d query frames", features, len(query))
    query_features = extract(query.images)
    keep = len(reference) * len(query) <= MAX_KEPT_CELLS
    from cmal_lcd.progress import Progress

    with Progress(len(query), desc="match: SeqSLAM", unit="query", logger=logger) as bar:
        result = match_sequences(ref_features, query_features, metric=metric, params=params,
                                 keep_matrices=keep, progress=bar.update)
    seconds = time.perf_counter() - start
    logger.info("match: %d of %d queries scored in %.1f s; writing %s", result.n_scored,
                len(query), seconds, ", ".join(MATCH_OUTPUTS))

    if reference.poses is not None and query.poses is not None:
        truth = ground_truth_from_poses(reference.poses[["x", "y"]].to_numpy(),
                                        query.poses[["x", "y"]].to_numpy(),
                                        max_distance=poses_tolerance)
        truth_source = "poses"
    else:
        truth = ground_truth_from_correspondence(len(reference), len(query))
        truth_source = "frame index"
    metrics = loop_closure_metrics(result.match, result.confidence_score, truth,
                                   d_thresh=d_thresh,
                                   single_frame_match=result.single_frame_match)
    record = {"n_reference": len(reference), "n_query": len(query), **metrics,
              "seconds": seconds,
              "params": {**params.as_dict(), "d_thresh": d_thresh, **extractor_info,
                         "ground_truth": truth_source,
                         "poses_tolerance": poses_tolerance if truth_source == "poses" else None,
                         "reference_dir": str(reference_dir), "query_dir": str(query_dir)}}
    atomic_write_json(out_dir / "metrics.json", record)

    scored = result.match >= 0
    correct = correct_matches(result.match, truth, d_thresh=d_thresh)[scored]
    precision, recall, _ = precision_recall_curve(result.confidence_score[scored], correct,
                                                  n_positive=metrics["n_positive"])
    label = extractor_info.get("label", features)
    plot_pr_curves({f"{label} + SeqSLAM": (recall, precision)}, path=out_dir / "pr_curve.png",
                   title=f"{Path(reference_dir).name} (reference) vs {Path(query_dir).name} "
                         f"(query)")
    if keep:
        D, D_hat = result.D, result.D_hat
    else:
        D, D_hat = _subsampled_matrices(ref_features, query_features, metric=metric,
                                        params=params)
    plot_difference_matrices(D, D_hat, path=out_dir / "difference_matrices.png",
                             match=result.match if keep else None,
                             truth=truth if keep else None,
                             title=f"{label}: {len(reference)} reference x {len(query)} query "
                                   f"frames" + ("" if keep else " (every k-th frame shown)"))
    return record


def check_feature_name(name: str) -> None:
    """Refuse a ``--features`` value that names no extractor (before any file is read).

    Raises
    ------
    ValueError
        ``--features must be one of [...], got '<name>'``.
    """
    from cmal_lcd.features import METHOD_NAMES

    if name != "sad" and name not in METHOD_NAMES:
        raise ValueError(f"--features must be one of {['sad', *METHOD_NAMES]}, got {name!r}")


def check_poses_in_both(reference_dir, reference_has_poses: bool, query_dir,
                        query_has_poses: bool) -> None:
    """Refuse ``poses.csv`` in only one folder (it would silently fall back to index truth).

    Raises
    ------
    ValueError
        ``<folder without poses>: no poses.csv, but <other>/poses.csv exists; ...``.
    """
    if reference_has_poses == query_has_poses:
        return
    missing, other = ((query_dir, reference_dir) if reference_has_poses
                      else (reference_dir, query_dir))
    raise ValueError(f"{missing}: no poses.csv, but {Path(other) / 'poses.csv'} exists; give "
                     f"both folders poses.csv (ground truth from poses) or neither (query frame "
                     f"i is reference frame i)")


def prepare_output_folder(out_dir: Path, files: Sequence[str] = ()) -> None:
    """Create ``out_dir`` and check that each of ``files`` can be written there.

    Raises
    ------
    ValueError
        Naming ``out_dir`` (a file in the way, cannot be created, not writable) or the output
        file a folder stands in the way of.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"{out_dir}: --out is a file, not a folder")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"{out_dir}: cannot create the output folder "
                         f"({err.strerror or err})") from err
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise ValueError(f"{out_dir}: the output folder is not writable")
    for name in files:
        if (out_dir / name).is_dir():
            raise ValueError(f"{out_dir / name}: a folder stands where this output file goes; "
                             f"move it or choose another --out")


def warn_if_few_scored(metrics: dict, *, minimum: int) -> bool:
    """Print a warning when fewer than ``minimum`` queries were scored; return whether it did."""
    n_scored, n_query = metrics.get("n_scored"), metrics.get("n_query")
    if n_scored is None or n_scored >= minimum:
        return False
    print(f"cmal-lcd match: warning: only {n_scored} of {n_query} queries scored (fewer than "
          f"--min-scored-queries {minimum}); the metrics rest on too few decisions (lower --ds "
          f"or use longer folders)", file=sys.stderr)
    return True


#: The trained model each learned extractor loads (``<model_dir>/<name>/model.pt``).
EXTRACTOR_MODELS = {"cmal": "cmal", "cmal_untrained": "cmal", "bigan": "bigan"}


def _feature_function(name: str, *, model_dir):
    """``(extract(images) -> (N, F), metric, info)`` for a feature name."""
    if name == "sad":
        from cmal_lcd.matching import sad_thumbnails

        defaults = {k: v.default for k, v in _keyword_defaults(sad_thumbnails).items()}
        return sad_thumbnails, "sad", {"features": "sad", "label": "SAD", "sad": defaults}
    from cmal_lcd.config import compose
    from cmal_lcd.features import METHOD_NAMES, build_extractor, extractor_conf

    if name not in METHOD_NAMES:
        raise ValueError(f"--features must be one of {list(METHOD_NAMES)}, got {name!r}")
    try:
        extractor = build_extractor(name, conf=extractor_conf(compose(), name),
                                    model_dir=model_dir)
    except (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile) as err:
        model_file = Path(model_dir or ".") / EXTRACTOR_MODELS.get(name, name) / "model.pt"
        raise ValueError(f"{model_file}: not a readable trained model (truncated, corrupt, or "
                         f"holding objects other than tensors, which are never loaded: "
                         f"{type(err).__name__}); re-run the train stage") from err
    info = {"features": name, "label": extractor.label, "weights": extractor.weights}
    return extractor, extractor.metric, info


def _keyword_defaults(func) -> dict:
    import inspect

    return {k: v for k, v in inspect.signature(func).parameters.items()
            if v.kind is inspect.Parameter.KEYWORD_ONLY}


def _subsampled_matrices(ref_features, query_features, *, metric, params):
    """``D`` and ``D_hat`` of every k-th frame (for the figure when the full matrices are big)."""
    import math

    from cmal_lcd.matching import difference_matrix, enhance_contrast

    k = max(1, math.ceil(math.sqrt(len(ref_features) * len(query_features) / MAX_KEPT_CELLS)))
    D = difference_matrix(ref_features[::k], query_features[::k], metric=metric)
    return D, enhance_contrast(D, r_window=params.enhancement_window)


def _version_text() -> str:
    """``cmal-lcd X.Y.Z`` (the installed distribution's version, else the package's)."""
    try:
        from importlib.metadata import version

        number = version("cmal-lcd")
    except Exception:  # noqa: BLE001 - not installed (e.g. PYTHONPATH=src): the package's own
        from cmal_lcd import __version__ as number
    return f"cmal-lcd {number}"


def format_metrics(metrics: dict) -> str:
    """Human-readable lines for the printed summary."""
    keys = ("n_reference", "n_query", "auc_pr", "auc_roc", "recall_at_100p", "recall_at_1",
            "single_frame_recall_at_1", "seconds")
    lines = []
    for key in keys:
        value = metrics[key]
        lines.append(f"{key:>26}: {value:.4f}" if isinstance(value, float) else
                     f"{key:>26}: {value}")
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
