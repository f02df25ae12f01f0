"""Stage ``report``: tables, figures, DVC metrics/plots files and ``reports/README.md``.

Reads only the pipeline's files (docs/architecture.md):

- required: ``data/evaluation/<method>/metrics.json``, ``.../pr/<route>/<pair>.csv``,
  ``data/features/<method>/info.json``, ``data/timing/<method>.json`` (Table III) and
  ``data/protocol/<method>.json`` for every method of ``cfg.methods``;
- optional (a section says "not produced in this run" and why when absent):
  ``data/evaluation/<method>/matrices/<route>/<pair>.npz``, ``data/evaluation/invariance.json``,
  ``data/dataset/`` (Fig. 1), ``models/<name>/train_log.csv``,
  ``data/evaluation_loops/<method>/metrics.json`` (loop closure within one drive), and
  ``models/cmal/model.pt`` with the dataset's training split: Fig. 11 runs the trained CMAL on
  the frames training held out (``models.cmal.heldout_fraction``, ``seed``;
  :mod:`cmal_lcd.reports.reconstructions`).

Writes into ``reports/``: ``metrics.json`` (route -> pair -> method -> metrics, each method's
protocol chosen on validation drives), ``metrics_paper.json`` (the paper's protocol),
``summary.json`` (the DVC metrics: each method's mean R@100P), ``summary/<method>.json`` (per
method, six means over routes and pairs under the selected protocol,
:data:`cmal_lcd.reports.tables.SUMMARY_KEYS`; ``dvc metrics show -R reports/summary``; see
:mod:`cmal_lcd.reports.dvc_files`), ``tables/*.{md,csv,tex}``,
``figures/*.{png,pdf}``, ``plots/{pr,roc}/<route>/<pair>.csv`` (DVC plots, every method
overlaid: :func:`cmal_lcd.reports.plots.write_overlay_plots`), ``config.yaml`` (the config,
headed by the git commit and dataset kind) and ``README.md``: the entries of
:data:`REPORT_OUTPUTS` (the stage's outs in ``dvc.yaml``).

Old or new, never a mix: everything is written into ``<out>/.report.new-<id>/`` and swapped in
once complete (:func:`cmal_lcd.io.staged_entries`); the previous report stays in place until
then (its outs are ``persist: true``, so DVC no longer deletes them before the run). Other
entries of ``<out>`` (``world/``, ``seeds/``, ``nordland/``...) are never touched.

The readers are :mod:`cmal_lcd.reports.inputs`, the tables and figures with their captions
:mod:`cmal_lcd.reports.sections`, the DVC files :mod:`cmal_lcd.reports.dvc_files`, the git
commit and ``config.yaml`` :mod:`cmal_lcd.reports.provenance`.

``python -m cmal_lcd.stages.report [--params params.yaml] [--evaluation data/evaluation]
[--loops data/evaluation_loops] [--features data/features] [--timing data/timing]
[--protocol data/protocol] [--models models] [--dataset data/dataset] [--out reports]``
"""

from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig

from cmal_lcd.io import atomic_write_text, staged_entries
from cmal_lcd.reports import dvc_files, inputs, provenance, sections, tables
from cmal_lcd.reports.readme import render_readme
from cmal_lcd.stages import parse_stage_args, run, stage_config, stage_parser
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.report")


#: What the report writes into its ``out_dir``, all replaced together (the ``report`` stage's
#: outs and metrics in dvc.yaml); every other entry of ``out_dir`` belongs to someone else.
REPORT_OUTPUTS = ("README.md", "config.yaml", "metrics.json", "metrics_paper.json",
                  "summary.json", "summary", "tables", "figures", "plots")


def configured_methods(cfg: DictConfig) -> list[str]:
    """``cfg.methods`` as a list; ValueError when it names none."""
    methods = list(cfg.get("methods") or [])
    if not methods:
        raise ValueError("methods: the config lists no methods to report")
    return methods


def main(cfg: DictConfig, *, evaluation_dir: Path = REPO.evaluation,
         features_dir: Path = REPO.features, models_dir: Path = REPO.models,
         dataset_dir: Path = REPO.dataset, out_dir: Path = REPO.reports,
         protocol_dir: Path = REPO.protocols,
         loops_dir: Path = REPO.loops,
         timing_dir: Path | None = None, repo_dir: Path | None = None) -> Path:
    """Write the report of one pipeline run into ``out_dir`` (see the module docstring).

    Parameters
    ----------
    cfg : DictConfig
        The composed config (``methods`` gives the methods and their order; Fig. 11 reads
        ``models.cmal.heldout_fraction`` and ``seed``).
    timing_dir : Path, optional
        ``<timing_dir>/<method>.json`` (stage ``extract_features``) for Table III; without it
        Table III has no times.
    repo_dir : Path, optional
        Git work tree whose commit is recorded (default: the current directory).

    Returns
    -------
    Path
        ``out_dir/README.md``.
    """
    out_dir, loops_dir = Path(out_dir), Path(loops_dir)
    repo_dir = Path(repo_dir) if repo_dir is not None else Path.cwd()
    run_files, selected, paper_setting, pr_curves, optional = _read_inputs(
        cfg, evaluation_dir=evaluation_dir, features_dir=features_dir, models_dir=models_dir,
        dataset_dir=dataset_dir, protocol_dir=protocol_dir, timing_dir=timing_dir)
    commit, dirty = provenance.git_state(repo_dir,
                                         ignore=provenance.ignored_paths(repo_dir, out_dir))
    kind = provenance.dataset_kind(run_files.dataset_meta, Path(dataset_dir))
    with staged_entries(out_dir, REPORT_OUTPUTS, tag="report") as staging:
        _write_report(staging, cfg, run_files, optional, selected=selected,
                      paper_setting=paper_setting, pr_curves=pr_curves, loops_dir=loops_dir,
                      commit=commit, dirty=dirty, kind=kind)
    logger.info("report written to %s", out_dir)
    return out_dir / "README.md"


