"""Stage ``dataset``: render the weather world's training frames and test drives.

``python -m cmal_lcd.stages.make_dataset [--params params.yaml] [--out data/dataset]
[--manifest data/manifest.csv]`` reads the ``seed``, ``data`` and ``runtime`` nodes of the
composed config and writes ``images.npy``, ``frames.csv`` and ``dataset.json`` (see
:mod:`cmal_lcd.data.store`). A ``data.kind`` of ``folders`` (real frames) is handed to
:func:`cmal_lcd.data.folders.main_folders`.

The split manifest (:mod:`cmal_lcd.data.manifest`: every frame used for train, validation,
reference and query, with the sha256 of its pixels and, for folders, of its source file) is a
separate output beside the dataset folder, so the dataset's own files and hash are unchanged.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from cmal_lcd.data.manifest import build_manifest, data_root, write_manifest
from cmal_lcd.data.store import save_dataset
from cmal_lcd.data.world.config import KIND, DataConfig
from cmal_lcd.data.world.dataset import (dataset_meta, frame_table, make_world_renderer,
                                         plan_dataset, render_group)
from cmal_lcd.data.world.threads import set_render_threads
from cmal_lcd.stages import parse_stage_args, run, stage_config, stage_parser
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m` (how dvc.yaml runs it)
logger = logging.getLogger("cmal_lcd.stages.make_dataset")

#: Read, but not inputs: the renderer's numba threads (each pixel is computed by one thread,
#: so the outputs do not depend on the count; tests/test_dvc_params.py).
NOT_INPUTS = {"runtime.render_threads": "thread count only (per-frame work)",
              # folders: whether one training condition is refused (a method that trains CMAL
              # needs two); never what the dataset holds
              "methods": "decides only whether one training condition is refused",
              "extractors": "decides only whether one training condition is refused"}


def main(cfg: DictConfig, *, out_dir: str | Path, manifest: str | Path | None = None) -> Path:
    """Build the world, plan and render every frame, save the dataset to ``out_dir``.

    Parameters
    ----------
    cfg : DictConfig
        The composed config (``seed``, ``data``; ``runtime.render_threads`` if present).
    out_dir : str or Path
    manifest : str or Path, optional
        Also write the split manifest there (:func:`cmal_lcd.data.manifest.build_manifest`).

    Returns
    -------
    Path
        ``out_dir``.
    """
    start = time.perf_counter()
    if OmegaConf.select(cfg, "data.kind", default=KIND) == "folders":
        return _main_folders(cfg, out_dir=out_dir, manifest=manifest)
    config = DataConfig.from_config(cfg.data)
    seed = cfg.seed
    set_render_threads(cfg)
    world, renderer = make_world_renderer(config, seed=seed)
    groups = plan_dataset(config, world, seed=seed)
    total = sum(len(g) for g in groups)
    h, w = config.image_size
    images = np.empty((total, h, w, 3), np.uint8)
    row = 0
    for group in groups:
        images[row:row + len(group)] = render_group(
            renderer, group, supersample=config.supersample,
            sky_distance_m=config.camera.max_distance_m)
        row += len(group)
        logger.info("rendered %s %s (%d frames), %d/%d", group.split,
                    group.drive or group.condition, len(group), row, total)
    frames = frame_table(groups)
    meta = dataset_meta(config, world, groups, seed=seed,
                        config_dict=OmegaConf.to_container(cfg.data, resolve=True)
                        if isinstance(cfg.data, DictConfig) else dict(cfg.data))
    save_dataset(out_dir, images, frames, meta)
    if manifest is not None:
        write_manifest(manifest, build_manifest(images, frames, meta))
    logger.info("dataset: %d frames in %.1f s", total, time.perf_counter() - start)
    return Path(out_dir)


def _main_folders(cfg: DictConfig, *, out_dir: str | Path,
                  manifest: str | Path | None) -> Path:
    """``data.kind: folders``: :func:`cmal_lcd.data.folders.main_folders`, then the manifest of
    the saved frames with their source files (and the unused files of the folders read)."""
    from cmal_lcd.data.folders import main_folders
    from cmal_lcd.data.store import load_dataset
    from cmal_lcd.features import needs_two_conditions

    record: dict = {}
    main_folders(cfg, out_dir=out_dir, min_conditions=2 if needs_two_conditions(cfg) else 1,
                 record=record)
    if manifest is not None:
        dataset = load_dataset(out_dir)
        used = {Path(f).resolve() for f in record["files"]}
        unused = sorted({Path(f).resolve() for f in record["listed"]} - used)
        write_manifest(manifest, build_manifest(dataset.images, dataset.frames, dataset.meta,
                                                files=record["files"],
                                                root=data_root(*record["dirs"]),
                                                unused=unused))
    return Path(out_dir)


def cli(argv: list[str] | None = None) -> None:
    parser = stage_parser(__doc__)
    parser.add_argument("--out", default=REPO.dataset, type=Path)
    parser.add_argument("--manifest", default=None, type=Path,
                        help="split manifest, a separate output (default: manifest.csv beside "
                             f"--out, i.e. {REPO.manifest} for {REPO.dataset})")
    args = parse_stage_args(parser, argv)
    cfg = stage_config(args, __name__)
    manifest = args.manifest if args.manifest is not None else args.out.parent / "manifest.csv"
    main(cfg, out_dir=args.out, manifest=manifest)


if __name__ == "__main__":
    run(cli)
