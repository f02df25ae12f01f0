"""Stage ``evaluate_loops@<method>``: loop closure within one drive on the looping routes.

For every looping traversal of the dataset (``dataset.json`` ``loops``: lap 1 then lap 2 of a
test route, the weather changing between the laps or not: :mod:`cmal_lcd.evaluation.loop_route`),
match the method's test codes within the sequence (exclusion zone ``loop_exclude_frames`` of
``dataset.json``, from ``data.test.loops.exclude_frames``) under the protocol
``select_protocol@<method>`` chose on the validation drives (never tuned on test), and write,
under ``data/evaluation_loops/<method>/``:

- ``metrics.json``: ``{route: {loop: {metric: value, lap1, lap2}}}``; for a dataset without a
  looping route (folder datasets such as ``experiment=nordland``) ``{"skipped": reason}``;
- ``loops.csv``: one row per route and loop (``route, loop, lap1, lap2``, R@100P, AUC-PR,
  AUC-ROC, R@1, single-frame R@1, ``n_revisit``); only the header when skipped.
"""

from __future__ import annotations

import logging
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from cmal_lcd.data.store import load_dataset
from cmal_lcd.evaluation.loop_route import evaluate_loop_route, loops_of
from cmal_lcd.evaluation.protocol_file import centring_means, load_selected_protocol
from cmal_lcd.data.codes import load_features
from cmal_lcd.io import atomic_write_json, atomic_write_text
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.stages import (method_paths, method_stage_parser, parse_stage_args, run,
                              stage_config, stage_item)
from cmal_lcd.paths import REPO

# named, not __name__: run as `python -m` (dvc.yaml) __name__ would be "__main__"
logger = logging.getLogger("cmal_lcd.stages.evaluate_loops")


#: Columns of ``loops.csv``.
CSV_COLUMNS = ("route", "loop", "lap1", "lap2", "recall_at_100p", "auc_pr", "auc_roc",
               "recall_at_1", "single_frame_recall_at_1", "n_revisit")
#: ``metrics.json``'s reason when the dataset has no looping route.
NO_LOOPS = "no looping route in this dataset"


def main(cfg: DictConfig, *, method: str, dataset_dir: Path, features_dir: Path,
         protocol_path: Path, out_dir: Path) -> Path:
    """Evaluate ``method`` on every looping route; see the module docstring for the outputs."""
    out_dir = Path(out_dir)
    params = SeqSLAMParams.from_config(cfg.matching)  # checked by load_params
    d_thresh, pose_tolerance = cfg.matching.d_thresh, cfg.matching.pose_tolerance
    dataset = load_dataset(dataset_dir)
    loops = loops_of(dataset.meta)
    if not loops:
        reason = (f"{NO_LOOPS} (dataset.json lists no loops; kind "
                  f"{dataset.meta.get('kind')!r})")
        logger.info("%s: %s", method, reason)
        atomic_write_json(out_dir / "metrics.json", {"skipped": reason})
        atomic_write_text(out_dir / "loops.csv", ",".join(CSV_COLUMNS) + "\n")
        return out_dir
    exclude_frames = int(dataset.meta["loop_exclude_frames"])
    protocol = load_selected_protocol(protocol_path)
    _, frames = dataset.test()
    codes, info = load_features(features_dir, expected_rows=len(frames))
    means = centring_means(protocol, features_dir, len(dataset.conditions))

    metrics: dict = {}
    for route, lap1, lap2, name in loops:
        try:
            evaluation = evaluate_loop_route(
                codes, frames, lap1, lap2, metric=info["metric"], params=params,
                exclude_frames=exclude_frames, pose_tolerance=pose_tolerance,
                d_thresh=d_thresh, protocol=protocol, train_means=means)
        except ValueError as err:
            raise ValueError(f"{features_dir}: {method} {route} loop {name}: {err}") from err
        metrics.setdefault(route, {})[name] = {**evaluation.metrics, "lap1": lap1, "lap2": lap2}
        logger.info("%s %s loop %s (%s): R@100P %.3f AUC-PR %.3f", method, route, name,
                    protocol.label, evaluation.metrics["recall_at_100p"],
                    evaluation.metrics["auc_pr"])
    table = pd.DataFrame([{"route": route, "loop": name, **values}
                          for route, loops_ in metrics.items()
                          for name, values in loops_.items()])[list(CSV_COLUMNS)]
    atomic_write_text(out_dir / "loops.csv", table.to_csv(index=False, lineterminator="\n"))
    atomic_write_json(out_dir / "metrics.json", metrics)
    return out_dir


def cli(argv: list[str] | None = None) -> None:
    args = parse_stage_args(method_stage_parser(__doc__, out_root=REPO.loops), argv)
    args.method = stage_item(args.method, stage="evaluate_loops", option="--method")
    main(stage_config(args, __name__, args.method), **method_paths(args))


if __name__ == "__main__":
    run(cli)
