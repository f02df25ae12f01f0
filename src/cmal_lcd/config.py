"""One source of configuration: Hydra's ``conf/``, composed into ``params.yaml`` for DVC.

DVC stages read ``params.yaml`` (:func:`load_params`); the Hydra app and the tests compose
``conf/`` directly (:func:`compose`). :func:`compose_params_yaml` writes the composition to
``params.yaml`` as DVC's own ``compose_and_dump`` writes it, byte-identical to what ``dvc exp
run`` writes when ``hydra.enabled`` is set (``tests/test_schema.py`` compares the two).

Commands work on the checkout they are run in (:func:`checkout_root`): ``cmal-lcd
compose-params`` and ``cmal-lcd-run`` read ``conf/`` and write ``params.yaml`` of the nearest
folder at or above the working directory that holds ``conf/config.yaml`` (or of ``--repo`` /
``$CMAL_LCD_REPO``), never of the folder the package was installed from.

Every composition and every ``params.yaml`` read is checked (:func:`check_config`): keys, types
and ranges against the typed schema (:mod:`cmal_lcd.schema`; the values stay in ``conf/``) and
the names that reach paths and DVC's shell commands (:func:`cmal_lcd.names.check_config_names`).
So ``cmal-lcd compose-params`` refuses a bad override before writing ``params.yaml``,
``cmal-lcd-run`` before its first step, and ``dvc exp run -S`` (DVC composes ``conf/`` itself,
without this package) in the first stage that reads the written ``params.yaml``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from omegaconf import DictConfig, OmegaConf

from cmal_lcd.checkout import (CONF_DIR, REPO_ENV, REPO_ROOT, CheckoutNotFoundError,  # noqa: F401
                               checkout_root)
from cmal_lcd.features.inputs import feature_inputs, register_resolver
from cmal_lcd.names import check_config_names
from cmal_lcd.schema import register_configs, validate

# ${cmal_lcd.feature_inputs:${methods}} in conf/config.yaml (also registered by Hydra's plugin
# scan through hydra_plugins.cmal_lcd_resolvers, for `dvc exp run`)
register_resolver()

PARAMS_FILE = REPO_ROOT / "params.yaml"


def command_conf_dir() -> Path:
    """``conf/`` of the working directory's checkout (:func:`checkout_root`), else the one this
    package was installed from: what ``match`` and ``loops`` compose."""
    try:
        return checkout_root() / "conf"
    except CheckoutNotFoundError:
        return CONF_DIR


def command_config(overrides: Sequence[str] = ()) -> DictConfig:
    """The config ``match`` and ``loops`` use: ``conf/`` of :func:`command_conf_dir` composed
    with ``overrides`` (their ``--config``, e.g. ``experiment=nordland``, ``matching.ds=5``).

    Raises
    ------
    ValueError
        One line, ``--config <overrides>: <why>`` when an override is to blame (an unknown
        group option or key, a value the schema refuses).
    """
    if not overrides:
        return compose(config_dir=command_conf_dir())
    try:
        return compose(list(overrides), config_dir=command_conf_dir())
    except Exception as err:  # noqa: BLE001 - Hydra's own errors too: one line naming the flag
        raise ValueError(f"--config {' '.join(overrides)}: {' '.join(str(err).split())}"
                         ) from None


def command_matching(overrides: Sequence[str] = ()) -> dict[str, Any]:
    """The ``matching`` node ``match`` and ``loops`` use, as plain values: with no
    ``overrides``, ``conf/matching/seqslam.yaml`` (:func:`cmal_lcd.matching.matching_defaults`,
    no Hydra: SAD matching stays light); else the ``matching`` node of :func:`command_config`
    with them (their ``--config``, e.g. ``experiment=nordland``)."""
    if not overrides:
        from cmal_lcd.matching import matching_defaults

        return matching_defaults()
    return OmegaConf.to_container(command_config(overrides).matching, resolve=True)


def check_config(cfg: Any) -> DictConfig:
    """``cfg`` typed by the schema (:func:`cmal_lcd.schema.validate`); refuse a composed config
    that breaks the schema or holds an unsafe name.

    Raises
    ------
    ValueError
        One line naming the key: ``matching.ds: must be >= 1, got 0``
        (:class:`cmal_lcd.schema.SchemaError`), or an unsafe name
        (:func:`cmal_lcd.names.check_config_names`).
    """
    typed = validate(cfg)
    check_config_names(typed)
    check_feature_inputs(typed)
    return typed


def check_feature_inputs(cfg: Any) -> None:
    """Every ``extractors`` node can make a method, every ``methods`` entry is a built-in or
    configured method, and ``feature_inputs`` is what ``methods`` derives
    (:mod:`cmal_lcd.features.inputs`).

    It is derived at composition; a hand-edited ``methods`` in ``params.yaml`` leaves it stale
    (DVC would then run the features stages of the old list).
    """
    from cmal_lcd.features import check_extractors, method_names
    from cmal_lcd.features.inputs import method_inputs

    extractors = cfg.get("extractors")
    if isinstance(extractors, DictConfig):
        extractors = OmegaConf.to_container(extractors, resolve=True)
    check_extractors(extractors)
    methods = list(cfg.get("methods") or [])
    if "methods" in cfg and not methods:
        raise ValueError("methods: empty; name at least one feature method (every table has "
                         "one row per method)")
    for i, method in enumerate(methods):
        if method in methods[:i]:
            first = methods.index(method)
            raise ValueError(f"methods[{i}]: {method!r} is listed twice (methods[{first}]); "
                             f"each method is one row of every table")
        if method not in method_names(extractors):
            raise ValueError(f"methods[{i}]: unknown feature method {method!r}; expected some "
                             f"of {method_names(extractors)} (or add an extractors.{method} "
                             f"node)")
        if extractors and method in extractors:
            method_inputs(method, extractors)  # its module's file must be found
    if "feature_inputs" not in cfg:
        return
    given = OmegaConf.to_container(cfg.feature_inputs, resolve=True) \
        if isinstance(cfg.feature_inputs, DictConfig) else cfg["feature_inputs"]
    derived = feature_inputs(cfg["methods"], extractors)
    if given != derived:
        raise ValueError(f"feature_inputs: {sorted(given)} is not what methods "
                         f"{list(cfg['methods'])} derives; it is derived at composition, never "
                         f"set by hand (run `cmal-lcd compose-params`)")


def load_params(path: str | Path = "params.yaml") -> DictConfig:
    """Load a composed ``params.yaml``, typed by the schema (:func:`check_config`).

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist (run ``cmal-lcd compose-params``).
    ValueError
        ``<path>: <key>: <what is wrong>`` (:func:`check_config`; the same class), or
        ``<path>: not a regular file (a FIFO) ...`` (:func:`cmal_lcd.io.check_regular_file`).
    """
    from cmal_lcd.io import check_regular_file

    path = Path(path)
    check_regular_file(path, what="the params file")  # a FIFO would block the read
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no such params file; compose it from conf/ with `cmal-lcd compose-params`"
        )
    cfg = OmegaConf.load(path)
    if not isinstance(cfg, DictConfig):
        raise ValueError(f"{path}: expected a mapping at the top level")
    try:
        return check_config(cfg)
    except ValueError as err:
        raise type(err)(f"{path}: {err}") from None


def hydra_composition(overrides: Sequence[str] = (), *, config_dir: str | Path = CONF_DIR,
                      config_name: str = "config") -> DictConfig:
    """``conf/<config_name>.yaml`` composed by Hydra with ``overrides`` and resolved, unchecked:
    what DVC's ``compose_and_dump`` writes to ``params.yaml`` (``dvc exp run -S``)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(Path(config_dir).resolve()), version_base="1.3"):
        cfg = hydra_compose(config_name=config_name, overrides=list(overrides))
    OmegaConf.resolve(cfg)
    return cfg


