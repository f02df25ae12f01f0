"""Stage ``report``: tables, figures, DVC metrics/plots files and ``reports/README.md``.

Reads only the pipeline's files (docs/architecture.md):

- required: ``data/evaluation/<method>/metrics.json``, ``.../pr/<route>/<pair>.csv`` and
  ``data/features/<method>/info.json`` for every method of ``cfg.methods``;
- optional (a section says "not produced in this run" and why when absent):
  ``data/evaluation/<method>/matrices/<route>/<pair>.npz``, ``data/evaluation/invariance.json``,
  ``data/dataset/`` (Fig. 1), ``models/cmal/reconstructions.npz`` (Fig. 11),
  ``models/<name>/train_log.csv``.

Writes into ``reports/``: ``metrics.json`` (route -> pair -> method -> metrics, each method's
protocol chosen on validation drives), ``metrics_paper.json`` (the paper's protocol),
``summary/<method>.json`` (the DVC metrics: per method, six means over routes and pairs under
the selected protocol, :data:`cmal_lcd.reports.tables.SUMMARY_KEYS`; one file per method so
``dvc metrics show`` prints one short row per method), ``tables/*.{md,csv,tex}``,
``figures/*.{png,pdf}``, ``plots/{pr,roc}/<route>/<pair>.csv`` (DVC plots, every method
overlaid: :func:`cmal_lcd.reports.plots.write_overlay_plots`), ``config.yaml`` (the config,
headed by the git commit and dataset kind) and ``README.md``.

``python -m cmal_lcd.stages.report [--params params.yaml] [--evaluation data/evaluation]
[--features data/features] [--models models] [--dataset data/dataset] [--out reports]``
"""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf

from cmal_lcd.io import atomic_write_json, atomic_write_text
from cmal_lcd.reports import figures, plots, tables
from cmal_lcd.reports.readme import Entry, RunInfo, render_readme
from cmal_lcd.stages import run, stage_config, stage_parser

logger = logging.getLogger(__name__)

PR_COLUMNS = ("recall", "precision")


# ---------------------------------------------------------------------------------------------
# Reading inputs
# ---------------------------------------------------------------------------------------------

def read_json(path: Path, *, producer: str) -> dict:
    """A JSON file; FileNotFoundError/ValueError naming it (and the stage that writes it)."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing; run the {producer} stage")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from err


def read_infos(features_dir: Path, methods: Sequence[str]) -> dict[str, dict]:
    """``{method: info.json}``; every info must have a ``label``."""
    infos = {}
    for method in methods:
        path = features_dir / method / "info.json"
        info = read_json(path, producer=f"extract_features@{method}")
        if not info.get("label"):
            raise ValueError(f"{path}: no 'label' (the method's name in tables)")
        infos[method] = info
    return infos


def read_pr_curve(path: Path) -> pd.DataFrame:
    """A PR curve file (``recall, precision, threshold``)."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing; run the evaluate stage")
    curve = pd.read_csv(path)
    missing = [c for c in PR_COLUMNS if c not in curve.columns]
    if missing:
        raise ValueError(f"{path}: missing columns {missing}")
    return curve


def read_pr_curves(evaluation_dir: Path, *, pairs: Sequence[tuple[str, str]],
                   methods: Sequence[str]) -> dict:
    """``{route: {pair: {method: PR curve}}}`` from ``<evaluation>/<method>/pr/``."""
    curves: dict = {}
    for route, pair in pairs:
        for method in methods:
            source = evaluation_dir / method / "pr" / route / f"{pair}.csv"
            curves.setdefault(route, {}).setdefault(pair, {})[method] = read_pr_curve(source)
    return curves


def dataset_meta(dataset_dir: Path) -> dict | None:
    """``dataset.json`` or None when absent."""
    path = dataset_dir / "dataset.json"
    return read_json(path, producer="dataset") if path.is_file() else None


