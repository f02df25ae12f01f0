"""Figures of the weather world: Fig. 1 (the same places under every condition) and a map.

Each function writes one file, PNG or PDF by the suffix of ``path`` (the report stage calls it
once per format); PDFs carry no creation date and PNGs no software tag, so the same dataset
gives the same bytes.
"""

from __future__ import annotations

import functools
import json
import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from cmal_lcd.data.store import Dataset  # noqa: E402
from cmal_lcd.io import atomic_path  # noqa: E402

logger = logging.getLogger(__name__)

_METADATA = {".png": {"Software": None}, ".pdf": {"CreationDate": None}}
_ROUTE_COLOURS = ("#d62728", "#1f77b4", "#9467bd", "#ff7f0e", "#8c564b")


def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    if path.suffix not in _METADATA:
        raise ValueError(f"path: expected a .png or .pdf file, got {path}")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix[1:], metadata=_METADATA[path.suffix], dpi=150)
    logger.info("wrote %s", path)
    return path


def sample_places(dataset: Dataset, *, route: str, n_places: int = 4) -> list[float]:
    """Arc lengths of ``n_places`` places that every drive of ``route`` passes.

    Evenly spaced inside the stretch common to all of the route's drives.

    Returns
    -------
    list of float
        Arc lengths, metres.
    """
    test = dataset.frames[(dataset.frames["split"] == "test") & (dataset.frames["route"] == route)]
    if test.empty:
        raise ValueError(f"route: no test frames of route {route!r}")
    starts = test.groupby("drive")["s"].min()
    ends = test.groupby("drive")["s"].max()
    lo, hi = float(starts.max()), float(ends.min())
    if hi <= lo:
        raise ValueError(f"route: the drives of {route!r} share no stretch")
    return list(lo + (hi - lo) * (np.arange(n_places) + 0.5) / n_places)


def pair_samples(dataset: Dataset, *, n_places: int = 4) -> tuple[list[str], np.ndarray,
                                                                   list[str]]:
    """For frames without arc lengths (folders): the first test pair's drives and, per row,
    the frame of each that shows the same place: ``n_places`` query frames evenly spaced among
    those with a true place, and the reference frame the ground truth gives (the nearest pose
    for pose truth; of a ground-truth file's right rows, the one nearest the query's index).

    Returns
    -------
    drives : list of str
        ``[reference drive, query drive]``.
    rows : ndarray, int64 (n_places, 2)
        Frame index within each drive.
    labels : list of str
        Row labels (``query frame q``).
    """
    from cmal_lcd.data.ground_truth import ReferenceSets
    from cmal_lcd.evaluation.loop_closure import dataset_ground_truth, ground_truth_for_pair

    route, reference, query, _ = dataset.pairs("test")[0]
    ref_frames, query_frames = dataset.drive(reference)[1], dataset.drive(query)[1]
    truth = ground_truth_for_pair(ref_frames, query_frames,
                                  kind=dataset_ground_truth(dataset.meta),
                                  pose_tolerance=float("inf"))
    if isinstance(truth, ReferenceSets):  # the right row nearest the query's own index
        truth = truth.nearest_right(np.arange(truth.n_query))
    placed = np.flatnonzero(np.asarray(truth) >= 0)
    if placed.size == 0:
        raise ValueError(f"route: no query frame of {query!r} has a true place")
    chosen = placed[((np.arange(n_places) + 0.5) * placed.size / n_places).astype(int)]
    return ([reference, query], np.stack([np.asarray(truth)[chosen], chosen], axis=1),
            [f"query frame {q}" for q in chosen])


