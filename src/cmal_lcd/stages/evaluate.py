"""Stage ``evaluate@<method>``: SeqSLAM matching and loop closure metrics for one method.

For every test pair of the dataset (route, reference drive, query drive) and both variants
(``selected``: the protocol ``select_protocol@<method>`` chose on the validation drives;
``paper``: raw codes with eq. 14 and Table I's window, the paper's setting, an ablation), match
the method's codes and write, under ``data/evaluation/<method>/``:

- ``metrics.json``: ``{route: {pair: {variant: {metric: value}}}}``; with
  ``matching.d_thresh_strict`` set, also variant ``strict``: the ``selected`` matches scored at
  that tolerance (``d_thresh`` says which)
- ``pr/<route>/<pair>.csv``: the exact PR curve of the selected variant (``recall, precision,
  threshold``)
- ``matrices/<route>/<pair>.npz``: ``D``, ``D_hat``, ``match``, ``truth`` (selected variant;
  with a ground-truth file, ``truth`` is the right row nearest the match)
- ``matches/<route>/<pair>.csv`` and ``candidates/<route>/<pair>.npz``: the exports of
  ``cmal-lcd match`` (docs/ground_truth.md) for the selected variant, frames named by their
  dataset ``frame`` id
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig

from cmal_lcd.data.store import load_dataset
from cmal_lcd.evaluation.export import candidate_arrays, matches_csv, true_reference
from cmal_lcd.evaluation.loop_closure import (STRICT, VARIANTS, dataset_ground_truth,
                                              dataset_sequences, drive_rows,
                                              evaluate_drive_pairs, match_metrics)
from cmal_lcd.evaluation.protocol import paper_protocol
from cmal_lcd.evaluation.protocol_file import centring_means, load_selected_protocol
from cmal_lcd.data.codes import load_features
from cmal_lcd.io import atomic_save_npz, atomic_write_json, atomic_write_text
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.names import output_path
from cmal_lcd.stages import (method_paths, method_stage_parser, parse_stage_args, run,
                              stage_config, stage_item)
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.evaluate")


def pr_curve_table(precision: np.ndarray, recall: np.ndarray,
                   thresholds: np.ndarray) -> pd.DataFrame:
    """PR curve points as a table for DVC plots: ``recall, precision, threshold``."""
    n = min(len(precision), len(recall), len(thresholds))
    return pd.DataFrame({"recall": recall[:n], "precision": precision[:n],
                         "threshold": thresholds[:n]})


def main(cfg: DictConfig, *, method: str, dataset_dir: Path, features_dir: Path,
         protocol_path: Path, out_dir: Path) -> Path:
    """Evaluate ``method`` on every test pair; see the module docstring for the outputs."""
    params = SeqSLAMParams.from_config(cfg.matching)  # checked by load_params
    matching = cfg.matching
    d_thresh, pose_tolerance, strict = (matching.d_thresh, matching.pose_tolerance,
                                        matching.d_thresh_strict)
    protocols = {"selected": load_selected_protocol(protocol_path),
                 "paper": paper_protocol(params)}
    dataset = load_dataset(dataset_dir)
    _, frames = dataset.test()
    codes, info = load_features(features_dir, expected_rows=len(frames))
    means = centring_means(protocols["selected"], features_dir, len(dataset.conditions))

    metrics: dict = {}
    for variant in VARIANTS:
        try:
            results = list(evaluate_drive_pairs(
                codes, frames, dataset.pairs("test"), metric=info["metric"], params=params,
                d_thresh=d_thresh, ground_truth=dataset_ground_truth(dataset.meta),
                pose_tolerance=pose_tolerance, protocol=protocols[variant], train_means=means,
                keep_matrices=variant == "selected",
                sequences=dataset_sequences(dataset.meta)))
        except ValueError as err:
            raise ValueError(f"{features_dir}: {method} ({variant}): {err}") from err
        for route, pair, evaluation in results:
            metrics.setdefault(route, {}).setdefault(pair, {})[variant] = evaluation.metrics
            logger.info("%s %s %s %s (%s): R@100P %.3f AUC-PR %.3f", method, route, pair,
                        variant, protocols[variant].label, evaluation.metrics["recall_at_100p"],
                        evaluation.metrics["auc_pr"])
            if variant != "selected":
                continue
            if strict is not None:
                metrics[route][pair][STRICT] = {
                    **match_metrics(evaluation.result, evaluation.truth, d_thresh=strict),
                    "d_thresh": strict}
            table = pr_curve_table(evaluation.precision, evaluation.recall,
                                   evaluation.thresholds)
            atomic_write_text(output_path(out_dir, "pr", route, f"{pair}.csv"),
                              table.to_csv(index=False))
            result = evaluation.result
            atomic_save_npz(output_path(out_dir, "matrices", route, f"{pair}.npz"),
                            D=result.D.astype(np.float32), D_hat=result.D_hat.astype(np.float32),
                            match=result.match, truth=true_reference(evaluation))
            write_exports(out_dir, route, pair, evaluation, frames=frames,
                          drives=_pair_drives(dataset, route, pair), d_thresh=d_thresh)
    atomic_write_json(out_dir / "metrics.json", metrics)
    return out_dir


def _pair_drives(dataset, route: str, pair: str) -> tuple[str, str]:
    """``(reference drive, query drive)`` of the test pair ``pair`` of ``route``."""
    for pair_route, reference, query, name in dataset.pairs("test"):
        if (pair_route, name) == (route, pair):
            return reference, query
    raise ValueError(f"pair {pair} of {route}: not a test pair of the dataset")


def write_exports(out_dir: Path, route: str, pair: str, evaluation, *, frames: pd.DataFrame,
                  drives: tuple[str, str], d_thresh: int) -> None:
    """``matches/<route>/<pair>.csv`` and ``candidates/<route>/<pair>.npz``
    (:mod:`cmal_lcd.evaluation.export`); frames are named by their dataset ``frame`` id."""
    reference, query = (frames["frame"].to_numpy()[drive_rows(frames, drive)].astype(str)
                        .tolist() for drive in drives)
    names = {"reference_names": reference, "query_names": query}
    atomic_write_text(output_path(out_dir, "matches", route, f"{pair}.csv"),
                      matches_csv(evaluation, d_thresh=d_thresh, **names))
    atomic_save_npz(output_path(out_dir, "candidates", route, f"{pair}.npz"),
                    **candidate_arrays(evaluation, **names))


def cli(argv: list[str] | None = None) -> None:
    args = parse_stage_args(method_stage_parser(__doc__, out_root=REPO.evaluation), argv)
    args.method = stage_item(args.method, stage="evaluate", option="--method")
    main(stage_config(args, __name__, args.method), **method_paths(args))


if __name__ == "__main__":
    run(cli)
