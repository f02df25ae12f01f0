"""The ``data`` node of the composed config, read into frozen dataclasses.

The values live in ``conf/data/gtav_weather.yaml`` only (no defaults here); their types and
ranges in :mod:`cmal_lcd.schema` (:class:`~cmal_lcd.schema.GtavWeatherDataSchema`), which
:meth:`DataConfig.from_config` applies first. What a per-key schema cannot say is checked here,
naming the key: a ``[low, high]`` interval in order, regions that do not overlap, roads inside
their region, known styles and conditions, pairs with a stretch the reference never visits, a
renderer that exists.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from cmal_lcd.data.world.condition import ConditionParams
from cmal_lcd.schema import WORLD_KIND as KIND
#: Renderer backends by name (see :mod:`cmal_lcd.data.world.render`).
RENDERER_NAMES = ("heightmap",)


# ----------------------------------------------------------------------------- readers

def _mapping(conf: Any, where: str) -> dict[str, Any]:
    if conf is None:
        return {}
    if not isinstance(conf, Mapping):
        raise ValueError(f"{where}: expected a mapping, got {type(conf).__name__}")
    return dict(conf)


def _get(conf: Mapping[str, Any], key: str, where: str) -> Any:
    """``conf[key]``; an absent key is refused naming it (the schema lets absent keys pass)."""
    if key not in conf:
        raise ValueError(f"{where}.{key}: required")
    return conf[key]


def _floats(conf: Mapping[str, Any], where: str, *keys: str) -> dict[str, float]:
    return {key: float(_get(conf, key, where)) for key in keys}


def _interval(value: Any, where: str) -> tuple[float, float]:
    """``[low, high]`` with ``low <= high`` (its bounds are the schema's)."""
    a, b = (float(v) for v in value)
    if a > b:
        raise ValueError(f"{where}: need low <= high, got [{a}, {b}]")
    return a, b


def _name(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value or "/" in value or "-" in value:
        raise ValueError(f"{where}: expected a non-empty name without '/' or '-', got {value!r}")
    return value


# ----------------------------------------------------------------------------- sections

@dataclass(frozen=True)
class StyleSpec:
    """Objects along a road of one style, as counts per 100 m of road (both sides).

    Attributes
    ----------
    trees, bushes, rocks, poles, fences, buildings, signs : float
        Expected number per 100 m of road.
    conifer_fraction : float
        Share of roadside trees that are conifers (the rest broadleaf).
    building_height_m : (float, float)
        Range of building heights.
    """

    name: str
    trees: float
    bushes: float
    rocks: float
    poles: float
    fences: float
    buildings: float
    signs: float
    conifer_fraction: float
    building_height_m: tuple[float, float]

    @classmethod
    def from_config(cls, name: str, conf: Any, where: str) -> "StyleSpec":
        conf = _mapping(conf, where)
        values = _floats(conf, where, "trees", "bushes", "rocks", "poles", "fences",
                         "buildings", "signs", "conifer_fraction")
        heights = _interval(_get(conf, "building_height_m", where), f"{where}.building_height_m")
        return cls(name=name, building_height_m=heights, **values)


@dataclass(frozen=True)
class RoadSpec:
    """One road: a meandering curve heading north (+y) from the region's southern edge.

    Attributes
    ----------
    x : float
        Mean x of the road, fraction of the world size.
    length_m : float
        Arc length of the road.
    style : str
        Key of ``data.world.styles``.
    meander_m : float
        Largest sideways excursion from ``x``.
    """

    name: str
    x: float
    length_m: float
    style: str
    meander_m: float

    @classmethod
    def from_config(cls, name: str, conf: Any, where: str, styles: Mapping[str, StyleSpec]
                    ) -> "RoadSpec":
        conf = _mapping(conf, where)
        values = _floats(conf, where, "x", "length_m", "meander_m")
        values["style"] = _name(_get(conf, "style", where), f"{where}.style")
        if values["style"] not in styles:
            raise ValueError(f"{where}.style: unknown style {values['style']!r}; "
                             f"known: {sorted(styles)}")
        return cls(name=_name(name, where), **values)


@dataclass(frozen=True)
class WorldSpec:
    """Terrain, regions, roads and object styles of the world (``data.world``)."""

    size_m: float
    cell_m: float
    hills_m: float
    hill_period_m: float
    mountains_m: float
    mountain_band_m: float
    forest_trees_per_ha: float
    forest_cover: float
    lane_width_m: float
    embankment_m: float
    train_region: tuple[float, float]
    test_region: tuple[float, float]
    y_range: tuple[float, float]
    skyline_deg: float
    styles: dict[str, StyleSpec]
    train_roads: dict[str, RoadSpec]

    @classmethod
    def from_config(cls, conf: Any, where: str = "data.world") -> "WorldSpec":
        conf = _mapping(conf, where)
        styles_conf = _mapping(conf.pop("styles", None), f"{where}.styles")
        if not styles_conf:
            raise ValueError(f"{where}.styles: at least one style is needed")
        styles = {_name(k, f"{where}.styles"): StyleSpec.from_config(k, v, f"{where}.styles.{k}")
                  for k, v in styles_conf.items()}
        roads_conf = _mapping(conf.pop("train_roads", None), f"{where}.train_roads")
        if not roads_conf:
            raise ValueError(f"{where}.train_roads: at least one training road is needed")
        roads = {k: RoadSpec.from_config(k, v, f"{where}.train_roads.{k}", styles)
                 for k, v in roads_conf.items()}
        values: dict[str, Any] = _floats(
            conf, where, "size_m", "cell_m", "hills_m", "hill_period_m", "mountains_m",
            "mountain_band_m", "forest_trees_per_ha", "forest_cover", "lane_width_m",
            "embankment_m", "skyline_deg")
        for key in ("train_region", "test_region", "y_range"):
            values[key] = _interval(_get(conf, key, where), f"{where}.{key}")
        spec = cls(styles=styles, train_roads=roads, **values)
        spec._validate(where)
        return spec

    def _validate(self, where: str) -> None:
        n_cells = self.size_m / self.cell_m
        if n_cells < 32 or n_cells > 8192:
            raise ValueError(f"{where}.size_m: size_m / cell_m must be in [32, 8192] cells, "
                             f"got {n_cells:.0f}")
        (a0, a1), (b0, b1) = self.train_region, self.test_region
        if a0 == a1 or b0 == b1:
            raise ValueError(f"{where}.train_region/test_region: regions must have a width")
        if not (a1 <= b0 or b1 <= a0):
            raise ValueError(f"{where}.train_region/test_region: training and test regions "
                             f"overlap ({list(self.train_region)} vs {list(self.test_region)})")
        for name, road in self.train_roads.items():
            _check_road_inside(road, self, self.train_region, f"{where}.train_roads.{name}")

    @property
    def n_cells(self) -> int:
        """Cells per side of the square heightmap."""
        return int(round(self.size_m / self.cell_m))


def _check_road_inside(road: RoadSpec, world: WorldSpec, region: tuple[float, float],
                       where: str) -> None:
    """The road's x band and length must fit its region."""
    x0, x1 = (v * world.size_m for v in region)
    centre = road.x * world.size_m
    half_width = road.meander_m + world.lane_width_m + 2.0
    if centre - half_width < x0 or centre + half_width > x1:
        raise ValueError(f"{where}.x: the road's band [{centre - half_width:.0f}, "
                         f"{centre + half_width:.0f}] m leaves its region [{x0:.0f}, {x1:.0f}] m "
                         f"(x or meander_m too large)")
    y0, y1 = (v * world.size_m for v in world.y_range)
    if road.length_m > (y1 - y0):
        raise ValueError(f"{where}.length_m: {road.length_m} m does not fit the region's "
                         f"north-south extent of {y1 - y0:.0f} m")


@dataclass(frozen=True)
class CameraSpec:
    """The car camera (``data.camera``)."""

    height_m: float
    hfov_deg: float
    pitch_deg: float
    max_distance_m: float
    shadow_distance_m: float

    @classmethod
    def from_config(cls, conf: Any, where: str = "data.camera") -> "CameraSpec":
        return cls(**_floats(_mapping(conf, where), where, "height_m", "hfov_deg", "pitch_deg",
                             "max_distance_m", "shadow_distance_m"))


@dataclass(frozen=True)
class TrainSpec:
    """Training frames: random poses along the training roads (``data.train``)."""

    paired: bool
    lateral_jitter_m: float
    heading_jitter_deg: float

    @classmethod
    def from_config(cls, conf: Any, where: str = "data.train") -> "TrainSpec":
        conf = _mapping(conf, where)
        return cls(paired=bool(_get(conf, "paired", where)),
                   **_floats(conf, where, "lateral_jitter_m", "heading_jitter_deg"))


@dataclass(frozen=True)
class WanderSpec:
    """Per-drive smooth wander of the test drives (``data.test.wander``).

    Attributes
    ----------
    lateral_m : float
        Largest sideways offset from the lane centre.
    heading_deg : float
        Largest heading offset from the road direction.
    speed : (float, float)
        Range of the speed factor (frame spacing = ``frame_spacing_m`` times the factor).
    period_frames : (float, float)
        Range of the periods of the wander's sinusoids, in frames.
    """

    lateral_m: float
    heading_deg: float
    speed: tuple[float, float]
    period_frames: tuple[float, float]

    @classmethod
    def from_config(cls, conf: Any, where: str = "data.test.wander") -> "WanderSpec":
        conf = _mapping(conf, where)
        return cls(**_floats(conf, where, "lateral_m", "heading_deg"),
                   **{key: _interval(_get(conf, key, where), f"{where}.{key}")
                      for key in ("speed", "period_frames")})


#: ``repeat`` name of the same-weather control's lap-2 drive: ``<route>/<control>_lap2``.
LAP2 = "lap2"


@dataclass(frozen=True)
class LoopSpec:
    """Looping routes within one drive (``data.test.loops``): lap 1, then lap 2 of the same
    test route in the same direction, as one sequence (the return leg is not rendered).

    Attributes
    ----------
    control : str or None
        Condition of the same-weather control: its drive is lap 1 and an extra drive of it
        (``<route>/<control>_lap2``, rendered for every test route) is lap 2. None: no control
        and no extra drive.
    pairs : tuple of (str, str)
        ``(lap 1, lap 2)`` conditions of the weather-change loops, both existing drives.
    exclude_frames : int
        Exclusion zone of the loop matching: a frame only matches frames more than this many
        frames older (:func:`cmal_lcd.matching.loops.exclusion_limits`).
    """

    control: str | None = None
    pairs: tuple[tuple[str, str], ...] = ()
    exclude_frames: int = 0  # no loops (the default instance): no matching either

    @classmethod
    def from_config(cls, conf: Any, *, conditions: Mapping[str, Any],
                    where: str = "data.test.loops") -> "LoopSpec":
        """Types and ranges are the schema's; here the rules across keys (known conditions)."""
        if conf is None:
            return cls()
        conf = _mapping(conf, where)
        control = conf.get("control")
        if control is not None:
            control = _name(control, f"{where}.control")
            if control not in conditions:
                raise ValueError(f"{where}.control: unknown condition {control!r}; "
                                 f"known: {list(conditions)}")
        pairs = _pairs(conf["pairs"], f"{where}.pairs", conditions) if conf.get("pairs") else ()
        return cls(control=control, pairs=pairs,
                   exclude_frames=int(_get(conf, "exclude_frames", where)))


@dataclass(frozen=True)
class TestSpec:
    """Test routes and drives (``data.test``).

    Attributes
    ----------
    routes : dict of str -> RoadSpec
        Routes in the test region, in order (``route1``, ``route2``).
    validation_routes : dict of str -> RoadSpec
        Further routes in the test region, driven like the test routes (same windows, pairs
        and wander) but used only to choose the matching protocol (``select_protocol``
        stage); never a test route and never a training road. May be empty.
    frame_spacing_m : float
        Distance between frames at the nominal speed.
    speed_mps : float
        Nominal speed (sets the ``time`` column).
    windows : dict of str -> (float, float)
        Fraction of the route's arc length each condition's drive covers.
    default_window : (float, float)
        Window of conditions not in ``windows``.
    pairs : tuple of (str, str)
        ``(reference, query)`` conditions evaluated on every route.
    min_novel_fraction : float
        Every pair's query drive must have at least this share of its window outside the
        reference window (true negatives for the ROC).
    weather_jitter : float
        Within a drive, weather parameters wander by this fraction of their range around the
        drive's own draw (a drive has one sun, but fog density and exposure drift).
    wander : WanderSpec
    loops : LoopSpec
        Looping routes within one drive (none when ``data.test.loops`` is absent).
    """

    routes: dict[str, RoadSpec]
    frame_spacing_m: float
    speed_mps: float
    windows: dict[str, tuple[float, float]]
    default_window: tuple[float, float]
    pairs: tuple[tuple[str, str], ...]
    min_novel_fraction: float
    weather_jitter: float
    wander: WanderSpec
    validation_routes: dict[str, RoadSpec] = field(default_factory=dict)
    loops: LoopSpec = field(default_factory=LoopSpec)

    __test__ = False  # not a pytest test class

    @classmethod
    def from_config(cls, conf: Any, *, world: WorldSpec, conditions: Mapping[str, Any],
                    where: str = "data.test") -> "TestSpec":
        conf = _mapping(conf, where)
        routes = _test_routes(conf.pop("routes", None), world, where)
        validation_routes = _validation_routes(conf.pop("validation_routes", None), world,
                                               routes, where)
        windows = _condition_windows(conf.pop("windows", None), conditions, where)
        pairs_conf = conf.pop("pairs", None)
        wander = WanderSpec.from_config(conf.pop("wander", None), f"{where}.wander")
        loops = LoopSpec.from_config(conf.pop("loops", None), conditions=conditions,
                                     where=f"{where}.loops")
        values: dict[str, Any] = _floats(conf, where, "frame_spacing_m", "speed_mps",
                                         "min_novel_fraction", "weather_jitter")
        values["default_window"] = _window(_get(conf, "default_window", where),
                                           f"{where}.default_window")
        for name in conditions:
            windows.setdefault(name, values["default_window"])
        pairs = _pairs(pairs_conf, f"{where}.pairs", conditions)
        spec = cls(routes=routes, windows=windows, pairs=pairs, wander=wander,
                   validation_routes=validation_routes, loops=loops, **values)
        _check_pairs_novel(spec, where)
        _check_loops_overlap(spec, where)
        return spec


def _test_routes(conf: Any, world: WorldSpec, where: str) -> dict[str, RoadSpec]:
    """``data.test.routes``: at least one, each a road inside the test region."""
    routes_conf = _mapping(conf, f"{where}.routes")
    if not routes_conf:
        raise ValueError(f"{where}.routes: at least one route is needed")
    routes = {}
    for name, road in routes_conf.items():
        routes[name] = RoadSpec.from_config(name, road, f"{where}.routes.{name}", world.styles)
        _check_road_inside(routes[name], world, world.test_region, f"{where}.routes.{name}")
    return routes


def _validation_routes(conf: Any, world: WorldSpec, routes: Mapping[str, RoadSpec],
                       where: str) -> dict[str, RoadSpec]:
    """``data.test.validation_routes`` (may be absent): roads inside the test region, named
    unlike every test route."""
    validation_conf = _mapping(conf or {}, f"{where}.validation_routes")
    validation_routes = {}
    for name, road in validation_conf.items():
        key = f"{where}.validation_routes.{name}"
        if name in routes:
            raise ValueError(f"{key}: a test route has the same name")
        validation_routes[name] = RoadSpec.from_config(name, road, key, world.styles)
        _check_road_inside(validation_routes[name], world, world.test_region, key)
    return validation_routes


def _condition_windows(conf: Any, conditions: Mapping[str, Any], where: str
                       ) -> dict[str, tuple[float, float]]:
    """``data.test.windows``: the configured drive window of each known condition."""
    windows_conf = _mapping(conf, f"{where}.windows")
    windows = {}
    for name, window in windows_conf.items():
        if name not in conditions:
            raise ValueError(f"{where}.windows.{name}: unknown condition {name!r}; "
                             f"known: {list(conditions)}")
        windows[name] = _window(window, f"{where}.windows.{name}")
    return windows


def _check_pairs_novel(spec: TestSpec, where: str) -> None:
    """Every pair's query window lies at least ``min_novel_fraction`` outside its reference's."""
    for ref, query in spec.pairs:
        novel = novel_fraction(spec.windows[ref], spec.windows[query])
        if novel < spec.min_novel_fraction:
            raise ValueError(
                f"{where}.pairs: in pair {ref}-{query} only {novel:.0%} of the query window "
                f"{list(spec.windows[query])} lies outside the reference window "
                f"{list(spec.windows[ref])}; min_novel_fraction is "
                f"{spec.min_novel_fraction:.0%} (change {where}.windows)")


def _check_loops_overlap(spec: TestSpec, where: str) -> None:
    """The windows of each looping pair overlap (lap 2 revisits places of lap 1)."""
    for first, second in spec.loops.pairs:
        if novel_fraction(spec.windows[first], spec.windows[second]) >= 1.0:
            raise ValueError(f"{where}.loops.pairs: the windows of {first} and {second} do "
                             f"not overlap: lap 2 would revisit no place of lap 1")


def _window(value: Any, where: str) -> tuple[float, float]:
    a, b = _interval(value, where)
    if a < 0.0 or b > 1.0:
        raise ValueError(f"{where}: need 0 <= low <= high <= 1, got [{a}, {b}]")
    if b - a < 0.05:
        raise ValueError(f"{where}: a drive window must cover at least 5% of the route, "
                         f"got [{a}, {b}]")
    return a, b


def _pairs(value: Any, where: str, conditions: Mapping[str, Any]) -> tuple[tuple[str, str], ...]:
    if value is None:
        raise ValueError(f"{where}: required (list of [reference, query] conditions)")
    pairs = []
    for item in value:
        items = [item] if isinstance(item, str) else list(item)
        if len(items) != 2:
            raise ValueError(f"{where}: each pair is [reference, query], got {item!r}")
        for name in items:
            if name not in conditions:
                raise ValueError(f"{where}: unknown condition {name!r} in pair {list(items)}; "
                                 f"known: {list(conditions)}")
        if items[0] == items[1]:
            raise ValueError(f"{where}: a pair needs two different conditions, got {items}")
        pairs.append((str(items[0]), str(items[1])))
    if len(set(pairs)) != len(pairs):
        raise ValueError(f"{where}: duplicate pairs in {pairs}")
    return tuple(pairs)


def novel_fraction(reference: tuple[float, float], query: tuple[float, float]) -> float:
    """Share of the query window ``[a, b]`` outside the reference window."""
    (r0, r1), (q0, q1) = reference, query
    overlap = max(0.0, min(r1, q1) - max(r0, q0))
    return 1.0 - overlap / (q1 - q0)


@dataclass(frozen=True)
class DataConfig:
    """The whole ``data`` node: world, camera, conditions, splits.

    Attributes
    ----------
    conditions : dict of str -> ConditionParams
        In label order (the index of a condition is its position).
    """

    kind: str
    image_size: tuple[int, int]
    supersample: int
    renderer: str
    train_per_condition: int
    world: WorldSpec
    camera: CameraSpec
    train: TrainSpec
    test: TestSpec
    conditions: dict[str, ConditionParams]

    @classmethod
    def from_config(cls, conf: Any) -> "DataConfig":
        """Read the ``data`` node of the composed config (DictConfig or plain mapping).

        The node is checked by the schema first (:func:`cmal_lcd.schema.validate`: unknown
        keys, types, ranges), then by the rules of this module.

        Raises
        ------
        ValueError
            Naming the key of any bad value (``data.world.size_m: must be > 0.0, got 0.0``).
        """
        from omegaconf import DictConfig, OmegaConf

        from cmal_lcd.schema import validate

        where = "data"
        if isinstance(conf, DictConfig):
            conf = OmegaConf.to_container(conf, resolve=True)
        conf = _mapping(conf, where)
        if conf.get("kind") != KIND:
            raise ValueError(f"{where}.kind: expected {KIND!r}, got {conf.get('kind')!r}")
        validate({where: conf})
        conditions_conf = _mapping(conf.pop("conditions", None), f"{where}.conditions")
        if not conditions_conf:
            raise ValueError(f"{where}.conditions: at least one condition is needed")
        conditions = {name: ConditionParams.from_config(name, c, where=f"{where}.conditions")
                      for name, c in conditions_conf.items()}
        world = WorldSpec.from_config(conf.pop("world", None), f"{where}.world")
        camera = CameraSpec.from_config(conf.pop("camera", None), f"{where}.camera")
        train = TrainSpec.from_config(conf.pop("train", None), f"{where}.train")
        test = TestSpec.from_config(conf.pop("test", None), world=world, conditions=conditions,
                                    where=f"{where}.test")
        values = {"kind": KIND, "renderer": _get(conf, "renderer", where),
                  "image_size": tuple(int(v) for v in _get(conf, "image_size", where)),
                  "supersample": int(_get(conf, "supersample", where)),
                  "train_per_condition": int(_get(conf, "train_per_condition", where))}
        if values["renderer"] not in RENDERER_NAMES:
            raise ValueError(f"{where}.renderer: unknown renderer {values['renderer']!r}; "
                             f"known: {list(RENDERER_NAMES)}")
        return cls(world=world, camera=camera, train=train, test=test, conditions=conditions,
                   **values)

    @property
    def condition_names(self) -> list[str]:
        """Condition names in label order."""
        return list(self.conditions)


def drive_name(route: str, condition: str) -> str:
    """Name of the drive of ``route`` under ``condition``: ``"route1/foggy"``."""
    return f"{route}/{condition}"


def pair_name(reference: str, query: str) -> str:
    """Name of a reference-query condition pair: ``"foggy-rainy"``."""
    return f"{reference}-{query}"
