"""Stage ``calibrate_world``: how hard is the weather world for SAD + SeqSLAM?

``python -m cmal_lcd.stages.calibrate_world [--params params.yaml] [--dataset data/dataset]
[--out reports/world]`` writes ``difficulty.json`` and ``difficulty.md``: for every route and
ordered condition pair, single-frame SAD recall@1 and SeqSLAM recall at 100% precision across
weathers, and a same-weather baseline over the same geometry (see
:mod:`cmal_lcd.evaluation.world_calibration`). The baseline drives are rendered here from the
dataset's own config and seed; they never enter the dataset.

Old or new, never a mix: both files are written into ``.<out>.new-<id>`` beside ``--out``,
which replaces ``--out`` once complete (:func:`cmal_lcd.io.staged_folder`); until then the
previous folder stays (the out is ``persist: true``, so DVC no longer deletes it first).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from cmal_lcd.data.store import Dataset, load_dataset
from cmal_lcd.evaluation.world_calibration import (SF_KEY, SadMatching, difficulty_markdown,
                                             pair_difficulty, sad_codes, summarise)
from cmal_lcd.data.world.config import KIND, DataConfig, drive_name, pair_name
from cmal_lcd.data.world.dataset import make_world_renderer, plan_drive, render_group
from cmal_lcd.data.world.threads import set_render_threads
from cmal_lcd.io import atomic_write_json, atomic_write_text, staged_folder
from cmal_lcd.stages import parse_stage_args, run, stage_config, stage_parser
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.calibrate_world")

#: Read, but not inputs: the renderer's numba threads (each pixel is computed by one thread,
#: so the outputs do not depend on the count; tests/test_dvc_params.py).
NOT_INPUTS = {"runtime.render_threads": "thread count only (per-frame work)"}


def difficulty_table(dataset: Dataset, matching: SadMatching) -> dict:
    """``{route: {"a-b": {"cross": metrics, "same": metrics}}}`` for every ordered pair."""
    config = DataConfig.from_config(dataset.meta["config"])
    seed = int(dataset.meta["seed"])
    world, renderer = make_world_renderer(config, seed=seed)
    table: dict = {}
    for route in dataset.meta["routes"]:
        codes, xy = {}, {}
        for condition in dataset.conditions:
            images, frames = dataset.drive(drive_name(route, condition))
            codes[condition] = sad_codes(np.asarray(images), matching)
            xy[condition] = frames[["x", "y"]].to_numpy(np.float64)
        table[route] = {}
        for ref, query in itertools.permutations(dataset.conditions, 2):
            cross = pair_difficulty(codes[ref], xy[ref], codes[query], xy[query],
                                    matching=matching)
            # same geometry, same weather: the reference condition over the query's window
            windows = {**config.test.windows, ref: config.test.windows[query]}
            repeat_config = dataclasses.replace(
                config, test=dataclasses.replace(config.test, windows=windows))
            group = plan_drive(repeat_config, world, route, ref, seed=seed,
                               repeat=f"repeat_over_{query}")
            images = render_group(renderer, group, supersample=config.supersample,
                                  sky_distance_m=config.camera.max_distance_m)
            same = pair_difficulty(codes[ref], xy[ref], sad_codes(images, matching),
                                   np.c_[group.poses.x, group.poses.y], matching=matching)
            table[route][pair_name(ref, query)] = {"cross": cross, "same": same}
            logger.info("%s %s: cross sf R@1 %.3f, same %.3f", route, pair_name(ref, query),
                        cross[SF_KEY], same[SF_KEY])
    return table


def main(cfg: DictConfig, *, dataset_dir: str | Path, out_dir: str | Path) -> Path:
    """Measure the dataset's difficulty; write ``difficulty.json`` and ``difficulty.md``."""
    set_render_threads(cfg)
    dataset = load_dataset(dataset_dir)
    out_dir = Path(out_dir)
    if dataset.meta.get("kind") != KIND:
        reason = (f"the dataset is of kind {dataset.meta.get('kind')!r}, not {KIND!r}: there is "
                  f"no world to calibrate")
        with staged_folder(out_dir, recover=True) as staging:
            atomic_write_json(staging / "difficulty.json", {"skipped": reason})
            atomic_write_text(staging / "difficulty.md",
                              f"# Difficulty of the weather world\n\nSkipped: {reason}.\n")
        return out_dir
    matching = SadMatching.from_config(cfg.matching)
    table = difficulty_table(dataset, matching)
    summary = summarise(table)
    with staged_folder(out_dir, recover=True) as staging:
        atomic_write_json(staging / "difficulty.json", {
            "routes": table, "summary": summary,
            "matching": {"seqslam": matching.params.as_dict(), "d_thresh": matching.d_thresh,
                         "pose_tolerance": matching.pose_tolerance, "sad": matching.sad}})
        atomic_write_text(staging / "difficulty.md", difficulty_markdown(table, summary))
    if not summary["ok"]:
        logger.warning("the world is outside the useful difficulty range: %s", summary)
    return out_dir


def cli(argv: list[str] | None = None) -> None:
    parser = stage_parser(__doc__)
    parser.add_argument("--dataset", default=REPO.dataset, type=Path)
    parser.add_argument("--out", default=REPO.world, type=Path)
    args = parse_stage_args(parser, argv)
    cfg = stage_config(args, __name__)
    main(cfg, dataset_dir=args.dataset, out_dir=args.out)


if __name__ == "__main__":
    run(cli)