def git_state(repo_dir: Path, *, ignore: Sequence[str] = ()) -> tuple[str, bool | None]:
    """``(commit, dirty)`` of the git work tree at ``repo_dir``.

    ``dirty`` is whether tracked files differ from the commit, ignoring ``ignore`` paths (the
    report's own outputs and ``dvc.lock``, which a pipeline run rewrites). Without git or a
    commit: ``("unknown (...)", None)``.
    """
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(repo_dir), *args], check=True,
                              capture_output=True, text=True, timeout=30).stdout.strip()
    try:
        commit = git("rev-parse", "HEAD")
    except (OSError, subprocess.SubprocessError):
        return "unknown (not a git repository, or no commit yet)", None
    try:
        excludes = [f":(exclude){p}" for p in ignore]
        dirty = bool(git("status", "--porcelain", "--untracked-files=no", "--", ".", *excludes))
    except (OSError, subprocess.SubprocessError):
        dirty = None
    return commit, dirty


# ---------------------------------------------------------------------------------------------
# DVC metrics and plots files
# ---------------------------------------------------------------------------------------------

def write_summary(summary_dir: Path, summary: Mapping[str, Mapping]) -> list[Path]:
    """``<summary_dir>/<method>.json`` per method (the DVC metrics); other ``*.json`` removed.

    Parameters
    ----------
    summary : mapping
        ``{method: {key: value}}`` from :func:`cmal_lcd.reports.tables.method_summary`.
    """
    summary_dir.mkdir(parents=True, exist_ok=True)
    for stale in summary_dir.glob("*.json"):
        if stale.stem not in summary:
            stale.unlink()
    return [atomic_write_json(summary_dir / f"{method}.json", row)
            for method, row in summary.items()]


def write_plots_files(plots_dir: Path, curves: Mapping, *, evaluations: Mapping,
                      labels: Mapping[str, str]) -> list[Path]:
    """The ``dvc plots`` files: ``plots/{pr,roc}/<route>/<pair>.csv``, every method overlaid.

    ``evaluations`` (``{method: metrics.json}``) gives each pair's ``n_positive`` and
    ``n_scored`` (selected protocol) for the ROC. Earlier files under ``pr/`` and ``roc/`` are
    removed first, so no chart from another run (or the old one-file-per-method layout) stays.
    """
    for kind in ("pr", "roc"):
        if (plots_dir / kind).is_dir():
            shutil.rmtree(plots_dir / kind)
    counts: dict = {}
    for route, per_pair in curves.items():
        for pair, per_method in per_pair.items():
            for method in per_method:
                values = evaluations[method][route][pair]["selected"]
                if "n_positive" in values and "n_scored" in values:
                    counts.setdefault(route, {}).setdefault(pair, {})[method] = {
                        "n_positive": values["n_positive"], "n_scored": values["n_scored"]}
    return plots.write_overlay_plots(plots_dir, curves, counts=counts, labels=labels)


# ---------------------------------------------------------------------------------------------
# Tables
# ---------------------------------------------------------------------------------------------

def _table_entry(rendered: dict, stem: Path, out_dir: Path, *, title: str,
                 description: str) -> Entry:
    tables.write_table(rendered, stem)
    files = [str(stem.relative_to(out_dir)) + f".{suffix}" for suffix in rendered]
    markdown = rendered["md"].split("\n\n", 1)[1]
    return Entry(title=title, description=description, files=files, markdown=markdown)


