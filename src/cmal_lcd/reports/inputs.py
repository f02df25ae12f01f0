"""The report's file readers: the pipeline's files (docs/architecture.md) as plain data.

Required inputs raise an error naming the file and the stage that writes it
(:func:`read_json`, :func:`read_pr_curve`); optional ones come back as ``None`` (or are left
out of a dict), and the report section that needs them says why it is missing.

- :func:`read_run` (:class:`RunFiles`, required): ``metrics.json``, ``info.json`` and
  ``protocol/<method>.json`` of every method, and ``dataset.json`` (optional);
- :func:`read_pr_curves` (required): ``<evaluation>/<method>/pr/<route>/<pair>.csv``;
- :func:`read_loop_metrics` (optional): ``<evaluation_loops>/<method>/metrics.json``;
- :func:`read_optional` (:class:`OptionalFiles`): ``invariance.json``,
  ``models/<name>/train_log.csv``, the dataset folder (Fig. 1 and the world map),
  ``<evaluation>/<method>/matrices/<route>/<pair>.npz`` (Fig. 6, read one pair at a time) and
  Fig. 11's arrays, computed from ``models/cmal/model.pt`` and the dataset's training split
  (:func:`compute_reconstructions`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd

from cmal_lcd.evaluation.loop_closure import STRICT
from cmal_lcd.reports import reconstructions as fig11
from cmal_lcd.reports import tables

#: Columns a PR curve file must have.
PR_COLUMNS = ("recall", "precision")
#: Arrays of a difference-matrix file that Fig. 6 draws (those present are read).
MATRIX_KEYS = ("D", "D_hat", "match", "truth")
#: Files of a dataset folder the weather figures need.
DATASET_FILES = ("dataset.json", "images.npy", "frames.csv")


def read_json(path: Path, *, producer: str) -> dict:
    """A JSON file; FileNotFoundError/ValueError naming it (and the stage that writes it)."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing; run the {producer} stage")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from err


def read_evaluations(evaluation_dir: Path, methods: Sequence[str]) -> dict[str, dict]:
    """``{method: metrics.json}`` (``{route: {pair: {variant: {metric: value}}}}``)."""
    return {m: read_json(evaluation_dir / m / "metrics.json", producer=f"evaluate@{m}")
            for m in methods}


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


def relative_weights(infos: Mapping[str, dict], models_dir: Path) -> None:
    """Name the trained weights in ``infos[*]["weights"]`` relative to the run: the absolute
    ``models_dir`` a Hydra job passes to its stages becomes ``models`` (the report is read
    apart from the machine and folder that produced it). Edits ``infos`` in place."""
    root = str(Path(models_dir).resolve())
    for info in infos.values():
        if isinstance(info.get("weights"), str):
            info["weights"] = info["weights"].replace(root, "models")


def read_protocols(protocol_dir: Path, methods: Sequence[str]) -> dict[str, dict]:
    """``{method: protocol/<method>.json}`` (``selected``, ``paper``, ``candidates``, ...)."""
    return {m: read_json(protocol_dir / f"{m}.json", producer=f"select_protocol@{m}")
            for m in methods}


def dataset_meta(dataset_dir: Path) -> dict | None:
    """``dataset.json`` or None when absent."""
    path = dataset_dir / "dataset.json"
    return read_json(path, producer="dataset") if path.is_file() else None


def read_loop_metrics(loops_dir: Path, methods: Sequence[str]) -> dict[str, dict | None]:
    """``<loops_dir>/<method>/metrics.json`` of every method (stage ``evaluate_loops``), None
    for a method whose file is absent; ``{"skipped": reason}`` when the dataset has no loops."""
    return {m: read_json(path, producer=f"evaluate_loops@{m}") if path.is_file() else None
            for m in methods for path in [Path(loops_dir) / m / "metrics.json"]}


def read_invariance(path: Path) -> dict | None:
    """``invariance.json`` (``{route: {method: {...}}}``) or None when absent."""
    return read_json(path, producer="analyse_codes") if path.is_file() else None


