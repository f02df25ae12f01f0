"""``cmal-lcd match REFERENCE_DIR QUERY_DIR``: loop closure between two folders of frames.

A user's own data through the pipeline's evaluation path: frames are decoded (on a thread
pool), turned into features (SAD thumbnails, or a DNN / learned extractor), normalised and
matched under a *matching protocol* exactly as the ``evaluate`` stage does
(:func:`cmal_lcd.evaluation.loop_closure.evaluate_pair`: code normalisation, eq. 14 on or off,
SeqSLAM with the paper's Table I parameters, loop closure metrics), then ``metrics.json``,
the exports (``matches.csv``, ``candidates.npz``; ``descriptors.npz`` and
``difference_matrix.npz`` on request) and the figures ``pr_curve.png`` and
``difference_matrices.png`` are written into ``--out``. Two descriptor files instead of two
folders are matched as given; ``--ground-truth`` reads the field's ground-truth files
(``docs/ground_truth.md``).

Which protocol (:func:`choose_protocol`; printed, and recorded under ``params.protocol``):

- ``--protocol FILE``: the ``selected`` protocol of a ``data/protocol/<method>.json`` written by
  the ``select_protocol`` stage (chosen on validation drives);
- ``--protocol raw``: codes as extracted, enhancement as ``--no-enhance``/``--r-window`` say
  (by default eq. 14 with Table I's window: the paper's protocol);
- neither, ``--features sad``: ``raw`` (SAD keeps the paper's matching);
- neither, a DNN or learned extractor: the file the pipeline writes,
  ``<checkout>/data/protocol/<method>.json`` with ``<checkout>`` the folder holding
  ``--model-dir`` (else the checkout of the working directory); when it is absent, ``raw``,
  with a warning (raw learned codes with eq. 14 tend to match the weather, not the place).

Centring statistics (``centre=condition``) come from the *training* codes of the pipeline's
features folder (``--train-features``, default ``<checkout>/data/features/<method>``), never
from the query folder: a robot sees its queries one at a time.

Outputs are old or new, never a mix: everything is written into a temporary sibling folder of
``--out``, which replaces ``--out`` only once complete
(:func:`cmal_lcd.io.staged_output_folder`). An
``--out`` holding anything but ``match``'s own outputs is refused, never emptied.

A failure is one line on stderr naming the file, folder or option, exit code 2 (raised as a
``ValueError``; :func:`cmal_lcd.cli.main` prints it). Imports stay inside the functions:
``cmal-lcd --help`` stays fast and SAD matching never imports torch.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import logging
import os
import pickle
import sys
import time
import zipfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported lazily at run time
    import numpy as np

    from cmal_lcd.data.frames import FrameFolder
    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.matching import SeqSLAMParams

logger = logging.getLogger(__name__)

#: ``match`` warns when fewer queries than this are scored (the metrics then rest on a
#: handful of decisions: ``--ds 39`` on 40 frames scores one query, whose R@100P is 0 or 1).
DEFAULT_MIN_SCORED_QUERIES = 10

#: Files written by ``match`` into its output folder by default (``docs/ground_truth.md``,
#: "Export"): the metrics, the per-query matches and verdicts, the ranked candidates, the two
#: figures (not with ``--no-figures``).
MATCH_OUTPUTS = ("metrics.json", "matches.csv", "candidates.npz", "pr_curve.png",
                 "difference_matrices.png")
#: Files ``match`` writes on request: ``--save-descriptors``, ``--save-matrix``.
OPTIONAL_OUTPUTS = ("descriptors.npz", "difference_matrix.npz")
#: Figures among :data:`MATCH_OUTPUTS`.
FIGURE_OUTPUTS = ("pr_curve.png", "difference_matrices.png")
#: ``--save-matrix`` refuses maps above this many cells (two float32 matrices of 1 GiB each).
MAX_SAVED_CELLS = 2**28

#: Up to this many matrix cells (4,096 x 4,096) ``loops`` keeps the self-difference matrix of
#: the search for its figure; above, the figure's cells are computed again for every k-th frame.
MAX_KEPT_CELLS = 16 * 2**20

#: Largest side of the matrices drawn in ``difference_matrices.png`` (every k-th frame): each
#: panel is about 550 pixels wide at 150 dpi, so more rows only cost drawing time.
DISPLAY_SIDE = 600

#: ``--protocol`` value for codes as extracted, enhancement from ``--no-enhance``/``--r-window``.
RAW_PROTOCOL = "raw"

#: The ``features`` of descriptor files (:mod:`cmal_lcd.data.descriptors`): matched as given,
#: by squared Euclidean distance (eq. 13).
PRECOMPUTED = "precomputed"

#: Steps of the timing split printed and written to ``metrics.json`` (:class:`StepTimer`):
#: reading and decoding both folders; feature extraction;
#: ``evaluate_pair`` (normalisation, difference matrix, enhancement, sequence search and
#: metrics: one library call, as in the ``evaluate`` stage); both figures; everything from
#: the call to the last figure (imports done inside included, process start-up not).
TIMING_KEYS = ("decode", "features", "match", "figures", "total")
#: The parts of ``match`` (wall seconds only, :data:`MATCH_PARTS` of ``timing``): the difference
#: rows and the search (enhancement, single-frame and sequence search, top K) as
#: :attr:`cmal_lcd.matching.MatchResult.seconds` sums them over the chunks (each includes
#: loading its compiled kernels from numba's cache at the first call), and the rest of the step
#: (``metrics``: code normalisation, recall@K, PR curve and AUCs).
MATCH_PARTS = ("difference", "search", "metrics")


class StepTimer:
    """Wall and process CPU seconds (all threads) per named step, and the total since creation.

    ``with steps("decode"): ...`` times a step; :meth:`split` returns ``(wall, cpu)`` dicts
    over :data:`TIMING_KEYS` (``total`` included).
    """

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self._start = (time.perf_counter(), time.process_time())

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.process_time()
        yield
        self.wall[name] = time.perf_counter() - wall
        self.cpu[name] = time.process_time() - cpu

    def add_parts(self, parts: dict[str, float]) -> None:
        """Record wall seconds measured inside a step (:data:`MATCH_PARTS`)."""
        self.wall.update(parts)

    def split(self) -> tuple[dict[str, float], dict[str, float]]:
        wall = {**self.wall, "total": time.perf_counter() - self._start[0]}
        cpu = {**self.cpu, "total": time.process_time() - self._start[1]}
        return ({k: wall[k] for k in TIMING_KEYS + MATCH_PARTS if k in wall},
                {k: cpu[k] for k in TIMING_KEYS if k in cpu})


def match_parts(match_seconds: float, matching_seconds: dict[str, float]) -> dict[str, float]:
    """:data:`MATCH_PARTS` of a ``match`` step of ``match_seconds`` wall seconds, from the
    ``difference`` and ``search`` seconds of its :class:`~cmal_lcd.matching.MatchResult`."""
    difference = matching_seconds.get("difference", 0.0)
    search = matching_seconds.get("search", 0.0)
    return {"difference": difference, "search": search,
            "metrics": max(0.0, match_seconds - difference - search)}


# ---------------------------------------------------------------------------- command line


def add_match_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``match``: every matching default is read from ``conf/matching/seqslam.yaml``
    (:func:`cmal_lcd.matching.matching_defaults`, the one source)."""
    from cmal_lcd.cli_arguments import DefaultsHelpFormatter, add_seqslam_arguments
    from cmal_lcd.matching import matching_defaults

    conf = matching_defaults()
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
                   help="metres, with --ground-truth utm or msls (default 25, as "
                        "VPR-methods-evaluation and MSLS's evaluate.py)")
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
    add_seqslam_arguments(
        p, ds_help="look-back length, query frames",
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

    A failure propagates to :func:`cmal_lcd.cli.main`, which prints it as one line (exit 2).
    """
    from cmal_lcd.matching import SeqSLAMParams

    if args.min_scored_queries < 0:
        raise ValueError(f"--min-scored-queries: must be >= 0, got {args.min_scored_queries}")
    params = SeqSLAMParams(ds=args.ds, v_min=args.v_min, v_max=args.v_max, v_step=args.v_step,
                           r_window=args.r_window, enhance=args.enhance, score=args.score)
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
                           save_matrix=args.save_matrix)
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


# ---------------------------------------------------------------------------- the command


def match_folders(reference_dir: str | os.PathLike, query_dir: str | os.PathLike, *,
                  features: str | None = None, descriptor_key: str | None = None,
                  ground_truth: str | os.PathLike | None = None,
                  positive_dist_threshold: float | None = None,
                  params: SeqSLAMParams | None = None,
                  d_thresh: int | None = None, poses_tolerance: float | None = None,
                  out_dir: str | os.PathLike = "match_out",
                  model_dir: str | os.PathLike | None = None,
                  protocol: str | os.PathLike | None = None,
                  train_features: str | os.PathLike | None = None,
                  workers: int | None = None, figures: bool = True,
                  float32_codes: bool = False, quantise_sad: bool = False,
                  save_descriptors: bool = False, save_matrix: bool = False) -> dict:
    """Match two frame folders (or two descriptor files) and write ``metrics.json`` and the
    two figures into ``out_dir``.

    Parameters
    ----------
    reference_dir, query_dir : path-like
        Frame folders (see :func:`cmal_lcd.data.frames.read_frame_folder`), or both descriptor
        files (:func:`cmal_lcd.data.descriptors.read_descriptors`: rows are frames).
    features : str, optional
        For folders: ``sad`` (SeqSLAM thumbnails, the default) or a name of
        :func:`cmal_lcd.features.build_extractor`. Descriptor files are :data:`PRECOMPUTED`
        (matched as given with ``sqeuclidean``); any other value is refused.
    descriptor_key : str, optional
        The array of both descriptor files (default: each file's only 2-D array).
    ground_truth : path-like or ``"utm"``, optional
        A ground-truth file (:func:`cmal_lcd.evaluation.gt_files.read_ground_truth_file`), or
        ``"utm"``: positions from the frames' file names
        (:func:`~cmal_lcd.evaluation.gt_files.utm_ground_truth`); default: ``poses.csv`` of
        both folders, else by frame index.
    positive_dist_threshold : float, optional
        Metres, with ``ground_truth="utm"`` only (default 25).
    params : SeqSLAMParams, optional
        Matching parameters (default Table I). A protocol file replaces ``enhance`` and
        ``r_window`` (which must then stay at their defaults).
    d_thresh : int, optional
        Tolerance in frames (default ``matching.d_thresh`` of ``conf/matching/seqslam.yaml``,
        :func:`cmal_lcd.matching.matching_defaults`).
    poses_tolerance : float, optional
        Ground-truth radius in metres, used when both folders have ``poses.csv`` (default
        ``matching.pose_tolerance`` of the same file).
    out_dir : path-like
        Output folder, replaced as a whole once every output is written.
    model_dir : path-like, optional
        Folder holding ``<name>/model.pt`` for trained extractors (e.g. ``models/``).
    protocol : path-like or ``"raw"``, optional
        See :func:`choose_protocol`.
    train_features : path-like, optional
        Features folder giving the centring means of ``centre=condition``.
    workers : int, optional
        Threads decoding frames (default: the usable cores, at most 8).
    figures : bool
        Also draw ``pr_curve.png`` and ``difference_matrices.png`` (default). Without them the
        difference matrices are not kept either; every number is the same.
    save_descriptors, save_matrix : bool
        Also write ``descriptors.npz`` (features as extracted) or ``difference_matrix.npz``
        (``D`` and ``D_hat``; refused above :data:`MAX_SAVED_CELLS` cells).
    float32_codes : bool
        Compare codes with ``sqeuclidean_f32`` instead of the float64 ``sqeuclidean``
        (:mod:`cmal_lcd.matching.difference`); no effect on ``sad``.
    quantise_sad : bool
        Compare SAD thumbnails as bytes (``sad_u8``) whatever ``matching.sad.quantise`` says;
        refused with any other ``features``.

    Returns
    -------
    dict
        As written to ``metrics.json``: ``n_reference, n_query``, every metric of
        :func:`~cmal_lcd.evaluation.loop_closure.evaluate_pair` (``auc_pr, auc_roc,
        recall_at_100p, recall_at_1, single_frame_recall_at_1``, recall@K, ``n_scored,
        n_positive``), ``single_frame`` (the same metrics of the single-frame nearest
        neighbour, :func:`~cmal_lcd.evaluation.loop_closure.single_frame_metrics`),
        ``ground_truth`` (its source, tolerance, frame order and the queries with no right
        reference), ``seconds`` (features + matching wall time), ``timing`` and
        ``timing_cpu`` (wall and process CPU seconds per step, :data:`TIMING_KEYS`) and
        ``params`` (everything used, ``protocol`` included).
    """
    steps = StepTimer()
    params, d_thresh, poses_tolerance = _with_matching_defaults(params, d_thresh, poses_tolerance)
    features = _input_features(reference_dir, query_dir, features, descriptor_key=descriptor_key)
    check_feature_name(features)
    if quantise_sad and features != "sad":
        raise ValueError(f"--quantise-sad: only with --features sad, got {features!r}")
    chosen = choose_protocol(features, protocol, model_dir=model_dir, params=params,
                             train_features=train_features)
    train_means = chosen.train_means()  # (K, F) or None; before any frame is read
    from cmal_lcd.io import staged_output_folder

    with staged_output_folder(out_dir, MATCH_OUTPUTS + OPTIONAL_OUTPUTS, command="match",
                              inputs=(reference_dir, query_dir)) as staging:
        with steps("decode"):
            reference, query = read_inputs(reference_dir, query_dir, workers=workers,
                                           descriptor_key=descriptor_key,
                                           descriptors=features == PRECOMPUTED)
        truth_kind, truth = _checked_ground_truth(reference_dir, reference, query_dir, query,
                                                  ds=params.ds, poses_tolerance=poses_tolerance,
                                                  ground_truth=ground_truth,
                                                  positive_dist_threshold=positive_dist_threshold)
        with steps("features"):
            ref_features, query_features, metric, extractor_info = _extract_pair(
                features, reference, query, model_dir=model_dir,
                features_dir=chosen.train_features, quantise_sad=quantise_sad)
            metric = _codes_metric(metric, float32_codes=float32_codes)
        with steps("match"):
            if not kernels_cached():
                print(COMPILE_NOTICE, file=sys.stderr)
            if save_matrix:
                check_saved_matrix_size(len(ref_features), len(query_features))
            evaluation = _evaluate(ref_features, query_features, truth, metric=metric,
                                   params=params, d_thresh=d_thresh, chosen=chosen,
                                   train_means=train_means, keep_matrices=figures,
                                   keep_all=save_matrix, sequences=_sequences(reference, query))
            single_frame = _single_frame(evaluation, d_thresh=d_thresh)
        steps.add_parts(match_parts(steps.wall["match"], evaluation.result.seconds))
        seconds = _log_scored_seconds(steps, evaluation, n_query=len(query))
        if figures:
            with steps("figures"):
                write_figures(staging, evaluation, ref_features, query_features, metric=metric,
                              params=chosen.protocol.seqslam(params), chosen=chosen,
                              train_means=train_means,
                              label=extractor_info.get("label", features),
                              reference_dir=reference_dir, query_dir=query_dir,
                              reference_sequences=_sequences(reference, query)[0])
        wall, cpu = steps.split()
        record = _match_record(len(reference), len(query), evaluation, seconds, wall, cpu,
                               single_frame=single_frame,
                               ground_truth=_ground_truth_record(
                                   truth_kind, truth, reference, query, d_thresh=d_thresh,
                                   poses_tolerance=poses_tolerance),
                               params=_match_params(chosen, params, extractor_info, metric,
                                                    d_thresh=d_thresh, truth_kind=truth_kind,
                                                    poses_tolerance=poses_tolerance,
                                                    reference_dir=reference_dir,
                                                    query_dir=query_dir))
        _write_json(staging / "metrics.json", record)
        write_exports(staging, evaluation, d_thresh=d_thresh, reference=reference, query=query,
                      descriptors=(ref_features, query_features) if save_descriptors else None,
                      matrix=save_matrix)
    return record


def outputs_written(*, figures: bool, save_descriptors: bool, save_matrix: bool) -> list[str]:
    """The files of ``--out`` after a ``match`` with these options."""
    written = [name for name in MATCH_OUTPUTS if figures or name not in FIGURE_OUTPUTS]
    return written + [name for name, wanted in zip(OPTIONAL_OUTPUTS,
                                                   (save_descriptors, save_matrix)) if wanted]


def check_saved_matrix_size(n_reference: int, n_query: int) -> None:
    """Refuse ``--save-matrix`` for maps above :data:`MAX_SAVED_CELLS` cells."""
    if n_reference * n_query > MAX_SAVED_CELLS:
        raise ValueError(f"--save-matrix: {n_reference} x {n_query} frames make two matrices of "
                         f"{n_reference * n_query * 4 / 2**30:.1f} GiB each; the limit is "
                         f"{MAX_SAVED_CELLS} cells (use the candidates in candidates.npz)")


def write_exports(folder: Path, evaluation, *, d_thresh: int, reference, query,
                  descriptors=None, matrix: bool = False) -> None:
    """``matches.csv`` and ``candidates.npz`` (:mod:`cmal_lcd.evaluation.export`) into
    ``folder``; ``descriptors.npz`` when ``descriptors`` (``(R, F)``, ``(Q, F)``) are given;
    ``difference_matrix.npz`` when ``matrix`` (the result then holds ``D`` and ``D_hat``)."""
    import numpy as np

    from cmal_lcd.evaluation.export import candidate_arrays, matches_csv

    names = {"reference_names": reference.names, "query_names": query.names}
    (folder / "matches.csv").write_text(matches_csv(evaluation, d_thresh=d_thresh, **names),
                                        encoding="utf-8")
    np.savez(folder / "candidates.npz", **candidate_arrays(evaluation, **names))
    if descriptors is not None:
        np.savez(folder / "descriptors.npz", reference=descriptors[0], query=descriptors[1])
    if matrix:
        np.savez(folder / "difference_matrix.npz", D=evaluation.result.D,
                 D_hat=evaluation.result.D_hat)


def _codes_metric(metric: str, *, float32_codes: bool) -> str:
    """``metric`` of the extractor, or ``sqeuclidean_f32`` for codes when ``float32_codes``."""
    from cmal_lcd.matching.difference import CODE_METRICS

    return CODE_METRICS["float32"] if float32_codes and metric == CODE_METRICS["float64"] \
        else metric


def _with_matching_defaults(params: SeqSLAMParams | None, d_thresh: int | None,
                            poses_tolerance: float | None):
    """``params`` (default Table I), ``d_thresh`` and ``poses_tolerance`` (defaults of
    :func:`cmal_lcd.matching.matching_defaults`) for the ones given as None."""
    from cmal_lcd.matching import SeqSLAMParams, matching_defaults

    params = SeqSLAMParams() if params is None else params
    conf = matching_defaults()
    from cmal_lcd.schema import MAX_D_THRESH

    d_thresh = conf["d_thresh"] if d_thresh is None else d_thresh
    if not 0 <= d_thresh <= MAX_D_THRESH:
        raise ValueError(f"--d-thresh: must be 0..{MAX_D_THRESH} frames, got {d_thresh}")
    poses_tolerance = conf["pose_tolerance"] if poses_tolerance is None else poses_tolerance
    return params, d_thresh, poses_tolerance


def _checked_ground_truth(reference_dir, reference: FrameFolder | DescriptorFile, query_dir,
                          query: FrameFolder | DescriptorFile, *, ds: int,
                          poses_tolerance: float, ground_truth: str | os.PathLike | None = None,
                          positive_dist_threshold: float | None = None):
    """``(truth_kind, truth)`` after checking the lengths and that both or neither folder has
    poses: ``"file"`` and the :class:`~cmal_lcd.evaluation.ground_truth.ReferenceSets` of
    ``ground_truth`` (``msls`` by default for two Mapillary SLS sides), or ``"poses"`` or
    ``"index"`` and the ground truth of every query (the evaluate stage's conventions;
    ``"index"`` uses the lengths)."""
    from cmal_lcd.evaluation.loop_closure import ground_truth_for_pair

    from cmal_lcd.evaluation import gt_files

    check_lengths(reference_dir, len(reference), query_dir, len(query), ds=ds)
    if ground_truth is None and all(side.sequences is not None for side in (reference, query)):
        ground_truth = gt_files.MSLS  # two Mapillary SLS sides carry their positions
    keyword = str(ground_truth) if str(ground_truth) in gt_files.POSITION_KEYWORDS else None
    if positive_dist_threshold is not None and keyword is None:
        raise ValueError(f"--positive-dist-threshold: only with --ground-truth "
                         f"{' or '.join(gt_files.POSITION_KEYWORDS)}")
    radius = (gt_files.POSITIVE_DIST_THRESHOLD if positive_dist_threshold is None
              else positive_dist_threshold)
    if keyword is not None and isinstance(reference, DescriptorFile):
        raise ValueError(f"--ground-truth {keyword}: positions come from the frame folders, "
                         f"but {reference_dir} is a descriptor file")
    if keyword == gt_files.MSLS:
        return "file", gt_files.msls_ground_truth(reference_dir, query_dir, radius=radius)
    if keyword == gt_files.UTM:
        from cmal_lcd.data.frames import ORDER_NAME, frame_order

        for folder, side in ((reference_dir, reference), (query_dir, query)):
            if frame_order(side.names) == ORDER_NAME:
                logger.warning("%s: frames without a timestamp in their names are ordered by "
                               "name, i.e. by UTM east, not in travel order; sequence "
                               "matching assumes travel order", folder)
        return "file", gt_files.utm_ground_truth(reference.names, query.names,
                                                 reference_dir=reference_dir,
                                                 query_dir=query_dir, radius=radius)
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


def _extract_pair(features: str, reference: FrameFolder, query: FrameFolder, *, model_dir,
                  features_dir: Path | None = None, quantise_sad: bool = False):
    """Codes ``(R, F)`` and ``(Q, F)`` of both folders, their metric and the extractor info
    (``features_dir``, ``quantise_sad``: see :func:`_feature_function`); descriptor files'
    own rows, with ``sqeuclidean``."""
    if isinstance(reference, DescriptorFile):
        from cmal_lcd.matching.difference import CODE_METRICS

        return reference.descriptors, query.descriptors, CODE_METRICS["float64"], {
            "features": PRECOMPUTED, "label": f"descriptors ({reference.path.name})",
            "descriptor_key": reference.key, "dimensions": int(reference.descriptors.shape[1])}
    extract, metric, extractor_info = _feature_function(features, model_dir=model_dir,
                                                        features_dir=features_dir,
                                                        quantise_sad=quantise_sad)
    logger.info("match: %s features of %d reference frames", features, len(reference))
    ref_features = extract(reference.images)
    logger.info("match: %s features of %d query frames", features, len(query))
    query_features = extract(query.images)
    return ref_features, query_features, metric, extractor_info


#: Said once, when the matching kernels have no compiled copy in numba's cache yet.
COMPILE_NOTICE = ("cmal-lcd match: compiling the matching kernels (numba, first use after an "
                  "install: about 10 s; cached for later runs)")


def kernels_cached() -> bool:
    """Whether numba's cache holds the SeqSLAM kernels (its index files beside
    ``cmal_lcd/matching/seqslam.py``, or under ``$NUMBA_CACHE_DIR``)."""
    import cmal_lcd.matching.seqslam as seqslam

    source = Path(seqslam.__file__)
    folders = [source.parent / "__pycache__"]
    if os.environ.get("NUMBA_CACHE_DIR"):
        folders.append(Path(os.environ["NUMBA_CACHE_DIR"]))
    return any(any(folder.rglob(f"{source.stem}.*.nbi")) for folder in folders
               if folder.is_dir())


def _log_scored_seconds(steps: StepTimer, evaluation, *, n_query: int) -> float:
    """The features + matching wall seconds, logged with the number of scored queries."""
    seconds = steps.wall["features"] + steps.wall["match"]
    logger.info("match: %d of %d queries scored in %.1f s; writing %s",
                evaluation.result.n_scored, n_query, seconds, ", ".join(MATCH_OUTPUTS))
    return seconds


def _match_record(n_reference: int, n_query: int, evaluation, seconds: float, wall: dict,
                  cpu: dict, *, single_frame: dict, ground_truth: dict, params: dict) -> dict:
    """What :func:`match_folders` returns and writes as ``metrics.json``."""
    return {"n_reference": n_reference, "n_query": n_query, **evaluation.metrics,
            "single_frame": single_frame, "ground_truth": ground_truth,
            "seconds": seconds, "timing": wall, "timing_cpu": cpu, "params": params}


def _single_frame(evaluation, *, d_thresh: int) -> dict:
    """The single-frame nearest neighbour's metrics under the same ground truth
    (:func:`~cmal_lcd.evaluation.loop_closure.single_frame_metrics`)."""
    from cmal_lcd.evaluation.loop_closure import single_frame_metrics

    try:
        return single_frame_metrics(evaluation.result, evaluation.truth, d_thresh=d_thresh)
    except ValueError as err:
        logger.warning("match: no single-frame metrics (%s)", err)
        return {}


def _ground_truth_record(truth_kind: str, truth, reference, query, *, d_thresh: int,
                         poses_tolerance: float) -> dict:
    """``metrics.json``'s ``ground_truth``: ``kind, source, tolerance, frame_order`` and
    ``n_query_without_reference`` (plus the pair counts of a file)."""
    import numpy as np

    from cmal_lcd.evaluation.gt_files import describe_ground_truth

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


def _match_params(chosen: ChosenProtocol, params: SeqSLAMParams, extractor_info: dict,
                  metric: str, *,
                  d_thresh: int, truth_kind: str, poses_tolerance: float, reference_dir,
                  query_dir) -> dict:
    """The ``params`` of ``metrics.json``: everything used, the protocol included."""
    return {**chosen.protocol.seqslam(params).as_dict(), "d_thresh": d_thresh,
            **extractor_info, "metric": metric, "protocol": chosen.as_dict(),
            "ground_truth": {"poses": "poses", "index": "frame index"}.get(truth_kind,
                                                                           "file"),
            "poses_tolerance": poses_tolerance if truth_kind == "poses" else None,
            "reference_dir": str(reference_dir), "query_dir": str(query_dir)}


def _sequences(reference, query) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The sequence numbers of both sides (``None``: one sequence; descriptor files have one)."""
    return reference.sequences, query.sequences


def _evaluate(ref_features, query_features, truth, *, metric, params, d_thresh, chosen,
              train_means, keep_matrices=True, keep_all=False, sequences=(None, None)):
    """:func:`~cmal_lcd.evaluation.loop_closure.evaluate_pair` under the chosen protocol (the
    ``evaluate`` stage's code path); errors are prefixed with the protocol. The difference
    matrices are kept for the figure when ``keep_matrices`` and they are small enough.
    ``sequences``: the reference and query sequence numbers (:func:`_sequences`)."""
    from cmal_lcd.evaluation import loop_closure

    # Kept only when the figure shows every frame (k = 1). Keeping 3,600 x 3,600 matrices cost
    # 0.5-0.9 s (copies, and the transposes of MatchResult); computing the figure's every 6th
    # column again costs 0.1-0.2 s (benchmarks/README.md, `cmal-lcd match`).
    keep = keep_all or (keep_matrices
                        and max(len(ref_features), len(query_features)) <= DISPLAY_SIDE)
    try:
        return loop_closure.evaluate_pair(ref_features, query_features, truth, metric=metric,
                                          params=params, d_thresh=d_thresh,
                                          keep_matrices=keep, protocol=chosen.protocol,
                                          train_means=train_means,
                                          reference_sequences=sequences[0],
                                          query_sequences=sequences[1])
    except ValueError as err:
        raise ValueError(f"match ({chosen.protocol.label}): {err}") from err


def _write_json(path: Path, record: dict) -> None:
    from cmal_lcd.io import atomic_write_json

    atomic_write_json(path, record)


def write_figures(folder: Path, evaluation, ref_features, query_features, *, metric: str,
                  params: SeqSLAMParams, chosen: ChosenProtocol, train_means, label: str,
                  reference_dir, query_dir, reference_sequences=None) -> None:
    """``pr_curve.png`` and ``difference_matrices.png`` (paper Fig. 6) into ``folder``.

    ``ref_features (R, F)`` and ``query_features (Q, F)`` as extracted; ``params`` the
    effective ones (the protocol's enhancement); ``reference_sequences (R,)`` when the
    reference holds several sequences. The matrices are those of every k-th frame
    (kept by the search, else :func:`figure_matrices`), the overlays every query's match and
    true place.
    """
    from cmal_lcd.reports import plots

    plots.plot_pr_curves({f"{label} + SeqSLAM": (evaluation.recall, evaluation.precision)},
                         path=folder / "pr_curve.png",
                         title=f"{Path(reference_dir).name} (reference) vs "
                               f"{Path(query_dir).name} (query)")
    n_ref, n_query = len(ref_features), len(query_features)
    result = evaluation.result
    if result.D is not None:
        k = max(1, -(-max(n_ref, n_query) // DISPLAY_SIDE))
        D, D_hat = result.D[::k, ::k], result.D_hat[::k, ::k]
    else:
        from cmal_lcd.matching.normalise import normalise_pair

        ref, qry = normalise_pair(ref_features, query_features, chosen.protocol.normalisation,
                                  train_means=train_means)
        D, D_hat, k = figure_matrices(ref, qry, metric=metric, params=params,
                                      reference_sequences=reference_sequences)
    truth = evaluation.truth
    if hasattr(truth, "nearest_right"):  # ReferenceSets: the right row nearest the match
        truth = truth.nearest_right(result.match)
    plots.plot_difference_matrices(
        D, D_hat, path=folder / "difference_matrices.png", frames=(n_ref, n_query),
        match=result.match, truth=truth,
        title=f"{label}: {n_ref} reference x {n_query} query frames"
              + (f" (one frame in {k} shown)" if k > 1 else ""),
        labels=("difference matrix D (eq. 13)",
                "enhanced matrix D_hat (eq. 14)" if params.enhance else
                "D as searched (no enhancement)"))


def figure_matrices(reference: np.ndarray, query: np.ndarray, *, metric: str,
                    params: SeqSLAMParams, side: int | None = None, reference_sequences=None
                    ) -> tuple[np.ndarray, np.ndarray, int]:
    """``D`` and ``D_hat`` of every k-th reference and query frame, for the figure.

    Parameters
    ----------
    reference : ndarray (R, F)
    query : ndarray (Q, F)
        Normalised features (as matched).
    metric : str
    params : SeqSLAMParams
        Effective parameters (``enhancement_window``).
    side : int, optional
        At most this many rows and columns (default :data:`DISPLAY_SIDE`).
    reference_sequences : ndarray (R,), optional
        Sequence numbers of the reference rows (enhancement windows stop at their bounds).

    Returns
    -------
    D, D_hat : ndarray, float32 (ceil(R / k), ceil(Q / k))
        ``D[::k, ::k]`` and ``D_hat[::k, ::k]`` of the full matrices (``D_hat`` up to one
        constant: eq. 14's shift to values >= 0 is the minimum over the kept columns). Eq. 14
        works down each query's column, so it runs on every reference row of the kept
        columns; the full ``R x Q`` matrices are never held.
    k : int
        ``ceil(max(R, Q) / side)``.
    """
    from cmal_lcd.matching import difference_matrix, enhance_contrast

    side = DISPLAY_SIDE if side is None else side
    k = max(1, -(-max(len(reference), len(query)) // side))
    columns = difference_matrix(reference, query[::k], metric=metric)
    enhanced = enhance_contrast(columns, r_window=params.enhancement_window,
                                reference_sequences=reference_sequences)
    return columns[::k], enhanced[::k], k


# ---------------------------------------------------------------------------- protocol


@dataclasses.dataclass(frozen=True)
class ChosenProtocol:
    """The protocol ``match`` applies and where it came from.

    Attributes
    ----------
    protocol : MatchingProtocol
    source : str
        Printed after the label: the file, or why ``raw`` was used.
    file : Path or None
        The protocol file read.
    train_features : Path or None
        Features folder of the centring means (``centre="condition"`` only).
    warning : str or None
        Printed as a warning (``raw`` learned codes because no file was found).
    """

    protocol: MatchingProtocol
    source: str
    file: Path | None = None
    train_features: Path | None = None
    warning: str | None = None

    def train_means(self) -> np.ndarray | None:
        """Training-set mean code per condition, ``(K, F)``, or None (no condition centring).

        Raises
        ------
        ValueError
            Naming the missing or unreadable file and ``--train-features``.
        """
        from cmal_lcd.evaluation.protocol_file import centring_means

        if self.protocol.normalisation.centre != "condition":
            return None
        try:
            return centring_means(self.protocol, self.train_features)
        except (FileNotFoundError, ValueError) as err:
            raise ValueError(f"--train-features: {err} (the centring means of "
                             f"{self.protocol.label})") from None

    def as_dict(self) -> dict[str, Any]:
        """``centre, l2, enhance, r_window, label, source, file, train_features, warning``."""
        return {**self.protocol.as_dict(), "source": self.source,
                "file": None if self.file is None else str(self.file),
                "train_features": (None if self.train_features is None
                                   or self.protocol.normalisation.centre != "condition"
                                   else str(self.train_features)),
                "warning": self.warning}


def raw_protocol(params: SeqSLAMParams) -> MatchingProtocol:
    """Codes as extracted; enhancement and window from ``params`` (Table I: the paper's)."""
    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.matching.normalise import CodeNormalisation

    return MatchingProtocol(CodeNormalisation("none", False), enhance=params.enhance,
                            r_window=params.r_window)


def pipeline_protocol_path(features: str, *,
                           model_dir: str | os.PathLike | None) -> Path | None:
    """Where the pipeline writes ``features``' protocol: ``<checkout>/data/protocol/<name>.json``
    with ``<checkout>`` the parent of ``model_dir`` (else the working directory's checkout;
    None outside one)."""
    from cmal_lcd.config import CheckoutNotFoundError, checkout_root
    from cmal_lcd.evaluation.protocol_file import PROTOCOL_DIR

    if model_dir is not None:
        root = Path(os.path.abspath(model_dir)).parent
    else:
        try:
            root = checkout_root()
        except CheckoutNotFoundError:
            return None
    return root / PROTOCOL_DIR / f"{features}.json"


def choose_protocol(features: str, protocol: str | os.PathLike | None, *,
                    model_dir: str | os.PathLike | None, params: SeqSLAMParams,
                    train_features: str | os.PathLike | None = None) -> ChosenProtocol:
    """The protocol ``match`` applies (module docstring), before any frame is read.

    Raises
    ------
    ValueError
        ``--protocol FILE``: missing, not a protocol record, or chosen for another method;
        ``--no-enhance``/``--r-window`` changed while a file sets the enhancement.
    """
    if protocol is not None and str(protocol) == RAW_PROTOCOL:
        return ChosenProtocol(raw_protocol(params), source="--protocol raw")
    if protocol is not None:
        return _protocol_from_file(Path(protocol), features, params=params,
                                   train_features=train_features, found=False)
    if features == "sad":
        return ChosenProtocol(raw_protocol(params),
                              source="sad default; --protocol FILE applies a chosen one")
    if features == PRECOMPUTED:
        return ChosenProtocol(raw_protocol(params), source="descriptor files, as given")
    path = pipeline_protocol_path(features, model_dir=model_dir)
    if path is not None and path.is_file():
        return _protocol_from_file(path, features, params=params,
                                   train_features=train_features, found=True)
    where = str(path) if path is not None else "no checkout found (pass --model-dir)"
    return ChosenProtocol(
        raw_protocol(params), source=f"fallback: no protocol file ({where})",
        warning=f"no protocol chosen for {features} ({where}): using raw codes with "
                f"{'eq. 14' if params.enhance else 'no enhancement'}, which for learned codes "
                f"tends to match the weather rather than the place; pass --protocol "
                f"data/protocol/{features}.json (select_protocol stage) or --protocol raw")


def _protocol_from_file(path: Path, features: str, *, params: SeqSLAMParams,
                        train_features: str | os.PathLike | None,
                        found: bool) -> ChosenProtocol:
    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.evaluation.protocol_file import FEATURES_DIR, read_protocol_record
    from cmal_lcd.matching import SeqSLAMParams

    try:
        record = read_protocol_record(path)
    except (FileNotFoundError, ValueError) as err:
        raise ValueError(f"--protocol {err}") from None
    method = record.get("method")
    if method is not None and method != features:
        raise ValueError(f"--protocol {path}: chosen for {method!r}, not for --features "
                         f"{features!r}")
    chosen = MatchingProtocol.from_dict(record["selected"])
    default = SeqSLAMParams()
    if (params.enhance, params.r_window) != (default.enhance, default.r_window):
        raise ValueError(f"--no-enhance/--r-window: {path} sets the enhancement "
                         f"({chosen.label}); leave them at their defaults or pass --protocol "
                         f"{RAW_PROTOCOL}")
    if train_features is None:
        train_features = path.parent.parent.parent / FEATURES_DIR / features
    if chosen.normalisation.centre == "condition":
        check_training_features(Path(train_features), features)
    source = f"{path}{' (found beside --model-dir)' if found else ''}"
    return ChosenProtocol(chosen, source=source, file=path,
                          train_features=Path(train_features))


def check_training_features(folder: Path, features: str) -> None:
    """Refuse a features folder whose ``info.json`` names another method than ``features``.

    Raises
    ------
    ValueError
        ``--train-features <folder>: codes of '<method>', not of '<features>'``.
    """
    import json

    try:
        method = json.loads((folder / "info.json").read_text(encoding="utf-8")).get("method")
    except (OSError, ValueError, AttributeError):
        return  # no readable info.json: the training codes' own checks speak later
    if method is not None and method != features:
        raise ValueError(f"--train-features {folder}: codes of {method!r}, not of "
                         f"{features!r}")


# ---------------------------------------------------------------------------- inputs


@dataclasses.dataclass(frozen=True)
class DescriptorFile:
    """The descriptors of one side, read from a file: ``descriptors (N, D)``, rows = frames."""

    descriptors: np.ndarray
    path: Path
    key: str | None = None
    poses = None  # descriptor files carry no poses
    sequences = None  # and hold one sequence

    def __len__(self) -> int:
        return len(self.descriptors)

    @property
    def names(self) -> list[str]:
        return [str(i) for i in range(len(self))]


def _input_features(reference, query, features: str | None, *,
                    descriptor_key: str | None) -> str:
    """The ``features`` to match with: :data:`PRECOMPUTED` for two descriptor files, else
    ``features`` (default ``sad``). Refuses one file and one folder, ``--features`` with
    files, ``--descriptor-key`` with folders."""
    from cmal_lcd.data.array_files import ARRAY_SUFFIXES, is_array_file

    files = [is_array_file(reference), is_array_file(query)]
    if files[0] != files[1]:
        file, folder = (reference, query) if files[0] else (query, reference)
        raise ValueError(f"{folder}: a folder of frames, but {file} is a descriptor file; "
                         f"give two descriptor files ({', '.join(ARRAY_SUFFIXES)}) or two "
                         f"folders")
    if files[0]:
        if features not in (None, PRECOMPUTED):
            raise ValueError(f"--features {features}: descriptor files are matched as given; "
                             f"leave --features out")
        return PRECOMPUTED
    if descriptor_key is not None:
        raise ValueError(f"--descriptor-key {descriptor_key}: only with descriptor files, but "
                         f"{reference} and {query} are folders of frames")
    return "sad" if features is None else features


def read_inputs(reference, query, *, workers: int | None, descriptor_key: str | None,
                descriptors: bool):
    """Both sides: :class:`DescriptorFile` when ``descriptors`` (same dimensions checked),
    else :class:`~cmal_lcd.data.frames.FrameFolder` (read on ``workers`` threads)."""
    if not descriptors:
        from cmal_lcd.data.frames import read_frame_folder

        return (read_frame_folder(reference, workers=workers),
                read_frame_folder(query, workers=workers))
    from cmal_lcd.data.descriptors import read_descriptors

    sides = [DescriptorFile(read_descriptors(path, key=descriptor_key), Path(path),
                            descriptor_key) for path in (reference, query)]
    dims = [side.descriptors.shape[1] for side in sides]
    if dims[0] != dims[1]:
        raise ValueError(f"{query}: descriptors of {dims[1]} dimensions, but {reference} has "
                         f"{dims[0]}")
    for side in sides:
        logger.info("read %d descriptors of %d dimensions from %s", len(side), dims[0],
                    side.path)
    return sides[0], sides[1]


def check_feature_name(name: str) -> None:
    """Refuse a ``--features`` value that names no extractor (before any file is read): a
    built-in method, or a node of ``extractors`` in the checkout's ``conf/`` (composed only
    for a name that is not built in).

    Raises
    ------
    ValueError
        ``--features must be one of [...], got '<name>'``.
    """
    from cmal_lcd.features import method_names

    if name in (PRECOMPUTED, *method_names()):
        return
    from cmal_lcd.config import command_conf_dir, compose

    names = method_names(compose(config_dir=command_conf_dir()).get("extractors"))
    if name not in names:
        raise ValueError(f"--features must be one of {names} (your own: an extractors.<name> "
                         f"node in conf/config.yaml), got {name!r}")


def check_lengths(reference_dir, n_reference: int, query_dir, n_query: int, *, ds: int) -> None:
    """Refuse folders too short for the look-back search (naming the folder and ``ds``)."""
    if n_query <= ds:
        raise ValueError(f"{query_dir}: {n_query} query frames; the look-back search needs "
                         f"more than ds={ds}")
    if n_reference < ds:
        raise ValueError(f"{reference_dir}: {n_reference} reference frames; a sequence "
                         f"spans ds={ds} frames of the reference, so it needs at least "
                         f"ds frames")


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


# ---------------------------------------------------------------------------- outputs


def warn_if_few_scored(metrics: dict, *, minimum: int) -> bool:
    """Print a warning when fewer than ``minimum`` queries were scored; return whether it did."""
    n_scored, n_query = metrics.get("n_scored"), metrics.get("n_query")
    if n_scored is None or n_scored >= minimum:
        return False
    print(f"cmal-lcd match: warning: only {n_scored} of {n_query} queries scored (fewer than "
          f"--min-scored-queries {minimum}); the metrics rest on too few decisions (lower --ds "
          f"or use longer folders)", file=sys.stderr)
    return True


# ---------------------------------------------------------------------------- features


def _feature_function(name: str, *, model_dir, features_dir: Path | None = None,
                      quantise_sad: bool = False):
    """``(extract(images uint8 (N, H, W, 3)) -> (N, F), metric, info)`` for a feature name.

    ``sad`` imports neither torch nor Hydra; the extractors do. A method that chooses on
    validation (``dnn``: its layer and input side) takes the choice the features stage
    recorded in ``features_dir/info.json`` (the folder of the protocol's training codes,
    :func:`recorded_choice`); else the configured one.
    ``quantise_sad`` compares the SAD thumbnails as bytes (``sad_u8``) whatever
    ``matching.sad.quantise`` says.
    """
    if name == "sad":
        from cmal_lcd.matching import (matching_defaults, sad_metric, sad_thumbnails,
                                       thumbnail_options)

        sad = matching_defaults()["sad"]
        if quantise_sad:  # --quantise-sad: the bytes whatever the configuration says
            sad["quantise"] = True
        return (functools.partial(sad_thumbnails, **thumbnail_options(sad)), sad_metric(sad),
                {"features": "sad", "label": "SAD", "sad": sad})
    from cmal_lcd.config import command_conf_dir, compose
    from cmal_lcd.features import build_extractor, configured_method, extractor_conf, located
    from cmal_lcd.features.base import encode_with_progress, forward_batch_size
    from cmal_lcd.models.device import pick_device

    cfg = compose(config_dir=command_conf_dir())
    check_feature_name(name)
    entry = configured_method(cfg, name)
    try:
        conf = extractor_conf(cfg, name)
        choice = recorded_choice(features_dir) if entry.apply_choice is not None else None
        if choice is not None:
            conf = located(entry.apply_choice)(conf, choice)
        extractor = build_extractor(name, conf=conf, model_dir=model_dir, device=pick_device())
    except (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile) as err:
        if entry.model is None:
            raise
        model_file = Path(model_dir or ".") / entry.model / "model.pt"
        raise ValueError(f"{model_file}: not a readable trained model (truncated, corrupt, or "
                         f"holding objects other than tensors, which are never loaded: "
                         f"{type(err).__name__}); re-run the train stage") from err
    info = {"features": name, "label": extractor.label, "weights": extractor.weights}
    # a bar on a terminal, or a line every 30 s: a DNN takes minutes on thousands of frames
    extract = functools.partial(encode_with_progress, extractor,
                                batch_size=forward_batch_size(extractor, conf),
                                desc=f"match: encode {name}",
                                logger=logger)
    return extract, extractor.metric, info


def recorded_choice(features_dir: Path | None) -> dict | None:
    """The ``layer_selection`` the features stage recorded in ``features_dir/info.json`` (what
    a method chose on validation, ``Method.choose``: ``dnn``'s layer and input side), so that
    the codes are those the protocol and its centring means were made for; None when there is
    no such file or choice."""
    import json

    if features_dir is None:
        return None
    try:
        info = json.loads((Path(features_dir) / "info.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    selection = info.get("layer_selection") if isinstance(info, dict) else None
    if not isinstance(selection, dict) or "selected" not in selection:
        return None
    logger.info("match: %s at %s px, as chosen on validation in %s", selection["selected"],
                selection.get("image_size", "the configured"), Path(features_dir) / "info.json")
    return selection


# ---------------------------------------------------------------------------- printing


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
    parts = ", ".join(f"{k} {wall[k]:.2f}" for k in MATCH_PARTS if k in wall)
    steps = [f"{k} {wall[k]:.2f}/{cpu[k]:.2f}" + (f" ({parts})" if k == "match" and parts else "")
             for k in TIMING_KEYS if k in wall]
    return "time (s, wall/cpu): " + ", ".join(steps)