def write_tables(out_dir: Path, *, selected: dict, paper_setting: dict, methods: Sequence[str],
                 labels: Mapping[str, str], infos: Mapping[str, dict],
                 invariance: dict | None, invariance_path: Path,
                 protocols: Mapping[str, dict]) -> list[Entry]:
    """Write every table; return their README entries."""
    tdir = out_dir / "tables"
    entries = []
    protocol = tables.protocol_table(protocols, methods=methods, labels=labels)
    entries.append(_table_entry(
        tables.render_table(protocol, caption="Matching protocol per method, chosen by the "
                            "select_protocol stage on the validation drives (mean over the "
                            "validation pairs); never tuned on a test route.",
                            label="tab:protocol",
                            columns={"candidates": lambda v: f"{v:.0f}"}),
        tdir / "protocol", out_dir, title="Matching protocol per method",
        description="What each method's codes go through before SeqSLAM: centring (none; the "
                    "reference map's mean code; or the training-set mean code of the frame's "
                    "nearest weather), L2 normalisation, and contrast enhancement (eq. 14) with "
                    "its window. Every combination was scored on the validation drives; the "
                    "best mean recall@100%P won (ties: AUC-PR). The paper protocol's "
                    "validation scores are beside it. Source: `data/protocol/<method>.json`, "
                    "which also holds every candidate's per-pair scores."))
    table2 = tables.recall_at_100p_table(selected, methods=methods, labels=labels)
    entries.append(_table_entry(
        tables.render_table(table2, caption="Table II: recall at 100% precision, per route and "
                            "reference-query pair (each method's protocol chosen on the validation drives); 'paper' rows are the "
                            "paper's GTA V numbers.", label="tab:recall-at-100p"),
        tdir / "table2_recall_at_100p", out_dir, title="Table II: recall at 100% precision",
        description="The share of true loop closures found before the first false one, per "
                    "method and pair, with the paper's Table II values under each method where "
                    "route and pair match the paper's."))
    auc = tables.auc_table(selected, methods=methods, labels=labels)
    entries.append(_table_entry(
        tables.render_table(auc, caption="Area under the ROC and precision-recall curves "
                            "(selected protocols).", label="tab:auc"),
        tdir / "auc", out_dir, title="AUC-ROC and AUC-PR",
        description="Threshold-free summaries of each PR/ROC curve (paper Fig. 10 as numbers); "
                    "the paper gives these only as a bar chart, so there is no paper column."))
    recall_k = tables.recall_at_k_table(selected, methods=methods, labels=labels)
    entries.append(_table_entry(
        tables.render_table(recall_k, caption="recall@K: the share of scored queries with a "
                            "reference frame within D_thresh of the true place among their K "
                            "best, after sequence matching and single-frame (mean over routes "
                            "and pairs; selected protocols).", label="tab:recall-at-k"),
        tdir / "recall_at_k", out_dir, title="recall@K",
        description="The place-recognition community's retrieval measure beside the PR "
                    "metrics: a query counts at K when one of the K reference frames ranked "
                    "best (by SeqSLAM's sequence score, or by the frame difference alone) is "
                    "within D_thresh frames of its true place. recall@1 is the match itself; "
                    "recall@K rises with K. Per pair in `metrics.json`; – where the evaluation "
                    "predates recall@K."))
    table3 = tables.inference_table(infos, methods=methods)
    entries.append(_table_entry(
        tables.render_table(table3, caption="Table III: feature inference time per frame (ms, "
                            "median of repeats, warm-up excluded) and storage per frame; paper "
                            "columns from its Table III and Section IV-D.",
                            label="tab:inference", default=tables.format_number,
                            columns={"batch-1 ms/frame": tables.format_ms,
                                     "batched ms/frame": tables.format_ms}),
        tdir / "table3_inference", out_dir, title="Table III: inference time and storage",
        description="Milliseconds per frame from a raw frame to its code at batch size 1 and "
                    "batched, on the device named, and the bytes one code takes."))
    ablation = tables.ablation_table(selected, paper_setting, methods=methods, labels=labels)
    entries.append(_table_entry(
        tables.render_table(ablation, caption="Ablation: each method under its protocol chosen "
                            "on validation drives and under the paper's protocol (raw codes, "
                            "eq. 14 with Table I's window).",
                            label="tab:ablation-paper-protocol"),
        tdir / "ablation_paper_protocol", out_dir, title="Ablation: the paper's protocol",
        description="The same matching on raw codes with the paper's contrast enhancement "
                    "(eq. 14, Table I), which can flatten the differences of smooth learned "
                    "codes and leaves per-weather code offsets in place; it keeps the paper "
                    "comparison visible."))
    title = "Condition invariance of the codes"
    if invariance is None:
        entries.append(Entry(title=title, description="", missing=(
            f"`{invariance_path}` does not exist (the code-invariance analysis did not run).")))
    else:
        inv = tables.invariance_table(invariance, methods=methods, labels=labels)
        entries.append(_table_entry(
            tables.render_table(inv, caption="Weather invariance of the codes, across weathers: "
                                "mean difference to the same place and to other places "
                                "(after each method's selected normalisation; mean over the "
                                "route's test pairs).",
                                label="tab:invariance", default=tables.format_number,
                                columns={"weather classifier accuracy": tables.format_percent,
                                         "single-frame r@1": tables.format_percent,
                                         "single-frame r@1 (raw codes)":
                                             tables.format_percent}),
            tdir / "invariance", out_dir, title=title,
            description="For every cross-weather test pair, with codes normalised as the "
                        "method's selected protocol does: the mean difference (the method's "
                        "own: eq. 13 for codes, SAD for thumbnails) between a query and the "
                        "reference frame of its true place, and between it and reference frames "
                        "more than D_thresh frames away (other places, also under the other "
                        "weather). Their ratio is scale-free: lower = the place dominates the "
                        "code. Single-frame r@1: nearest reference frame within D_thresh of the "
                        "true place, no sequence. The raw-code columns repeat the ratio and "
                        "r@1 without normalisation. The accuracy is CMAL's weather classifier C "
                        "on the test frames."))
    return entries