@dataclass(frozen=True)
class RunFiles:
    """The required files of one pipeline run (and ``dataset.json``), read by most sections.

    Attributes
    ----------
    methods : list of str
        The methods, in report order.
    evaluations : dict
        ``{method: metrics.json}``: ``{route: {pair: {variant: {metric: value}}}}``.
    infos : dict
        ``{method: info.json}`` (each with a ``label``).
    protocols : dict
        ``{method: protocol/<method>.json}``.
    dataset_meta : dict or None
        ``dataset.json`` (None when absent).
    """

    methods: list[str]
    evaluations: dict[str, dict]
    infos: dict[str, dict]
    protocols: dict[str, dict]
    dataset_meta: dict | None

    @property
    def labels(self) -> dict[str, str]:
        """``{method: label}``, the method's name in tables and figures."""
        return {m: self.infos[m]["label"] for m in self.methods}

    @property
    def pair_order(self) -> list[tuple[str, str]]:
        """``(route, pair name)`` in ``dataset.json``'s order (empty without it)."""
        return [(str(p[0]), str(p[3])) for p in (self.dataset_meta or {}).get("pairs", [])]

    @property
    def conditions(self) -> list[str] | None:
        """``dataset.json``'s ordered condition names (None without them)."""
        return (self.dataset_meta or {}).get("conditions")

    def strict_metrics(self) -> tuple[dict, int] | None:
        """The ``strict`` variant (``matching.d_thresh_strict``) as :meth:`nested_metrics`, and
        its tolerance in frames; None unless every method's every pair has one."""
        found = [pair.get(STRICT) for evaluation in self.evaluations.values()
                 for route in evaluation.values() for pair in route.values()]
        if not found or any(f is None for f in found):
            return None
        return self.nested_metrics(STRICT), int(found[0]["d_thresh"])

    def nested_metrics(self, variant: str) -> dict:
        """``{route: {pair: {method: {metric: value}}}}`` of one protocol variant
        (``selected`` or ``paper``), pairs in :attr:`pair_order` first
        (:func:`cmal_lcd.reports.tables.metrics_by_route_pair_method`)."""
        return tables.metrics_by_route_pair_method(self.evaluations, methods=self.methods,
                                                   variant=variant, pair_order=self.pair_order)


def read_timings(timing_dir: Path, methods: Sequence[str]) -> dict[str, dict]:
    """``{method: <timing_dir>/<method>.json}``: Table III timings (stage ``extract_features``)."""
    return {m: read_json(timing_dir / f"{m}.json", producer=f"extract_features@{m}")
            for m in methods}


def read_run(*, evaluation_dir: Path, features_dir: Path, protocol_dir: Path,
             dataset_dir: Path, methods: Sequence[str], timing_dir: Path | None = None
             ) -> RunFiles:
    """Every method's metrics, info and protocol, and ``dataset.json``.

    ``infos[method]["timing"]`` is ``<timing_dir>/<method>.json`` (the features stage writes
    timings apart from ``info.json``); without ``timing_dir``, whatever ``info.json`` holds.
    """
    infos = read_infos(features_dir, methods)
    if timing_dir is not None:
        for method, timing in read_timings(timing_dir, methods).items():
            infos[method] = {**infos[method], "timing": timing}
    return RunFiles(methods=list(methods), evaluations=read_evaluations(evaluation_dir, methods),
                    infos=infos,
                    protocols=read_protocols(protocol_dir, methods),
                    dataset_meta=dataset_meta(dataset_dir))


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


@dataclass(frozen=True)
class PairMatrices:
    """The saved difference matrices of one route and pair.

    Attributes
    ----------
    route, pair : str
    found : dict
        ``{method: {key: ndarray}}`` with the keys of :data:`MATRIX_KEYS` the file has:
        ``D``, ``D_hat`` ``(n_reference, n_query)``, ``match``, ``truth`` ``(n_query,)``.
    absent : list of str
        The files looked for and not found.
    """

    route: str
    pair: str
    found: dict[str, dict[str, np.ndarray]]
    absent: list[str]


def read_pair_matrices(evaluation_dir: Path, *, route: str, pair: str,
                       methods: Sequence[str]) -> PairMatrices:
    """The matrices of every method for one pair (methods without a file in ``absent``)."""
    found, absent = {}, []
    for method in methods:
        path = evaluation_dir / method / "matrices" / route / f"{pair}.npz"
        if path.is_file():
            with np.load(path, allow_pickle=False) as npz:
                found[method] = {k: npz[k] for k in MATRIX_KEYS if k in npz.files}
        else:
            absent.append(str(path))
    return PairMatrices(route=route, pair=pair, found=found, absent=absent)


def iter_pair_matrices(evaluation_dir: Path, *, pairs: Sequence[tuple[str, str]],
                       methods: Sequence[str]) -> Iterator[PairMatrices]:
    """:func:`read_pair_matrices` for each pair, read when the caller gets to it (one pair's
    matrices in memory at a time)."""
    for route, pair in pairs:
        yield read_pair_matrices(evaluation_dir, route=route, pair=pair, methods=methods)


def train_log_paths(models_dir: Path, names: Sequence[str]) -> dict[str, Path]:
    """``{name: models/<name>/train_log.csv}``, where the train stage writes each log."""
    return {name: models_dir / name / "train_log.csv" for name in names}


def read_train_logs(paths: Mapping[str, Path]) -> dict[str, pd.DataFrame]:
    """``{name: train_log.csv}`` for the logs of ``paths`` that exist (``iteration`` + one
    column per logged key; possibly no rows)."""
    return {name: pd.read_csv(path) for name, path in paths.items() if path.is_file()}


