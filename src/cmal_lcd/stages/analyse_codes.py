"""Stage ``analyse_codes``: is a method's code condition-invariant? (issue: evidence for CMAL)

For every test route and every learned method (and the untrained control), compare the mean
squared distance between codes of the same place under different weather with the mean distance
between different places under the same weather (``cmal_lcd.evaluation.invariance``), and
measure the CMAL condition classifier's accuracy on the test frames. Writes
``data/evaluation/invariance.json``: ``{route: {method: {statistic: value}}}``.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig

from cmal_lcd.config import load_params
from cmal_lcd.data.store import load_dataset
from cmal_lcd.evaluation.invariance import code_invariance
from cmal_lcd.features.store import load_features
from cmal_lcd.io import atomic_write_json

logger = logging.getLogger(__name__)

#: Methods whose codes are analysed (those present in ``cfg.methods``).
ANALYSED = ("sad", "dnn", "bigan", "cmal", "cmal_untrained")


def place_ids(frames: pd.DataFrame, *, bin_metres: float) -> np.ndarray:
    """Place id of every test frame: its route and its position along the route.

    Frames within the same ``bin_metres`` of arc length ``s`` on the same route are one place;
    without arc lengths (real data matched by index), a frame's index within its drive is its
    place.

    Returns
    -------
    ndarray, int64 (N,)
    """
    route_codes = pd.factorize(frames["route"])[0].astype(np.int64)
    if frames["s"].notna().all():
        position = np.floor(frames["s"].to_numpy(float) / bin_metres).astype(np.int64)
    else:
        position = frames.groupby("drive").cumcount().to_numpy(np.int64)
    return route_codes * 10_000_000 + position


def main(cfg: DictConfig, *, dataset_dir: Path, features_dir: Path, models_dir: Path,
         out_path: Path, bin_metres: float = 2.0) -> Path:
    """Write the invariance statistics of every analysed method per route to ``out_path``."""
    dataset = load_dataset(dataset_dir)
    images, frames = dataset.test()
    frames = frames.reset_index(drop=True)
    condition = np.array([dataset.condition_index(c) for c in frames["condition"]], np.int64)
    place = place_ids(frames, bin_metres=bin_metres)
    methods = [m for m in cfg.methods if m in ANALYSED]
    codes = {m: load_features(features_dir / m, expected_rows=len(frames)) for m in methods}

    accuracy = None
    if (models_dir / "cmal").exists():
        from cmal_lcd.models import load_trained
        from cmal_lcd.models.cmal import condition_accuracy

        model, _ = load_trained(models_dir / "cmal")
        accuracy_by_route = {}
        for route in frames["route"].unique():
            rows = frames.index[frames["route"] == route].to_numpy()
            accuracy_by_route[route] = float(condition_accuracy(model, images[rows],
                                                                condition[rows]))
        accuracy = accuracy_by_route

    result: dict = {}
    for route in frames["route"].unique():
        rows = frames.index[frames["route"] == route].to_numpy()
        for method in methods:
            values, info = codes[method]
            feats = values[rows].astype(np.float64)
            # Squared Euclidean for every method; the ratio of the two means is scale-free,
            # so methods with codes of different magnitudes compare.
            stats = code_invariance(feats, place[rows], condition[rows])
            stats["label"] = info["label"]
            if method == "cmal" and accuracy is not None:
                stats["classifier_accuracy"] = accuracy[route]
            result.setdefault(route, {})[method] = stats
            logger.info("%s %s: same place / other weather %.4g, other place / same weather "
                        "%.4g", route, method, stats["same_place_cross_condition"],
                        stats["different_place_same_condition"])
    atomic_write_json(out_path, result)
    return out_path


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--dataset", default="data/dataset", type=Path)
    parser.add_argument("--features", default="data/features", type=Path)
    parser.add_argument("--models", default="models", type=Path)
    parser.add_argument("--out", default="data/evaluation/invariance.json", type=Path)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(load_params(args.params), dataset_dir=args.dataset, features_dir=args.features,
         models_dir=args.models, out_path=args.out)


if __name__ == "__main__":
    cli()