# ---------------------------------------------------------------------------------------------
# Figures
# ---------------------------------------------------------------------------------------------

def write_choice_tables(out_dir: Path, *, infos: Mapping[str, dict], models_dir: Path,
                        model_names: Sequence[str]) -> list[Entry]:
    """Tables of the choices made on validation drives besides the protocol: the ``dnn``
    layer and where each model's validation curve flattens (``iterations``)."""
    tdir = out_dir / "tables"
    entries = []
    selection = (infos.get("dnn") or {}).get("layer_selection")
    if selection:
        entries.append(_table_entry(
            tables.render_table(tables.layer_choice_table(selection),
                                caption="DNN layer, chosen by the extract_features stage on the "
                                        "validation drives (mean over validation pairs; codes "
                                        f"{selection.get('protocol', '')}).",
                                label="tab:dnn-layer"),
            tdir / "dnn_layer", out_dir, title="DNN layer chosen on validation",
            description=f"Every EfficientNet-Lite0 block of `features.dnn.layer_candidates`, "
                        f"pooled to the configured grid, scored on the validation drives; the "
                        f"best mean {selection.get('criterion')} won. Source: "
                        f"`data/features/dnn/info.json` (`layer_selection`)."))
    logs = {}
    for name in model_names:
        path = models_dir / name / "train_log.csv"
        if path.is_file():
            logs[name] = pd.read_csv(path)
    curve = tables.validation_curve_table(logs)
    if not curve.empty:
        entries.append(_table_entry(
            tables.render_table(curve, caption="Validation recall@100%P logged during "
                                "training (mean over validation pairs; codes centred by the "
                                "training mean of their nearest condition, L2, no enhancement).",
                                label="tab:validation-curve",
                                columns={"best at iteration": lambda v: f"{v:.0f}",
                                         "last iteration": lambda v: f"{v:.0f}",
                                         "within 2 points of best from": lambda v: f"{v:.0f}"}),
            tdir / "validation_curve", out_dir, title="Where training flattens (iterations)",
            description="`start` is the untrained model (iteration 0). `models.<name>."
                        "iterations` is chosen from this curve (see the training-curve "
                        "figures, `val` panel); the last column is the first logged iteration "
                        "within 2 points of the best value. Source: "
                        "`models/<name>/train_log.csv`."))
    return entries


def _figure_files(paths: Sequence[Path], out_dir: Path) -> list[str]:
    return [str(Path(p).relative_to(out_dir)) for p in paths]


def write_pr_figures(out_dir: Path, curves: Mapping, *, labels: Mapping[str, str],
                     styles: Mapping) -> list[Entry]:
    """Figs. 8-9: one PR figure per route."""
    entries = []
    for route, per_pair in curves.items():
        fig = figures.pr_curves_figure(per_pair, route=route, labels=labels, styles=styles)
        paths = figures.save_figure(fig, out_dir / "figures" / f"fig08-09_pr_{route}")
        entries.append(Entry(
            title=f"Figs. 8-9: precision-recall curves, {route}",
            description="Precision against recall of every method on each reference-query "
                        "pair of this route, sweeping the SeqSLAM confidence threshold; a curve "
                        "that stays at precision 1 further to the right has higher "
                        "recall@100%P.", files=_figure_files(paths, out_dir)))
    return entries