def _read_inputs(cfg: DictConfig, *, evaluation_dir: Path, features_dir: Path,
                 models_dir: Path, dataset_dir: Path, protocol_dir: Path,
                 timing_dir: Path | None) -> tuple:
    """The run's files (:func:`cmal_lcd.reports.inputs.read_run`), its nested metrics under the
    selected and the paper's protocols, its PR curves and its optional inputs."""
    evaluation_dir, features_dir, models_dir, dataset_dir, protocol_dir = map(
        Path, (evaluation_dir, features_dir, models_dir, dataset_dir, protocol_dir))
    run_files = inputs.read_run(evaluation_dir=evaluation_dir, features_dir=features_dir,
                                protocol_dir=protocol_dir, dataset_dir=dataset_dir,
                                methods=configured_methods(cfg),
                                timing_dir=Path(timing_dir) if timing_dir is not None else None)
    inputs.relative_weights(run_files.infos, models_dir)
    methods = run_files.methods
    selected = run_files.nested_metrics("selected")
    paper_setting = run_files.nested_metrics("paper")
    pairs = tables.route_pairs(selected)
    pr_curves = inputs.read_pr_curves(evaluation_dir, pairs=pairs, methods=methods)
    optional = inputs.read_optional(evaluation_dir=evaluation_dir, models_dir=models_dir,
                                    dataset_dir=dataset_dir, pairs=pairs, methods=methods,
                                    model_names=list(cfg.get("model_names") or []),
                                    heldout_fraction=cfg.models.cmal.heldout_fraction,
                                    seed=cfg.seed, threads=cfg.runtime.threads)
    return run_files, selected, paper_setting, pr_curves, optional


def _write_report(staging: Path, cfg: DictConfig, run_files, optional, *, selected,
                  paper_setting, pr_curves, loops_dir: Path, commit: str, dirty: bool | None,
                  kind: str) -> None:
    """Every entry of :data:`REPORT_OUTPUTS` into ``staging``: the DVC metrics and plots files,
    the tables, the figures, ``config.yaml`` and ``README.md``."""
    methods, labels = run_files.methods, run_files.labels
    d_thresh = cfg.matching.d_thresh
    dvc_files.write_metrics(staging, selected=selected, paper_setting=paper_setting,
                            methods=methods)
    dvc_files.write_plots_files(staging / "plots", pr_curves,
                                evaluations=run_files.evaluations, labels=labels)
    dvc_files.write_training_plots(staging / "plots", optional.train_log_paths)
    table_entries = sections.table_entries(staging, run_files, optional, selected=selected,
                                           paper_setting=paper_setting,
                                           loop_metrics=inputs.read_loop_metrics(
                                               loops_dir, methods),
                                           loops_dir=loops_dir,
                                           d_thresh=d_thresh)
    # a ground-truth file's own sets decide what is right, not d_thresh (no band in Fig. 6)
    by_file = bool((run_files.dataset_meta or {}).get("ground_truth_sets"))
    figure_entries = sections.figure_entries(staging, run_files, optional,
                                             selected=selected, pr_curves=pr_curves,
                                             d_thresh=None if by_file
                                             else d_thresh)
    atomic_write_text(staging / "config.yaml",
                      provenance.config_text(cfg, commit=commit, dirty=dirty, kind=kind))
    atomic_write_text(staging / "README.md", render_readme(
        run=provenance.run_info(cfg, commit=commit, dirty=dirty, kind=kind,
                                meta=run_files.dataset_meta, protocols=run_files.protocols),
        methods=methods, labels=labels, infos=run_files.infos, selected=selected,
        paper_setting=paper_setting, tables=table_entries, figures=figure_entries))


def cli(argv: list[str] | None = None) -> None:
    """Command line: ``python -m cmal_lcd.stages.report [--params ...] [--out ...]``."""
    parser = stage_parser(__doc__)
    parser.add_argument("--evaluation", default=REPO.evaluation, type=Path)
    parser.add_argument("--features", default=REPO.features, type=Path)
    parser.add_argument("--models", default=REPO.models, type=Path)
    parser.add_argument("--dataset", default=REPO.dataset, type=Path)
    parser.add_argument("--protocol", default=REPO.protocols, type=Path)
    parser.add_argument("--loops", default=REPO.loops, type=Path)
    parser.add_argument("--timing", default=REPO.timings, type=Path)
    parser.add_argument("--out", default=REPO.reports, type=Path)
    args = parse_stage_args(parser, argv)
    cfg = stage_config(args, __name__)
    main(cfg, evaluation_dir=args.evaluation, features_dir=args.features,
         models_dir=args.models, dataset_dir=args.dataset, out_dir=args.out,
         protocol_dir=args.protocol, loops_dir=args.loops, timing_dir=args.timing)


if __name__ == "__main__":
    run(cli)
