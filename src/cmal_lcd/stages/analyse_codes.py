"""Stage ``analyse_codes``: is a method's code weather-invariant?

For every test route, every method and every cross-weather test pair, compare the difference
between codes of the same place with that between different places, both across weathers
(:func:`cmal_lcd.evaluation.invariance.cross_weather_separation`), after the normalisation of
the method's selected matching protocol (``data/protocol/<method>.json``) and, for reference,
on raw codes; and measure the trained CMAL classifier's accuracy on the test frames. Writes
``data/evaluation/invariance.json``: ``{route: {method: {statistic: mean over the route's
pairs}}}``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from cmal_lcd.data.store import load_dataset
from cmal_lcd.evaluation.invariance import cross_weather_separation
from cmal_lcd.evaluation.loop_closure import dataset_ground_truth, drive_rows, ground_truth_for_pair
from cmal_lcd.evaluation.protocol import MatchingProtocol
from cmal_lcd.evaluation.protocol_file import centring_means, load_selected_protocol
from cmal_lcd.data.codes import load_features
from cmal_lcd.io import atomic_write_json
from cmal_lcd.matching import difference_matrix
from cmal_lcd.matching.normalise import CodeNormalisation, normalise_pair
from cmal_lcd.stages import parse_stage_args, run, stage_config, stage_parser
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.analyse_codes")


STATISTICS = ("same_place", "other_place", "ratio", "single_frame_recall_at_1")


def method_separation(codes: np.ndarray, frames, pairs, *, metric: str,
                      normalisation: CodeNormalisation, train_means, d_thresh: int,
                      ground_truth: str, pose_tolerance: float) -> dict[str, dict]:
    """:func:`cross_weather_separation` of every pair, averaged per route.

    Returns
    -------
    dict
        ``{route: {statistic: mean over the route's pairs}}``.
    """
    per_route: dict[str, list[dict]] = {}
    for route, ref_drive, query_drive, _ in pairs:
        ref_rows, query_rows = drive_rows(frames, ref_drive), drive_rows(frames, query_drive)
        truth = ground_truth_for_pair(frames.iloc[ref_rows], frames.iloc[query_rows],
                                      kind=ground_truth, pose_tolerance=pose_tolerance)
        ref, query = normalise_pair(codes[ref_rows], codes[query_rows], normalisation,
                                    train_means=train_means)
        D = difference_matrix(ref, query, metric=metric)
        per_route.setdefault(route, []).append(cross_weather_separation(D, truth,
                                                                        d_thresh=d_thresh))
    return {route: {k: float(np.nanmean([s[k] for s in stats])) for k in STATISTICS}
            for route, stats in per_route.items()}


def main(cfg: DictConfig, *, dataset_dir: Path, features_dir: Path, protocol_dir: Path,
         models_dir: Path, out_path: Path) -> Path:
    """Write the invariance statistics of every method per route to ``out_path``."""
    dataset = load_dataset(dataset_dir)
    images, frames = dataset.test()
    pairs = dataset.pairs("test")
    options = dict(d_thresh=cfg.matching.d_thresh,
                   ground_truth=dataset_ground_truth(dataset.meta),
                   pose_tolerance=cfg.matching.pose_tolerance)
    accuracies: dict[str, dict | None] = {}  # per trained model
    result: dict = {}
    for method in cfg.methods:
        model = trained_model_of(method, cfg.get("extractors"))
        if model is not None and model not in accuracies:
            accuracies[model] = classifier_accuracy_by_route(dataset, images, frames,
                                                             models_dir / model)
        accuracy = accuracies.get(model) if model is not None else None
        codes, info = load_features(features_dir / method, expected_rows=len(frames))
        protocol: MatchingProtocol = load_selected_protocol(protocol_dir / f"{method}.json")
        means = centring_means(protocol, features_dir / method, len(dataset.conditions))
        selected = method_separation(codes, frames, pairs, metric=info["metric"],
                                     normalisation=protocol.normalisation, train_means=means,
                                     **options)
        raw = method_separation(codes, frames, pairs, metric=info["metric"],
                                normalisation=CodeNormalisation(), train_means=None, **options)
        for route in selected:
            stats = {**selected[route], **{f"raw_{k}": v for k, v in raw[route].items()},
                     "normalisation": protocol.normalisation.label, "label": info["label"]}
            if accuracy is not None:
                stats["classifier_accuracy"] = accuracy[route]
            result.setdefault(route, {})[method] = stats
            logger.info("%s %s (%s): same/other place %.3f (raw %.3f), single-frame r@1 %.3f",
                        route, method, stats["normalisation"], stats["ratio"],
                        stats["raw_ratio"], stats["single_frame_recall_at_1"])
    atomic_write_json(out_path, result)
    return out_path


def trained_model_of(method: str, extractors=None) -> str | None:
    """The model whose trained weights ``method``'s codes come from (``Method.trained`` of its
    ``extractors`` node, default the built-in one), or None (a method that trains nothing, a
    control, an encoder of yours)."""
    from cmal_lcd.features import method_entry, method_names

    if method not in method_names(extractors):
        return None
    entry = method_entry(method, extractors)
    return entry.model if entry.trained else None


def classifier_accuracy_by_route(dataset, images, frames, model_dir: Path) -> dict | None:
    """Accuracy of a trained model's condition classifier on each route's test frames, those of
    the drives of its test pairs (None: no model there, or a model without a classifier, one
    that is not ``conditional``)."""
    if not model_dir.exists():
        return None
    from cmal_lcd.models import load_trained

    model, _ = load_trained(model_dir)
    if not model.conditional:
        return None
    from cmal_lcd.models import condition_accuracy  # the conditional models' classifier

    condition = np.array([dataset.condition_index(c) for c in frames["condition"]], np.int64)
    # the drives of the test pairs: a loop's extra lap-2 drive would count its weather twice
    paired = frames["drive"].isin({d for p in dataset.pairs("test") for d in p[1:3]}).to_numpy()
    return {route: float(condition_accuracy(model, images[rows], condition[rows]))
            for route in frames["route"].unique()
            for rows in [np.flatnonzero((frames["route"].to_numpy() == route) & paired)]}


def cli(argv: list[str] | None = None) -> None:
    parser = stage_parser(__doc__)
    parser.add_argument("--dataset", default=REPO.dataset, type=Path)
    parser.add_argument("--features", default=REPO.features, type=Path)
    parser.add_argument("--protocol", default=REPO.protocols, type=Path)
    parser.add_argument("--models", default=REPO.models, type=Path)
    parser.add_argument("--out", default=REPO.invariance, type=Path)
    args = parse_stage_args(parser, argv)
    cfg = stage_config(args, __name__)
    main(cfg, dataset_dir=args.dataset, features_dir=args.features,
         protocol_dir=args.protocol, models_dir=args.models, out_path=args.out)


if __name__ == "__main__":
    run(cli)
