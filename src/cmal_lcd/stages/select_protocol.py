"""Stage ``select_protocol@<method>``: choose a method's matching protocol on validation drives.

Every candidate of ``matching.protocol`` (centring none/reference/condition x L2 off/on x
enhancement off or eq. 14 with each window) is scored on the validation pairs (the world's
validation route, or a real dataset's validation index range) with the Table I sequence search;
the best mean ``matching.protocol.criterion`` wins (ties: mean AUC-PR). Test frames are never
read. Writes ``data/protocol/<method>.json``::

    {"method", "selected": {centre, l2, enhance, r_window, label}, "paper": {... the paper's
     protocol}, "criterion",
     "validation_pairs", "n_train_frames", "candidates": [{..., mean_recall_at_100p,
     mean_auc_pr, pairs: [...]}], "fallback": null | reason}

A dataset without validation frames falls back to the paper's protocol and says so in
``fallback`` (the report prints it).

Usage::

    python -m cmal_lcd.stages.select_protocol --method cmal [--params params.yaml] \\
        [--dataset data/dataset] [--features data/features/cmal] [--out data/protocol/cmal.json]
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping

from cmal_lcd.data.store import load_dataset
from cmal_lcd.evaluation.loop_closure import (dataset_ground_truth, dataset_sequences,
                                              evaluate_drive_pairs)
from cmal_lcd.evaluation.protocol import candidate_protocols, paper_protocol, select_protocol
from cmal_lcd.data.codes import (load_centring_means, load_features, load_training_codes,
                                     load_validation_codes)
from cmal_lcd.io import atomic_write_json
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.stages import parse_stage_args, run, stage_config, stage_item, stage_parser
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.select_protocol")


def main(cfg: Mapping[str, Any], *, method: str, dataset_dir: Path, features_dir: Path,
         out_path: Path) -> Path:
    """Choose ``method``'s protocol on the validation pairs; write ``out_path`` (JSON)."""
    matching = cfg["matching"]
    settings = matching["protocol"]  # its keys, types and values checked by the schema
    params = SeqSLAMParams.from_config(matching)
    dataset = load_dataset(dataset_dir)
    _, val_frames = dataset.validation()
    pairs = dataset.pairs("val")
    _, info = load_features(features_dir)
    record: dict[str, Any] = {"method": method, "criterion": settings["criterion"],
                              "validation_pairs": pairs, "fallback": None,
                              "paper": paper_protocol(params).as_dict()}
    if len(val_frames) == 0 or not pairs:
        chosen = paper_protocol(params)
        record.update(selected=chosen.as_dict(), candidates=[], n_train_frames=0,
                      fallback="the dataset has no validation drives")
        logger.warning("%s: %s", method, record["fallback"])
        atomic_write_json(out_path, record)
        return out_path
    val_codes = load_validation_codes(features_dir, expected_rows=len(val_frames))
    n_train = len(load_training_codes(features_dir)[0])
    centres = list(settings["centre"])
    if n_train == 0 and "condition" in centres:
        logger.warning("%s: no training codes; centre=condition is not tried", method)
        centres.remove("condition")
    means = (load_centring_means(features_dir, len(dataset.conditions))
             if "condition" in centres else None)
    candidates = candidate_protocols(params, centres=centres, l2=settings["l2"],
                                     enhance_windows=settings["enhance_windows"])

    def evaluate(protocol):
        return [e.metrics for _, _, e in evaluate_drive_pairs(
            val_codes, val_frames, pairs, metric=info["metric"], params=params,
            d_thresh=matching["d_thresh"],
            ground_truth=dataset_ground_truth(dataset.meta),
            pose_tolerance=matching["pose_tolerance"], protocol=protocol,
            train_means=means, sequences=dataset_sequences(dataset.meta))]

    chosen, table = select_protocol(candidates, evaluate, criterion=settings["criterion"])
    best = next(row for row in table if row["label"] == chosen.label)
    logger.info("%s: selected %s (validation mean R@100P %.3f, AUC-PR %.3f) among %d candidates",
                method, chosen.label, best["mean_recall_at_100p"], best["mean_auc_pr"],
                len(table))
    record.update(selected=chosen.as_dict(), candidates=table, n_train_frames=n_train)
    atomic_write_json(out_path, record)
    return out_path


def cli(argv: list[str] | None = None) -> Path:
    parser = stage_parser(__doc__)
    parser.add_argument("--method", default=None,
                        help="default: the item of the DVC stage running it ($DVC_STAGE)")
    parser.add_argument("--dataset", default=REPO.dataset, type=Path)
    parser.add_argument("--features", default=None, type=Path,
                        help=f"default: {REPO.features}/<method>")
    parser.add_argument("--out", default=None, type=Path,
                        help=f"default: {REPO.protocols}/<method>.json")
    args = parse_stage_args(parser, argv)
    args.method = stage_item(args.method, stage="select_protocol", option="--method")
    cfg = stage_config(args, __name__, args.method)
    return main(cfg, method=args.method, dataset_dir=args.dataset,
                features_dir=args.features or args.paths.method_features(args.method),
                out_path=args.out or args.paths.protocol(args.method))


if __name__ == "__main__":
    run(cli)