def write_matrix_figures(out_dir: Path, evaluation_dir: Path, *, pairs: Sequence[tuple[str, str]],
                         methods: Sequence[str], labels: Mapping[str, str]) -> list[Entry]:
    """Fig. 6: difference and enhanced matrices of every method, one figure per pair."""
    entries = []
    for route, pair in pairs:
        title = f"Fig. 6: difference and enhanced matrices, {route} {pair}"
        found, absent = {}, []
        for method in methods:
            path = evaluation_dir / method / "matrices" / route / f"{pair}.npz"
            if path.is_file():
                with np.load(path, allow_pickle=False) as npz:
                    found[method] = {k: npz[k] for k in ("D", "D_hat", "match", "truth")
                                     if k in npz.files}
            else:
                absent.append(str(path))
        if not found:
            entries.append(Entry(title=title, description="", missing=(
                "no difference matrices were saved by the evaluate stage (" + ", ".join(absent)
                + ")")))
            continue
        fig = figures.matrices_figure(found, labels=labels,
                                      title=f"{route} {pair}: rows = reference, "
                                            f"columns = query")
        paths = figures.save_figure(fig, out_dir / "figures" / f"fig06_matrices_{route}_{pair}",
                                    png_dpi=100)
        note = f" Missing for: {', '.join(absent)}." if absent else ""
        entries.append(Entry(
            title=title,
            description="Left: the frame-to-frame difference matrix D of the normalised codes "
                        "(dark = alike); right: the matrix the sequence search used (after "
                        "eq. 14 only when the method's selected protocol enhances), with the true "
                        "place (white line) and "
                        "SeqSLAM's matches (red dots); a clean diagonal means the code "
                        "recognises places across the weather change." + note,
            files=_figure_files(paths, out_dir)))
    return entries


def write_weather_figures(out_dir: Path, dataset_dir: Path) -> list[Entry]:
    """Fig. 1 (weather samples) and the world map, via the world engineer's plotting code."""
    specs = (("Fig. 1: the same places under every weather", "fig01_weather_samples",
              "plot_weather_samples",
              "Test frames of one place under each weather condition, as in the paper's Fig. 1."),
             ("World map", "world_map", "plot_world_map",
              "Training area and test routes of the dataset, seen from above."))
    reason = None
    missing_files = [name for name in ("dataset.json", "images.npy", "frames.csv")
                     if not (dataset_dir / name).is_file()]
    if missing_files:
        reason = f"`{dataset_dir}` has no {', '.join(missing_files)}."
    else:
        try:
            from cmal_lcd.data.store import load_dataset
            from cmal_lcd.reports import world_figures
        except ImportError as err:
            reason = f"the plotting code is not available ({err})."
    if reason:
        return [Entry(title=t, description="", missing=reason) for t, _, _, _ in specs]
    dataset = load_dataset(dataset_dir)
    entries = []
    for title, name, function, description in specs:
        plot = getattr(world_figures, function, None)
        if plot is None:
            entries.append(Entry(title=title, description="", missing=(
                f"`cmal_lcd.reports.world_figures.{function}` does not exist.")))
            continue
        if name == "world_map" and dataset.meta.get("kind") != "gtav_weather":
            entries.append(Entry(title=title, description="", missing=(
                f"the dataset is `{dataset.meta.get('kind')}`, not the procedural world: "
                "there is no map to draw.")))
            continue
        paths = [out_dir / "figures" / f"{name}{suffix}" for suffix in (".png", ".pdf")]
        for path in paths:
            plot(dataset, path)
        entries.append(Entry(title=title, description=description,
                             files=_figure_files([p for p in paths if p.is_file()], out_dir)))
    return entries


def _condition_names(values: np.ndarray, conditions: Sequence[str] | None) -> list[str]:
    values = np.asarray(values)
    if np.issubdtype(values.dtype, np.integer) and conditions:
        return [conditions[int(v)] if 0 <= int(v) < len(conditions) else str(v) for v in values]
    return [str(v) for v in values]


