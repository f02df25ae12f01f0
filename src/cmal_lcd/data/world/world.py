"""The procedural world: terrain, roads, objects and surface colours, built from a seed.

Everything is a deterministic function of ``(DataConfig, seed)`` through named random streams
(:mod:`cmal_lcd.data.world.rng`), so the dataset stage, the calibration and the figures all
rebuild the same world. Grids are indexed ``[iy, ix]``; cell ``(ix, iy)`` covers
``x in [ix * cell_m, (ix + 1) * cell_m)`` and likewise for ``y``. ``x`` points east, ``y`` north,
headings are counter-clockwise from ``+x`` in radians.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from cmal_lcd.data.world import materials as M
from cmal_lcd.data.world.config import DataConfig, RoadSpec, StyleSpec, WorldSpec
from cmal_lcd.data.world.noise import fbm, value_noise
from cmal_lcd.data.world.rng import stream_rng
from cmal_lcd.data.world.roads import Road, RoadField, meander_centreline, road_field, road_profile

logger = logging.getLogger(__name__)

#: Width of the gravel shoulder beyond the outer lane edge, metres.
SHOULDER_M = 1.2
#: Objects keep this far from the centreline beyond the lane edge, metres.
KEEP_OUT_M = 2.5

_ROOFS = np.array([[0.30, 0.12, 0.10], [0.22, 0.22, 0.24], [0.30, 0.24, 0.18],
                   [0.20, 0.26, 0.22], [0.40, 0.38, 0.36]], np.float32)
_SIGNS = np.array([[0.05, 0.15, 0.55], [0.05, 0.40, 0.12], [0.60, 0.06, 0.05],
                   [0.75, 0.60, 0.05], [0.80, 0.80, 0.80]], np.float32)


@dataclass(frozen=True)
class World:
    """A built world: grids for the ray-caster plus the roads and billboard sprites.

    Attributes
    ----------
    spec : WorldSpec
    height : ndarray, float32 (n, n)
        Top surface: terrain, roads, buildings, fences, rocks.
    ground : ndarray, float32 (n, n)
        Terrain and roads only (camera height, sprite bases, building floors).
    material : ndarray, uint8 (n, n)
        Material id of the top surface (:mod:`~cmal_lcd.data.world.materials`).
    albedo : ndarray, uint8 (n, n, 3)
        Linear albedo of the top surface, times 255.
    style : ndarray, uint8 (n, n)
        Palette entry of walls and fences.
    road_lateral, road_s : ndarray, float32 (n, n)
        Signed offset from, and arc length along, the nearest road centreline (lane markings).
    puddle : ndarray, uint8 (n, n)
        Depth of the hollows where rain water collects on roads and shoulders (0-255).
    canopy_lo, canopy_hi : ndarray, float32 (n, n)
        Vertical extent of tree canopies over each cell (shadow casting only); empty cells have
        ``lo > hi``.
    sprites : ndarray, float32 (S, 10)
        Billboards (trees, bushes, poles, signs), columns :data:`~materials.SPRITE_FIELDS`.
    palette : ndarray, float32 (256, 4)
    skyline : ndarray, float32 (B,)
        Elevation (radians) of the far mountain skyline per azimuth bin over ``[0, 2 pi)``.
    roads : dict of str -> Road
        Training roads then test routes.
    train_roads, routes : tuple of str
    """

    spec: WorldSpec
    height: np.ndarray
    ground: np.ndarray
    material: np.ndarray
    albedo: np.ndarray
    style: np.ndarray
    road_lateral: np.ndarray
    road_s: np.ndarray
    puddle: np.ndarray
    canopy_lo: np.ndarray
    canopy_hi: np.ndarray
    sprites: np.ndarray
    palette: np.ndarray
    skyline: np.ndarray
    roads: dict[str, Road]
    train_roads: tuple[str, ...]
    routes: tuple[str, ...]

    @property
    def cell_m(self) -> float:
        return self.spec.cell_m

    @property
    def n_cells(self) -> int:
        return self.height.shape[0]

    @property
    def size_m(self) -> float:
        return self.n_cells * self.cell_m

    def region_box(self, which: str) -> tuple[float, float, float, float]:
        """``(x0, x1, y0, y1)`` in metres of the ``"train"`` or ``"test"`` region."""
        if which not in ("train", "test"):
            raise ValueError(f"which: expected 'train' or 'test', got {which!r}")
        xs = self.spec.train_region if which == "train" else self.spec.test_region
        y0, y1 = self.spec.y_range
        return (xs[0] * self.size_m, xs[1] * self.size_m, y0 * self.size_m, y1 * self.size_m)

    def ground_height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear ground height at points, float64 (K,) (clamped at the border)."""
        return bilinear(self.ground, np.asarray(x, np.float64) / self.cell_m,
                        np.asarray(y, np.float64) / self.cell_m)