def compose(overrides: Sequence[str] = (), *, config_dir: str | Path = CONF_DIR,
            config_name: str = "config") -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with Hydra overrides, resolved and typed by the
    schema (:func:`check_config`); closed to new keys, as Hydra composes it.

    Parameters
    ----------
    overrides : sequence of str
        Hydra overrides, e.g. ``["debug=tiny", "matching.ds=5"]``.
    """
    register_configs()  # here, not at import: reading params.yaml must not import Hydra
    typed = check_config(hydra_composition(overrides, config_dir=config_dir,
                                           config_name=config_name))
    OmegaConf.set_struct(typed, True)
    return typed


def compose_params_yaml(overrides: Sequence[str] = (), *, output: str | Path = PARAMS_FILE,
                        config_dir: str | Path = CONF_DIR, config_name: str = "config") -> Path:
    """Write the composition of ``conf/`` (plus overrides) to ``output`` as DVC does: composed
    once (:func:`hydra_composition`), checked (:func:`check_config`) before anything is
    written, then written as DVC's ``compose_and_dump`` writes it (``OmegaConf.to_yaml``), so
    that ``dvc exp run`` finds it unchanged."""
    from cmal_lcd.io import atomic_write_text

    register_configs()
    cfg = hydra_composition(overrides, config_dir=config_dir, config_name=config_name)
    check_config(cfg)
    output = Path(output)
    atomic_write_text(output, OmegaConf.to_yaml(cfg))
    return output