def write_reconstruction_figure(out_dir: Path, models_dir: Path, *,
                                conditions: Sequence[str] | None) -> Entry:
    """Fig. 11 from ``models/cmal/reconstructions.npz``."""
    title = "Fig. 11: reconstructions"
    path = models_dir / "cmal" / "reconstructions.npz"
    if not path.is_file():
        return Entry(title=title, description="", missing=(
            f"`{path}` does not exist (no trained CMAL model in this run)."))
    with np.load(path, allow_pickle=False) as npz:
        missing = [k for k in ("a", "recon_a", "translated_b", "b", "condition_a", "condition_b")
                   if k not in npz.files]
        if missing:
            raise ValueError(f"{path}: missing arrays {missing}")
        arrays = {k: npz[k] for k in npz.files}
    fig = figures.reconstructions_figure(
        arrays["a"], arrays["recon_a"], arrays["translated_b"], arrays["b"],
        condition_a=_condition_names(arrays["condition_a"], conditions),
        condition_b=_condition_names(arrays["condition_b"], conditions))
    paths = figures.save_figure(fig, out_dir / "figures" / "fig11_reconstructions")
    return Entry(title=title, description=(
        "Each row: a test frame A, CMAL's reconstruction of its code under A's weather, the same "
        "code decoded under another weather B, and a real frame under B; a good model keeps the "
        "scene and changes only the weather."), files=_figure_files(paths, out_dir))


def write_training_figures(out_dir: Path, models_dir: Path,
                           model_names: Sequence[str]) -> list[Entry]:
    """Training curves of every trained model from its ``train_log.csv``."""
    entries = []
    for name in model_names:
        title = f"Training curves: {name}"
        path = models_dir / name / "train_log.csv"
        if not path.is_file():
            entries.append(Entry(title=title, description="", missing=f"`{path}` does not exist."))
            continue
        log = pd.read_csv(path)
        if log.empty:
            entries.append(Entry(title=title, description="", missing=f"`{path}` has no rows."))
            continue
        fig = figures.training_curves_figure(log, title=f"{name}: training log")
        paths = figures.save_figure(fig, out_dir / "figures" / f"training_{name}")
        entries.append(Entry(title=title, description=(
            f"Every logged loss of the {name} model against iteration, grouped by module "
            f"(D = discriminator, G = decoder/generator, E = encoder, C = classifier). The "
            f"`val` panel scores the validation drives during training (mean over validation "
            f"pairs of SeqSLAM R@100P, AUC-PR and single-frame r@1; codes centred by the "
            f"training mean of their nearest condition, L2, no enhancement; iteration 0 is "
            f"the untrained model): `iterations` is chosen where it flattens."),
            files=_figure_files(paths, out_dir)))
    return entries


# ---------------------------------------------------------------------------------------------
# The stage
# ---------------------------------------------------------------------------------------------

