"""Loop closure between two folders of a user's frames (or two descriptor files), evaluated.

A user's own data through the pipeline's evaluation path (:func:`match_folders`, what
``cmal-lcd match`` runs): frames are decoded (on a thread pool,
:mod:`cmal_lcd.data.pair_inputs`), turned into features (:mod:`cmal_lcd.workflows.folder_features`),
normalised and matched under a *matching protocol* (:mod:`cmal_lcd.evaluation.chosen_protocol`)
exactly as the ``evaluate`` stage does (:func:`cmal_lcd.evaluation.loop_closure.evaluate_pair`:
code normalisation, eq. 14 on or off, SeqSLAM with the paper's Table I parameters, loop closure
metrics) against the ground truth of :mod:`cmal_lcd.evaluation.pair_truth`; then
``metrics.json``, the exports (``matches.csv``, ``candidates.npz``; ``descriptors.npz`` and
``difference_matrix.npz`` on request) and the figures (:mod:`cmal_lcd.reports.match_figures`)
are written into the output folder.

Outputs are old or new, never a mix: everything is written into a temporary sibling folder of
the output folder, which replaces it only once complete
(:func:`cmal_lcd.io.staged_output_folder`); a folder holding anything but these outputs is
refused, never emptied. A failure is one ``ValueError`` naming the file, folder or option.
Imports stay inside the functions: SAD matching never imports torch.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cmal_lcd.data.pair_inputs import PRECOMPUTED, input_features, read_inputs
from cmal_lcd.evaluation.chosen_protocol import ChosenProtocol, choose_protocol
from cmal_lcd.evaluation.pair_truth import checked_ground_truth, ground_truth_record
from cmal_lcd.workflows.folder_features import check_feature_name, extract_pair

if TYPE_CHECKING:  # imported lazily at run time
    import numpy as np

    from cmal_lcd.matching import SeqSLAMParams

logger = logging.getLogger(__name__)

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
                  save_descriptors: bool = False, save_matrix: bool = False,
                  config_overrides: Sequence[str] = ()) -> dict:
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
        A ground-truth file (:func:`cmal_lcd.data.gt_files.read_ground_truth_file`), or
        ``"utm"``: positions from the frames' file names
        (:func:`~cmal_lcd.data.gt_files.utm_ground_truth`); default: ``poses.csv`` of
        both folders, else by frame index.
    positive_dist_threshold : float, optional
        Metres, with ``ground_truth="utm"`` or ``"msls"`` only (default
        :func:`~cmal_lcd.data.gt_files.default_radius`).
    params : SeqSLAMParams, optional
        Matching parameters (default Table I). A protocol file replaces ``enhance`` and
        ``r_window`` (which must then stay at their defaults).
    d_thresh : int, optional
        Tolerance in frames (default ``matching.d_thresh`` of the config,
        :func:`cmal_lcd.config.command_matching`).
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
    config_overrides : sequence of str
        Hydra overrides of ``conf/`` (``match --config``, e.g. ``experiment=nordland``): the
        defaults of every matching argument left as None, SAD's thumbnails and the extractor's
        config then come from ``conf/`` composed with them
        (:func:`cmal_lcd.config.command_config`); recorded under ``params.config_overrides``.

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
    from cmal_lcd.io import staged_output_folder
    from cmal_lcd.reports import match_figures  # imported here: reports read evaluation

    from cmal_lcd.config import command_matching
    from cmal_lcd.matching import SeqSLAMParams

    steps = StepTimer()
    conf = command_matching(config_overrides)  # the defaults of every None below
    params, d_thresh, poses_tolerance = with_matching_defaults(params, d_thresh, poses_tolerance,
                                                               conf=conf)
    features = input_features(reference_dir, query_dir, features, descriptor_key=descriptor_key)
    check_feature_name(features, config_overrides=config_overrides)
    if quantise_sad and features != "sad":
        raise ValueError(f"--quantise-sad: only with --features sad, got {features!r}")
    chosen = choose_protocol(features, protocol, model_dir=model_dir, params=params,
                             train_features=train_features,
                             defaults=SeqSLAMParams.from_config(conf))
    train_means = chosen.train_means()  # (K, F) or None; before any frame is read
    with staged_output_folder(out_dir, MATCH_OUTPUTS + OPTIONAL_OUTPUTS, command="match",
                              inputs=(reference_dir, query_dir)) as staging:
        with steps("decode"):
            reference, query = read_inputs(reference_dir, query_dir, workers=workers,
                                           descriptor_key=descriptor_key,
                                           descriptors=features == PRECOMPUTED)
        truth_kind, truth = checked_ground_truth(reference_dir, reference, query_dir, query,
                                                  ds=params.ds, poses_tolerance=poses_tolerance,
                                                  ground_truth=ground_truth,
                                                  positive_dist_threshold=positive_dist_threshold)
        with steps("features"):
            ref_features, query_features, metric, extractor_info = extract_pair(
                features, reference, query, model_dir=model_dir,
                features_dir=chosen.train_features, quantise_sad=quantise_sad,
                config_overrides=config_overrides)
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
                match_figures.write_figures(staging, evaluation, ref_features, query_features, metric=metric,
                              params=chosen.protocol.seqslam(params), chosen=chosen,
                              train_means=train_means,
                              label=extractor_info.get("label", features),
                              reference_dir=reference_dir, query_dir=query_dir,
                              reference_sequences=_sequences(reference, query)[0])
        wall, cpu = steps.split()
        record = _match_record(len(reference), len(query), evaluation, seconds, wall, cpu,
                               single_frame=single_frame,
                               ground_truth=ground_truth_record(
                                   truth_kind, truth, reference, query, d_thresh=d_thresh,
                                   poses_tolerance=poses_tolerance),
                               params=_match_params(chosen, params, extractor_info, metric,
                                                    d_thresh=d_thresh, truth_kind=truth_kind,
                                                    poses_tolerance=poses_tolerance,
                                                    reference_dir=reference_dir,
                                                    query_dir=query_dir,
                                                    config_overrides=config_overrides))
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


def with_matching_defaults(params: SeqSLAMParams | None, d_thresh: int | None,
                           poses_tolerance: float | None, *, conf: Mapping[str, Any]):
    """``params``, ``d_thresh`` and ``poses_tolerance``, those given as None from ``conf``, the
    ``matching`` node (:func:`cmal_lcd.config.command_matching`; Table I); the last two checked
    by the schema's rules of ``matching.d_thresh`` and ``matching.pose_tolerance`` (the one
    check of each; ``--d-thresh: must be >= 0, got -1``)."""
    from cmal_lcd.matching import SeqSLAMParams
    from cmal_lcd.matching.params import check_matching

    params = SeqSLAMParams.from_config(conf) if params is None else params
    given = {"d_thresh": conf["d_thresh"] if d_thresh is None else d_thresh,
             "pose_tolerance": conf["pose_tolerance"] if poses_tolerance is None
             else poses_tolerance}
    try:
        checked = check_matching(**given)
    except ValueError as err:
        field, _, what = str(err).partition(": ")
        option = {"d_thresh": "--d-thresh", "pose_tolerance": "--poses-tolerance"}[field]
        raise ValueError(f"{option}: {what}") from None
    return params, checked["d_thresh"], checked["pose_tolerance"]


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


def _match_params(chosen: ChosenProtocol, params: SeqSLAMParams, extractor_info: dict,
                  metric: str, *,
                  d_thresh: int, truth_kind: str, poses_tolerance: float, reference_dir,
                  query_dir, config_overrides: Sequence[str]) -> dict:
    """The ``params`` of ``metrics.json``: everything used, the protocol included."""
    return {**chosen.protocol.seqslam(params).as_dict(), "d_thresh": d_thresh,
            **extractor_info, "metric": metric, "protocol": chosen.as_dict(),
            "ground_truth": {"poses": "poses", "index": "frame index"}.get(truth_kind,
                                                                           "file"),
            "poses_tolerance": poses_tolerance if truth_kind == "poses" else None,
            "reference_dir": str(reference_dir), "query_dir": str(query_dir),
            "config_overrides": list(config_overrides)}


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
    from cmal_lcd.reports import match_figures

    # Kept only when the figure shows every frame (k = 1). Keeping 3,600 x 3,600 matrices cost
    # 0.5-0.9 s (copies, and the transposes of MatchResult); computing the figure's every 6th
    # column again costs 0.1-0.2 s (benchmarks/README.md, `cmal-lcd match`).
    keep = keep_all or (keep_matrices
                        and max(len(ref_features), len(query_features)) <= match_figures.DISPLAY_SIDE)
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