def read_selections(models_dir: Path, names: Sequence[str]) -> dict[str, dict]:
    """``{name: models/<name>/selection.json}`` (which iteration ``model.pt`` keeps, see
    :func:`cmal_lcd.models.training.selection_record`) for the models that have one."""
    paths = {name: models_dir / name / "selection.json" for name in names}
    return {name: json.loads(path.read_text()) for name, path in paths.items() if path.is_file()}


def read_figure_dataset(dataset_dir: Path) -> tuple[Any | None, str | None]:
    """The dataset for the weather figures: ``(Dataset, None)``, or ``(None, why not)`` when
    a file of :data:`DATASET_FILES` is missing or the dataset store cannot be imported.

    The images are memory-mapped (:func:`cmal_lcd.data.store.load_dataset`).
    """
    missing = [name for name in DATASET_FILES if not (dataset_dir / name).is_file()]
    if missing:
        return None, f"`{dataset_dir}` has no {', '.join(missing)}."
    try:
        from cmal_lcd.data.store import load_dataset
    except ImportError as err:
        return None, f"the plotting code is not available ({err})."
    return load_dataset(dataset_dir), None


def compute_reconstructions(models_dir: Path, dataset: Any, *, dataset_missing: str | None,
                            heldout_fraction: float, seed: int, threads: int = 1
                            ) -> tuple[dict[str, np.ndarray] | None, str | None]:
    """Fig. 11's arrays: ``(arrays, None)``, or ``(None, why not)`` without a trained CMAL
    model, a dataset (``dataset_missing`` is then the reason) or two conditions.

    ``arrays``: :func:`cmal_lcd.reports.reconstructions.reconstruction_examples` of
    ``models_dir`` (``a``, ``recon_a``, ``translated_b``, ``b``: ``uint8 (n, S, S, 3)``;
    ``condition_a``, ``condition_b``: ``str (n,)``; ``frame_a``, ``frame_b``: ``int64 (n,)``).
    """
    if dataset is None:
        return None, fig11.model_missing(models_dir) or dataset_missing
    missing = fig11.examples_missing(models_dir, dataset.conditions)
    if missing is not None:
        return None, missing
    return fig11.reconstruction_examples(models_dir, dataset, heldout_fraction=heldout_fraction,
                                         seed=seed, threads=threads), None


@dataclass(frozen=True)
class OptionalFiles:
    """The inputs a run may lack; the section that needs one says why it is missing.

    Attributes
    ----------
    invariance : dict or None
        ``invariance.json``: ``{route: {method: {...}}}``.
    invariance_path : Path
    train_logs : dict
        ``{model name: train_log.csv}`` of the models that have a log.
    train_log_paths : dict
        ``{model name: path}`` for every model of the config, in its order.
    selections : dict
        ``{model name: selection.json}`` of the models that have one.
    reconstructions : dict or None
        The Fig. 11 arrays (:func:`compute_reconstructions`); ``reconstructions_missing`` says
        why they are None.
    reconstructions_missing : str or None
    dataset : Dataset or None
        The dataset folder for Fig. 1 and the map; ``dataset_missing`` says why it is None.
    dataset_missing : str or None
    matrices : iterator of PairMatrices
        Fig. 6's matrices, one pair read per step (iterate once).
    """

    invariance: dict | None
    invariance_path: Path
    train_logs: dict[str, pd.DataFrame]
    train_log_paths: dict[str, Path]
    selections: dict[str, dict]
    reconstructions: dict[str, np.ndarray] | None
    reconstructions_missing: str | None
    dataset: Any
    dataset_missing: str | None
    matrices: Iterator[PairMatrices]


def read_optional(*, evaluation_dir: Path, models_dir: Path, dataset_dir: Path,
                  pairs: Sequence[tuple[str, str]], methods: Sequence[str],
                  model_names: Sequence[str], heldout_fraction: float,
                  seed: int, threads: int = 1) -> OptionalFiles:
    """The optional inputs of the report (``matrices`` read later, when iterated).

    ``heldout_fraction`` (``models.cmal.heldout_fraction``) and ``seed``: the frames training
    held out, which Fig. 11 shows (:func:`compute_reconstructions`); ``threads``
    (``runtime.threads``): torch threads of its forward passes.
    """
    invariance_path = evaluation_dir / "invariance.json"
    log_paths = train_log_paths(models_dir, model_names)
    dataset, dataset_missing = read_figure_dataset(dataset_dir)
    recon, recon_missing = compute_reconstructions(models_dir, dataset,
                                                   dataset_missing=dataset_missing,
                                                   heldout_fraction=heldout_fraction, seed=seed,
                                                   threads=threads)
    return OptionalFiles(
        invariance=read_invariance(invariance_path), invariance_path=invariance_path,
        train_logs=read_train_logs(log_paths), train_log_paths=log_paths,
        selections=read_selections(models_dir, model_names),
        reconstructions=recon, reconstructions_missing=recon_missing,
        dataset=dataset, dataset_missing=dataset_missing,
        matrices=iter_pair_matrices(evaluation_dir, pairs=pairs, methods=methods))