def bilinear(grid: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """Bilinear sample of ``grid[iy, ix]`` at cell coordinates (cell centres at ``i + 0.5``).

    Parameters
    ----------
    grid : ndarray (n, m)
    gx, gy : ndarray, float (K,)
        Coordinates in cells.

    Returns
    -------
    ndarray, float64 (K,)
    """
    ny, nx = grid.shape
    fx = np.clip(np.asarray(gx, np.float64) - 0.5, 0.0, nx - 1.000001)
    fy = np.clip(np.asarray(gy, np.float64) - 0.5, 0.0, ny - 1.000001)
    ix, iy = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    wx, wy = fx - ix, fy - iy
    ix1, iy1 = np.minimum(ix + 1, nx - 1), np.minimum(iy + 1, ny - 1)
    g00, g01 = grid[iy, ix].astype(np.float64), grid[iy, ix1].astype(np.float64)
    g10, g11 = grid[iy1, ix].astype(np.float64), grid[iy1, ix1].astype(np.float64)
    return (g00 * (1 - wx) + g01 * wx) * (1 - wy) + (g10 * (1 - wx) + g11 * wx) * wy


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def terrain_heights(spec: WorldSpec, *, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rolling hills plus a ridged mountain ring along the world's border.

    Returns
    -------
    terrain : ndarray, float32 (n, n)
        Height in metres.
    ring : ndarray, float32 (n, n)
        Mountain weight in ``[0, 1]`` (1 at the border).
    """
    rng = stream_rng(seed, "world", "terrain")
    n, c = spec.n_cells, spec.cell_m
    hills = spec.hills_m * fbm((n, n), period_cells=spec.hill_period_m / c, octaves=6, rng=rng)
    ridges = 1.0 - np.abs(fbm((n, n), period_cells=140.0 / c, octaves=4, rng=rng))
    coords = (np.arange(n) + 0.5) * c
    edge_x = np.minimum(coords, spec.size_m - coords)
    edge = np.minimum(edge_x[None, :], edge_x[:, None])
    if spec.mountain_band_m > 0:
        ring = _smoothstep(1.0 - edge / spec.mountain_band_m).astype(np.float32)
    else:
        ring = np.zeros((n, n), np.float32)
    terrain = hills + spec.mountains_m * ring * (0.45 + 0.55 * ridges)
    return terrain.astype(np.float32), ring


def build_roads(config: DataConfig, terrain: np.ndarray, *, seed: int) -> dict[str, Road]:
    """Centrelines and height profiles of the training roads, test and validation routes."""
    spec = config.world
    specs: list[RoadSpec] = (list(spec.train_roads.values()) + list(config.test.routes.values())
                             + list(config.test.validation_routes.values()))
    roads = {}
    for road in specs:
        if road.name in roads:
            raise ValueError(f"data.test.routes.{road.name}: a training road has the same name")
        rng = stream_rng(seed, "world", "road", road.name)
        points, s, tangent = meander_centreline(
            x0=road.x * spec.size_m, y0=spec.y_range[0] * spec.size_m, length_m=road.length_m,
            meander_m=road.meander_m, rng=rng)
        under = bilinear(terrain, points[:, 0] / spec.cell_m, points[:, 1] / spec.cell_m)
        roads[road.name] = Road(name=road.name, style=road.style, points=points, s=s,
                                tangent=tangent, z=road_profile(under))
    return roads


def _surface(spec: WorldSpec, terrain: np.ndarray, ring: np.ndarray, field: RoadField, *,
             seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ground heights with the roads cut in; the ground's material, albedo and puddles."""
    rng = stream_rng(seed, "world", "albedo")
    n, c = spec.n_cells, spec.cell_m
    dist = field.distance
    flat = spec.lane_width_m + SHOULDER_M
    blend = _smoothstep((dist - flat) / spec.embankment_m)
    ground = (field.z * (1 - blend) + terrain * blend).astype(np.float32)

    tone = fbm((n, n), period_cells=60.0 / c, octaves=3, rng=rng)
    patches = fbm((n, n), period_cells=25.0 / c, octaves=3, rng=rng)
    fine = value_noise((n, n), period_cells=1.5, rng=rng)
    grass_a = np.array([0.13, 0.22, 0.06], np.float32)
    grass_b = np.array([0.27, 0.29, 0.10], np.float32)
    mix = (0.5 + 0.5 * tone)[..., None]
    albedo = grass_a * (1 - mix) + grass_b * mix
    material = np.full((n, n), M.GRASS, np.uint8)
    dirt = patches > 0.35
    albedo[dirt] = np.array([0.28, 0.23, 0.16], np.float32)
    mountain = terrain - spec.hills_m
    rock = (ring > 0.3) & (mountain > 0.2 * spec.mountains_m + 8 * tone)
    albedo[rock] = np.array([0.30, 0.29, 0.27], np.float32)
    material[rock] = M.ROCK
    snow = (ring > 0.3) & (mountain > 0.7 * spec.mountains_m + 10 * tone)
    albedo[snow] = np.array([0.80, 0.82, 0.86], np.float32)
    material[snow] = M.SNOW

    lat = field.distance
    lane = spec.lane_width_m
    gravel = lat < lane + SHOULDER_M
    albedo[gravel] = np.array([0.30, 0.28, 0.25], np.float32)
    material[gravel] = M.GRAVEL
    road = lat < lane
    repairs = (patches > 0.45)
    asphalt = np.where(repairs, 0.075, 0.11).astype(np.float32)
    albedo[road] = np.stack([asphalt, asphalt, asphalt * 1.05], axis=-1)[road]
    material[road] = M.ROAD  # markings are drawn by the renderer from the road coordinates
    albedo *= (1.0 + 0.15 * fine)[..., None]
    hollows = fbm((n, n), period_cells=3.0 / c, octaves=2, rng=rng)
    puddle = np.where(gravel, np.clip((hollows - 0.3) * 4.0, 0.0, 1.0), 0.0)
    return ground, material, albedo, np.round(puddle * 255).astype(np.uint8)


class _Grid:
    """Mutable grids while objects are placed."""

    def __init__(self, spec: WorldSpec, ground: np.ndarray, material: np.ndarray,
                 albedo: np.ndarray, field: RoadField):
        self.spec = spec
        self.c = spec.cell_m
        self.n = spec.n_cells
        self.ground = ground
        self.height = ground.copy()
        self.material = material
        self.albedo = albedo
        self.style = np.zeros_like(material)
        self.keep_out = field.distance < spec.lane_width_m + KEEP_OUT_M
        self.occupied = np.zeros_like(self.keep_out)
        self.canopy_lo = np.full(ground.shape, np.inf, np.float32)
        self.canopy_hi = np.full(ground.shape, -np.inf, np.float32)
        self.sprites: list[list[float]] = []

    def cell(self, x: float, y: float) -> tuple[int, int]:
        return int(np.floor(x / self.c)), int(np.floor(y / self.c))

    def inside(self, ix: int, iy: int) -> bool:
        return 0 <= ix < self.n and 0 <= iy < self.n

    def free(self, x: float, y: float) -> bool:
        ix, iy = self.cell(x, y)
        return self.inside(ix, iy) and not self.keep_out[iy, ix] and not self.occupied[iy, ix]

    def ground_at(self, x: float, y: float) -> float:
        return float(bilinear(self.ground, np.array([x / self.c]), np.array([y / self.c]))[0])


def _roadside_point(road: Road, s: float, offset: float) -> tuple[float, float, float, float]:
    """Point ``offset`` metres left of the centreline at ``s`` and the unit tangent there."""
    xy, tangent, _ = road.at(np.array([s]))
    tx, ty = tangent[0]
    return xy[0, 0] - ty * offset, xy[0, 1] + tx * offset, tx, ty


def _place_building(grid: _Grid, road: Road, rng: np.random.Generator, style: StyleSpec) -> None:
    lane = grid.spec.lane_width_m
    s = rng.uniform(0.0, road.length)
    side = rng.choice([-1.0, 1.0])
    along, depth = rng.uniform(7.0, 16.0), rng.uniform(6.0, 12.0)
    setback = rng.uniform(3.0, 14.0)
    h = rng.uniform(*style.building_height_m)
    wall = int(rng.integers(M.N_WALL_STYLES))
    roof = _ROOFS[int(rng.integers(len(_ROOFS)))] * rng.uniform(0.85, 1.15)
    x, y, tx, ty = _roadside_point(road, s, side * (lane + KEEP_OUT_M + setback + depth / 2))
    hx, hy = (along / 2, depth / 2) if abs(tx) > abs(ty) else (depth / 2, along / 2)
    ix0, iy0 = grid.cell(x - hx, y - hy)
    ix1, iy1 = grid.cell(x + hx, y + hy)
    m = int(np.ceil(1.5 / grid.c))  # keep 1.5 m between buildings
    if not (grid.inside(ix0 - m, iy0 - m) and grid.inside(ix1 + m, iy1 + m)):
        return
    if (grid.keep_out[iy0:iy1 + 1, ix0:ix1 + 1].any()
            or grid.occupied[iy0 - m:iy1 + m + 1, ix0 - m:ix1 + m + 1].any()):
        return
    block = (slice(iy0, iy1 + 1), slice(ix0, ix1 + 1))
    grid.height[block] = grid.ground[block].max() + h
    grid.material[block] = M.BUILDING
    grid.style[block] = wall
    grid.albedo[block] = roof
    grid.occupied[block] = True


def _place_fence(grid: _Grid, road: Road, rng: np.random.Generator) -> None:
    lane = grid.spec.lane_width_m
    s0 = rng.uniform(0.0, road.length)
    length = rng.uniform(10.0, 40.0)
    side = rng.choice([-1.0, 1.0])
    offset = side * (lane + rng.uniform(2.5, 5.0))
    height = rng.uniform(0.9, 1.6)
    style = M.FENCE_PALETTE_START + int(rng.integers(M.N_FENCE_STYLES))
    ss = np.arange(s0, min(s0 + length, road.length), 0.2)
    if len(ss) < 2:
        return
    xy, tangent, _ = road.at(ss)
    px = xy[:, 0] - tangent[:, 1] * offset
    py = xy[:, 1] + tangent[:, 0] * offset
    cells = []
    prev = None
    for x, y in zip(px, py):
        ix, iy = grid.cell(x, y)
        if prev is not None and ix != prev[0] and iy != prev[1]:
            cells.append((ix, prev[1]))  # close diagonal gaps (4-connected line)
        cells.append((ix, iy))
        prev = (ix, iy)
    for ix, iy in dict.fromkeys(cells):
        if not grid.inside(ix, iy) or grid.keep_out[iy, ix] or grid.occupied[iy, ix]:
            continue
        grid.height[iy, ix] = grid.ground[iy, ix] + height
        grid.material[iy, ix] = M.FENCE
        grid.style[iy, ix] = style
        grid.albedo[iy, ix] = grid.albedo[iy, ix] * 0.3 + 0.7 * np.array([0.35, 0.30, 0.25])
        grid.occupied[iy, ix] = True


def _place_rock(grid: _Grid, x: float, y: float, radius: float, height: float,
                rng: np.random.Generator) -> None:
    r_cells = int(np.ceil(radius / grid.c))
    cx, cy = grid.cell(x, y)
    tint = np.array([0.36, 0.35, 0.33], np.float32) * rng.uniform(0.75, 1.2)
    bumps = rng.uniform(0.8, 1.0, size=(2 * r_cells + 1, 2 * r_cells + 1))
    for j in range(-r_cells, r_cells + 1):
        for i in range(-r_cells, r_cells + 1):
            ix, iy = cx + i, cy + j
            if not grid.inside(ix, iy) or grid.keep_out[iy, ix] or grid.occupied[iy, ix]:
                continue
            r2 = ((i * grid.c) ** 2 + (j * grid.c) ** 2) / radius ** 2
            if r2 >= 1.0:
                continue
            top = grid.ground[iy, ix] + height * np.sqrt(1.0 - r2) * bumps[j + r_cells, i + r_cells]
            if top > grid.height[iy, ix]:
                grid.height[iy, ix] = top
                grid.material[iy, ix] = M.ROCK
                grid.albedo[iy, ix] = tint * bumps[j + r_cells, i + r_cells]


def _add_tree(grid: _Grid, x: float, y: float, *, conifer: bool, height: float,
              rng: np.random.Generator) -> None:
    z = grid.ground_at(x, y)
    if conifer:
        radius = height * rng.uniform(0.22, 0.32)
        rgb = np.array([0.05, 0.13, 0.06]) * rng.uniform(0.75, 1.25, size=3)
        kind, lo = M.CONIFER, 0.15
    else:
        radius = height * rng.uniform(0.3, 0.42)
        rgb = np.array([0.11, 0.20, 0.05]) * rng.uniform(0.75, 1.3, size=3)
        kind, lo = M.BROADLEAF, 0.4
    grid.sprites.append([x, y, z, height, radius, kind, *rgb, rng.integers(1 << 20)])
    r_cells = int(np.ceil(0.8 * radius / grid.c))
    cx, cy = grid.cell(x, y)
    for j in range(-r_cells, r_cells + 1):
        for i in range(-r_cells, r_cells + 1):
            ix, iy = cx + i, cy + j
            if grid.inside(ix, iy) and (i * i + j * j) * grid.c ** 2 <= (0.8 * radius) ** 2:
                grid.canopy_lo[iy, ix] = min(grid.canopy_lo[iy, ix], z + lo * height)
                grid.canopy_hi[iy, ix] = max(grid.canopy_hi[iy, ix], z + height)


def _roadside_objects(grid: _Grid, road: Road, style: StyleSpec, *, seed: int) -> None:
    """Buildings, fences, rocks, trees, bushes, poles and signs along one road."""
    per = road.length / 100.0

    def stream(kind: str) -> np.random.Generator:
        return stream_rng(seed, "world", "objects", road.name, kind)

    rng = stream("buildings")
    for _ in range(rng.poisson(style.buildings * per)):
        _place_building(grid, road, rng, style)
    rng = stream("fences")
    for _ in range(rng.poisson(style.fences * per)):
        _place_fence(grid, road, rng)
    rng = stream("rocks")
    for _ in range(rng.poisson(style.rocks * per)):
        _place_roadside_rock(grid, road, rng)
    rng = stream("trees")
    for _ in range(rng.poisson(style.trees * per)):
        _place_roadside_tree(grid, road, rng, style)
    rng = stream("bushes")
    for _ in range(rng.poisson(style.bushes * per)):
        _place_bush(grid, road, rng)
    _place_poles(grid, road, stream("poles"), style)
    rng = stream("signs")
    for _ in range(rng.poisson(style.signs * per)):
        _place_sign(grid, road, rng)


def _place_roadside_rock(grid: _Grid, road: Road, rng: np.random.Generator) -> None:
    """One rock at a random arc length and side, 0.5-12 m beyond the keep-out band."""
    lane = grid.spec.lane_width_m
    s, side = rng.uniform(0, road.length), rng.choice([-1.0, 1.0])
    radius = rng.uniform(0.8, 2.5)
    x, y, _, _ = _roadside_point(road, s, side * (lane + KEEP_OUT_M + radius
                                                  + rng.uniform(0.5, 12.0)))
    _place_rock(grid, x, y, radius, rng.uniform(0.4, 0.9) * radius, rng)


def _place_roadside_tree(grid: _Grid, road: Road, rng: np.random.Generator,
                         style: StyleSpec) -> None:
    """One tree (conifer with ``style.conifer_fraction``) 1.5-22 m beyond the keep-out band,
    added where the cell is free."""
    lane = grid.spec.lane_width_m
    s, side = rng.uniform(0, road.length), rng.choice([-1.0, 1.0])
    x, y, _, _ = _roadside_point(road, s, side * (lane + KEEP_OUT_M + rng.uniform(1.5, 22)))
    conifer = rng.random() < style.conifer_fraction
    height = rng.uniform(6.0, 15.0) if conifer else rng.uniform(5.0, 12.0)
    if grid.free(x, y):
        _add_tree(grid, x, y, conifer=conifer, height=height, rng=rng)


def _place_bush(grid: _Grid, road: Road, rng: np.random.Generator) -> None:
    """One bush sprite 0.5-10 m beyond the keep-out band, appended where the cell is free."""
    lane = grid.spec.lane_width_m
    s, side = rng.uniform(0, road.length), rng.choice([-1.0, 1.0])
    x, y, _, _ = _roadside_point(road, s, side * (lane + KEEP_OUT_M + rng.uniform(0.5, 10)))
    if grid.free(x, y):
        rgb = np.array([0.10, 0.20, 0.06]) * rng.uniform(0.7, 1.3, size=3)
        grid.sprites.append([x, y, grid.ground_at(x, y), rng.uniform(0.7, 1.8),
                             rng.uniform(0.7, 1.6), M.BUSH, *rgb, rng.integers(1 << 20)])


def _place_poles(grid: _Grid, road: Road, rng: np.random.Generator, style: StyleSpec) -> None:
    """A row of lamp-pole sprites on one side, ``style.poles`` per 100 m with jitter, on
    unoccupied cells (none when ``style.poles`` is 0)."""
    lane = grid.spec.lane_width_m
    if style.poles > 0:
        spacing = 100.0 / style.poles
        side = rng.choice([-1.0, 1.0])
        for s in np.arange(rng.uniform(0, spacing), road.length, spacing):
            s = s + rng.uniform(-0.1, 0.1) * spacing
            x, y, _, _ = _roadside_point(road, s, side * (lane + 2.0))
            ix, iy = grid.cell(x, y)
            if grid.inside(ix, iy) and not grid.occupied[iy, ix]:
                grey = rng.uniform(0.25, 0.45)
                grid.sprites.append([x, y, grid.ground_at(x, y), rng.uniform(7.0, 9.0), 0.8,
                                     M.LAMP_POLE, grey, grey, grey * 1.05, rng.integers(1 << 20)])


def _place_sign(grid: _Grid, road: Road, rng: np.random.Generator) -> None:
    """One sign sprite by the road, or (30%) a large billboard set back from it, on an
    unoccupied cell."""
    lane = grid.spec.lane_width_m
    s, side = rng.uniform(0, road.length), rng.choice([-1.0, 1.0])
    x, y, _, _ = _roadside_point(road, s, side * (lane + 2.5))
    ix, iy = grid.cell(x, y)
    billboard = rng.random() < 0.3
    if billboard:  # a large advertising board set back from the road
        x, y, _, _ = _roadside_point(road, s, side * (lane + 6.0 + rng.uniform(0, 6)))
        ix, iy = grid.cell(x, y)
    if grid.inside(ix, iy) and not grid.occupied[iy, ix]:
        rgb = _SIGNS[int(rng.integers(len(_SIGNS)))] * rng.uniform(0.7, 1.1)
        height, radius = ((rng.uniform(5.0, 8.0), rng.uniform(2.0, 4.0)) if billboard
                          else (rng.uniform(2.2, 3.5), rng.uniform(0.6, 1.4)))
        grid.sprites.append([x, y, grid.ground_at(x, y), height, radius, M.SIGN_BOARD,
                             *rgb, rng.integers(1 << 20)])


def _forest(grid: _Grid, ring: np.ndarray, *, seed: int) -> None:
    """Trees off the roads, in patches covering ``forest_cover`` of the land."""
    spec = grid.spec
    if spec.forest_trees_per_ha <= 0 or spec.forest_cover <= 0:
        return
    rng = stream_rng(seed, "world", "forest")
    mask = fbm((grid.n, grid.n), period_cells=90.0 / grid.c, octaves=3, rng=rng)
    threshold = np.quantile(mask, 1.0 - spec.forest_cover)
    area_ha = spec.size_m ** 2 / 1e4
    count = rng.poisson(spec.forest_trees_per_ha * area_ha)
    xy = rng.uniform(0.0, spec.size_m, size=(count, 2))
    conifer = rng.random(count) < 0.6
    heights = np.where(conifer, rng.uniform(7.0, 17.0, count), rng.uniform(6.0, 13.0, count))
    for k in range(count):
        x, y = xy[k]
        ix, iy = grid.cell(x, y)
        if mask[iy, ix] < threshold or ring[iy, ix] > 0.5 or not grid.free(x, y):
            continue  # outside forest patches, on the mountains, the road or a building
        _add_tree(grid, x, y, conifer=bool(conifer[k]), height=float(heights[k]), rng=rng)


def _skyline(*, seed: int, degrees: float, bins: int = 1440) -> np.ndarray:
    """Elevation (radians) of a distant mountain range per azimuth bin."""
    rng = stream_rng(seed, "world", "skyline")
    az = np.arange(bins) * (2 * np.pi / bins)
    total = np.zeros(bins)
    for k in (2, 3, 5, 8, 13, 21, 34):
        total += rng.uniform(0.3, 1.0) / np.sqrt(k) * np.sin(k * az + rng.uniform(0, 2 * np.pi))
    total = (total - total.min()) / (total.max() - total.min() + 1e-12)
    return np.deg2rad(degrees * (0.25 + 0.75 * total)).astype(np.float32)


def build_world(config: DataConfig, *, seed: int) -> World:
    """Build the world of ``config`` (a deterministic function of ``config.world``,
    ``config.test.routes`` and ``seed``).

    Parameters
    ----------
    config : DataConfig
    seed : int
        The pipeline's top-level seed.

    Returns
    -------
    World
    """
    spec = config.world
    terrain, ring = terrain_heights(spec, seed=seed)
    roads = build_roads(config, terrain, seed=seed)
    field = road_field(list(roads.values()), n_cells=spec.n_cells, cell_m=spec.cell_m)
    ground, material, albedo, puddle = _surface(spec, terrain, ring, field, seed=seed)
    grid = _Grid(spec, ground, material, albedo, field)
    for road in roads.values():
        _roadside_objects(grid, road, spec.styles[road.style], seed=seed)
    _forest(grid, ring, seed=seed)
    sprites = np.asarray(grid.sprites, np.float32).reshape(-1, len(M.SPRITE_FIELDS))
    logger.info("world: %d x %d cells of %.2f m, %d roads, %d sprites", spec.n_cells,
                spec.n_cells, spec.cell_m, len(roads), len(sprites))
    return World(
        spec=spec, height=grid.height.astype(np.float32), ground=grid.ground,
        material=grid.material,
        albedo=np.clip(np.round(grid.albedo * 255), 0, 255).astype(np.uint8),
        style=grid.style, road_lateral=field.lateral, road_s=field.s, puddle=puddle,
        canopy_lo=grid.canopy_lo, canopy_hi=grid.canopy_hi, sprites=sprites,
        palette=M.palette(), skyline=_skyline(seed=seed, degrees=spec.skyline_deg), roads=roads,
        train_roads=tuple(spec.train_roads), routes=tuple(config.test.routes))