def weather_samples_figure(dataset: Dataset, *, route: str | None = None,
                           n_places: int = 4) -> Figure:
    """Rows: places along ``route``; columns: conditions (each frame nearest the place). For
    frames without arc lengths (folders), the first test pair's frames that the ground truth
    pairs (:func:`pair_samples`)."""
    route = route or dataset.meta["routes"][0]
    test = dataset.frames[dataset.frames["split"] == "test"]
    if test["s"].isna().all():
        return _pair_samples_figure(dataset, n_places=n_places)
    places = sample_places(dataset, route=route, n_places=n_places)
    conditions = dataset.conditions
    h, w = dataset.images.shape[1:3]
    fig = Figure(figsize=(1.6 * len(conditions) + 0.4, 1.6 * n_places * h / w + 0.5))
    axes = fig.subplots(n_places, len(conditions), squeeze=False)
    fig.subplots_adjust(left=0.08, right=0.99, top=0.9, bottom=0.01, wspace=0.04, hspace=0.04)
    for j, condition in enumerate(conditions):
        images, frames = dataset.drive(f"{route}/{condition}")
        s = frames["s"].to_numpy()
        for i, place in enumerate(places):
            ax = axes[i, j]
            ax.imshow(np.asarray(images[int(np.argmin(np.abs(s - place)))]),
                      interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(condition, fontsize=9)
            if j == 0:
                ax.set_ylabel(f"{place:.0f} m", fontsize=8)
    fig.suptitle(f"The same places of {route} under each condition", fontsize=10)
    return fig


def _pair_samples_figure(dataset: Dataset, *, n_places: int) -> Figure:
    """Fig. 1 of a dataset without arc lengths: :func:`pair_samples` as an image grid."""
    drives, rows, labels = pair_samples(dataset, n_places=n_places)
    h, w = dataset.images.shape[1:3]
    # fixed margins in inches: row labels written across on the left, two title lines and the
    # column titles on top, whatever the frames' aspect
    label_in, title_in, panel_w = 1.2, 0.85, 1.8
    height = panel_w * len(rows) * h / w + 0.05 * len(rows) + title_in + 0.1
    width = panel_w * len(drives) + 0.05 * len(drives) + label_in + 0.1
    fig = Figure(figsize=(width, height))
    axes = fig.subplots(len(rows), len(drives), squeeze=False)
    fig.subplots_adjust(left=label_in / width, right=1 - 0.1 / width, top=1 - title_in / height,
                        bottom=0.1 / height, wspace=0.04, hspace=0.06)
    for j, drive in enumerate(drives):
        images, _ = dataset.drive(drive)
        for i, frame in enumerate(rows[:, j]):
            ax = axes[i, j]
            ax.imshow(np.asarray(images[int(frame)]), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(f"{drive.split('/', 1)[-1]} ({'reference' if j == 0 else 'query'})",
                             fontsize=9)
            if j == 0:
                ax.set_ylabel(f"{labels[i]}\nreference frame {frame}", fontsize=7, rotation=0,
                              ha="right", va="center")
    fig.suptitle("The same places in both drives\n(paired by the ground truth)", fontsize=9,
                 y=1 - 0.08 / height, va="top")
    return fig


def plot_weather_samples(dataset: Dataset, path: str | Path) -> Path:
    """Write Fig. 1 (the same places under every condition) to ``path`` (.png or .pdf)."""
    return _save(weather_samples_figure(dataset), path)


@functools.lru_cache(maxsize=2)
def _world_of(config_json: str, seed: int):
    from cmal_lcd.data.world.config import DataConfig
    from cmal_lcd.data.world.world import build_world

    return build_world(DataConfig.from_config(json.loads(config_json)), seed=seed)


def hillshade(height: np.ndarray, *, cell_m: float, azimuth_deg: float = 315.0,
              altitude_deg: float = 45.0) -> np.ndarray:
    """Lambertian shading of a heightmap lit from the north-west, float (n, m) in [0, 1]."""
    gy, gx = np.gradient(height.astype(np.float64), cell_m)
    az, alt = np.deg2rad(azimuth_deg), np.deg2rad(altitude_deg)
    light = np.array([np.cos(alt) * np.cos(az), np.cos(alt) * np.sin(az), np.sin(alt)])
    norm = np.sqrt(gx ** 2 + gy ** 2 + 1.0)
    return np.clip((-gx * light[0] - gy * light[1] + light[2]) / norm, 0.0, 1.0)


def _shaded_terrain(world, *, max_side: int) -> np.ndarray:
    """The world's albedo, hill-shaded, with buildings in red: float (n, n, 3) in [0, 1],
    ``n <= max_side`` (every k-th cell)."""
    from cmal_lcd.data.world import materials as M

    step = max(1, world.n_cells // max_side)
    height = world.height[::step, ::step]
    shade = hillshade(height, cell_m=world.cell_m * step)
    rgb = world.albedo[::step, ::step].astype(np.float64) / 255.0
    rgb = np.clip(rgb / max(rgb.mean(), 1e-6) * 0.45, 0, 1) * (0.45 + 0.55 * shade[..., None])
    mat = world.material[::step, ::step]
    rgb[mat == M.BUILDING] = (0.85, 0.35, 0.25)
    return rgb


def _draw_trees_regions_and_training(ax, world, dataset: Dataset) -> None:
    """Trees, the training and test regions, the training roads and the training frames."""
    from cmal_lcd.data.world import materials as M

    if len(world.sprites):
        trees = world.sprites[world.sprites[:, 5] <= M.BROADLEAF]
        ax.scatter(trees[:, 0], trees[:, 1], s=1.2, c="#06300a", linewidths=0, alpha=0.8)
    for which, colour in (("train", "white"), ("test", "gold")):
        x0, x1, y0, y1 = dataset.meta["regions"][which]
        ax.add_patch(matplotlib.patches.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False,
                                                  edgecolor=colour, linewidth=1.2,
                                                  linestyle="--"))
        ax.text(x0 + 5, y1 + 8, f"{which} region", color=colour, fontsize=8)
    for name in world.train_roads:
        road = world.roads[name]
        ax.plot(road.points[:, 0], road.points[:, 1], color="white", linewidth=0.8)
    train = dataset.frames[dataset.frames["split"] == "train"]
    ax.scatter(train["x"], train["y"], s=0.2, c="white", linewidths=0, alpha=0.5)


def _draw_routes(ax, dataset: Dataset) -> None:
    """The test routes (a colour each) and the validation routes (dotted), labelled."""
    test = dataset.frames[dataset.frames["split"] == "test"]
    for k, route in enumerate(dataset.meta["routes"]):
        rows = test[test["route"] == route]
        colour = _ROUTE_COLOURS[k % len(_ROUTE_COLOURS)]
        for _, drive in rows.groupby("drive", sort=False):
            ax.plot(drive["x"], drive["y"], color=colour, linewidth=1.0)
        start = rows.loc[rows["s"].idxmin()]
        ax.annotate(route, (start["x"], start["y"]), xytext=(6, -12), textcoords="offset points",
                    color=colour, fontsize=8, fontweight="bold")
    val = dataset.frames[dataset.frames["split"] == "val"]
    for route in dataset.meta.get("validation_routes", []):
        rows = val[val["route"] == route]
        for _, drive in rows.groupby("drive", sort=False):
            ax.plot(drive["x"], drive["y"], color="black", linewidth=1.0, linestyle=":")
        end = rows.loc[rows["s"].idxmax()]  # labelled at its far end, clear of the test labels
        ax.annotate(f"{route} (validation)", (end["x"], end["y"]), xytext=(-30, 6),
                    textcoords="offset points", color="black", fontsize=8, fontweight="bold")


def world_map_figure(dataset: Dataset, *, max_side: int = 512) -> Figure:
    """Top-down map: shaded terrain, objects, the training region with its frames and roads,
    the test region with the routes."""
    world = _world_of(json.dumps(dataset.meta["config"], sort_keys=True),
                      int(dataset.meta["seed"]))
    rgb = _shaded_terrain(world, max_side=max_side)
    size = world.size_m
    fig = Figure(figsize=(6.4, 6.0))
    ax = fig.subplots()
    fig.subplots_adjust(left=0.1, right=0.98, top=0.94, bottom=0.08)
    ax.imshow(rgb, origin="lower", extent=(0, size, 0, size), interpolation="bilinear")
    _draw_trees_regions_and_training(ax, world, dataset)
    _draw_routes(ax, dataset)
    ax.set_xlim(0, size)
    ax.set_ylim(0, size)
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_title("Weather world: training region, roads, test and validation routes",
                 fontsize=10)
    return fig


def plot_world_map(dataset: Dataset, path: str | Path) -> Path:
    """Write the top-down map of the world to ``path`` (.png or .pdf)."""
    return _save(world_map_figure(dataset), path)