def main(cfg: DictConfig, *, evaluation_dir: Path = Path("data/evaluation"),
         features_dir: Path = Path("data/features"), models_dir: Path = Path("models"),
         dataset_dir: Path = Path("data/dataset"), out_dir: Path = Path("reports"),
         protocol_dir: Path = Path("data/protocol"), repo_dir: Path | None = None) -> Path:
    """Write the report of one pipeline run into ``out_dir`` (see the module docstring).

    Parameters
    ----------
    cfg : DictConfig
        The composed config (``methods`` gives the methods and their order).
    repo_dir : Path, optional
        Git work tree whose commit is recorded (default: the current directory).

    Returns
    -------
    Path
        ``out_dir/README.md``.
    """
    evaluation_dir, features_dir, models_dir, dataset_dir, out_dir, protocol_dir = map(
        Path, (evaluation_dir, features_dir, models_dir, dataset_dir, out_dir, protocol_dir))
    methods = list(cfg.get("methods") or [])
    if not methods:
        raise ValueError("methods: the config lists no methods to report")
    evaluations = {m: read_json(evaluation_dir / m / "metrics.json", producer=f"evaluate@{m}")
                   for m in methods}
    infos = read_infos(features_dir, methods)
    protocols = {m: read_json(protocol_dir / f"{m}.json", producer=f"select_protocol@{m}")
                 for m in methods}
    labels = {m: infos[m]["label"] for m in methods}
    meta = dataset_meta(dataset_dir)
    pair_order = [(str(p[0]), str(p[3])) for p in (meta or {}).get("pairs", [])]

    selected = tables.metrics_by_route_pair_method(evaluations, methods=methods,
                                                   variant="selected", pair_order=pair_order)
    paper_setting = tables.metrics_by_route_pair_method(evaluations, methods=methods, variant="paper",
                                                pair_order=pair_order)
    atomic_write_json(out_dir / "metrics.json", selected)
    atomic_write_json(out_dir / "metrics_paper.json", paper_setting)
    write_summary(out_dir / "summary", tables.method_summary(selected, methods=methods))

    # PR curves: DVC plots files (every method overlaid per pair, PR and ROC) and Figs. 8-9
    curves = read_pr_curves(evaluation_dir, pairs=tables.route_pairs(selected), methods=methods)
    write_plots_files(out_dir / "plots", curves, evaluations=evaluations, labels=labels)

    invariance_path = evaluation_dir / "invariance.json"
    invariance = (read_json(invariance_path, producer="analyse_codes")
                  if invariance_path.is_file() else None)
    table_entries = write_tables(out_dir, selected=selected, paper_setting=paper_setting, methods=methods,
                                 labels=labels, infos=infos, invariance=invariance,
                                 invariance_path=invariance_path, protocols=protocols)

    table_entries += write_choice_tables(out_dir, infos=infos, models_dir=models_dir,
                                         model_names=list(cfg.get("model_names") or []))

    styles = figures.method_styles(methods)
    figure_entries = write_weather_figures(out_dir, dataset_dir)
    figure_entries += write_matrix_figures(out_dir, evaluation_dir,
                                           pairs=tables.route_pairs(selected), methods=methods,
                                           labels=labels)
    figure_entries += write_pr_figures(out_dir, curves, labels=labels, styles=styles)
    paths = figures.save_figure(
        figures.auc_bars_figure(selected, methods=methods, labels=labels, styles=styles),
        out_dir / "figures" / "fig10_auc")
    figure_entries.append(Entry(
        title="Fig. 10: area under the curve", files=_figure_files(paths, out_dir),
        description="AUC-ROC (top) and AUC-PR (bottom) of every method on every route and "
                    "pair; higher bars mean a more reliable loop closure score."))
    figure_entries.append(write_reconstruction_figure(
        out_dir, models_dir, conditions=(meta or {}).get("conditions")))
    figure_entries += write_training_figures(out_dir, models_dir,
                                             list(cfg.get("model_names") or []))

    repo_dir = Path(repo_dir) if repo_dir is not None else Path.cwd()
    ignore = ["dvc.lock"]
    try:
        ignore.append(str(out_dir.resolve().relative_to(repo_dir.resolve())))
    except ValueError:
        pass
    commit, dirty = git_state(repo_dir, ignore=ignore)
    kind = str((meta or {}).get("kind", f"unknown ({dataset_dir}/dataset.json missing)"))
    run = RunInfo(seed=cfg.get("seed"), git_commit=commit, git_dirty=dirty, dataset_kind=kind,
                  matching=OmegaConf.to_container(cfg.matching, resolve=True)
                  if "matching" in cfg else {})
    header = (f"# Config that produced the numbers in this folder.\n# git commit: {commit}"
              f"{' (dirty)' if dirty else ''}\n# dataset kind: {kind}\n")
    atomic_write_text(out_dir / "config.yaml", header + OmegaConf.to_yaml(cfg, resolve=True))
    text = render_readme(run=run, methods=methods, labels=labels, infos=infos,
                         selected=selected, paper_setting=paper_setting, tables=table_entries,
                         figures=figure_entries)
    readme = atomic_write_text(out_dir / "README.md", text)
    logger.info("report written to %s", out_dir)
    return readme


def cli(argv: list[str] | None = None) -> None:
    """Command line: ``python -m cmal_lcd.stages.report [--params ...] [--out ...]``."""
    parser = stage_parser(__doc__)
    parser.add_argument("--evaluation", default="data/evaluation", type=Path)
    parser.add_argument("--features", default="data/features", type=Path)
    parser.add_argument("--models", default="models", type=Path)
    parser.add_argument("--dataset", default="data/dataset", type=Path)
    parser.add_argument("--protocol", default="data/protocol", type=Path)
    parser.add_argument("--out", default="reports", type=Path)
    args = parser.parse_args(argv)
    cfg = stage_config(args)
    main(cfg, evaluation_dir=args.evaluation, features_dir=args.features,
         models_dir=args.models, dataset_dir=args.dataset, out_dir=args.out,
         protocol_dir=args.protocol)


if __name__ == "__main__":
    run(cli)
