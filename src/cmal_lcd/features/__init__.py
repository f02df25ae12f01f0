"""Per-frame feature extractors, picked by name.

=================  ==========================  ===========  =============================
name               label                       metric       code
=================  ==========================  ===========  =============================
``sad``            SAD                         sad          float32 (height*width,) z-scores
``dnn``            DNN (VGG16 fc6) or          sqeuclidean  float32 4096 (VGG16 fc6/fc7) or
                   DNN (EfficientNet-Lite0,                 C*4*4 (an EfficientNet-Lite0 block
                   block k, 4x4, S px)                      at S px input, chosen on validation)
``dnn_head``       DNN (VGG16 fc7) or          sqeuclidean  float32 4096 (VGG16 fc7) or 1280
                   DNN (EfficientNet-Lite0,                 (EfficientNet-Lite0 global-pooled
                   pooled head, S px)                       head at a side chosen on
                                                            validation); ablation of ``dnn``
``bigan``          BiGAN                       sqeuclidean  float32 1024, trained E(x)
``cmal``           CMAL                        sqeuclidean  float32 1024, trained En(x|C(x))
``cmal_untrained`` CMAL (untrained control)    sqeuclidean  float32 1024, random init
``cmal_place``     CMAL (+ ...) + place        sqeuclidean  float32 1024, trained
                   (extension)                              En(x|C(x)) with place
                                                            supervision (not the paper)
``place_encoder``  place encoder (ablation:    sqeuclidean  float32 1024, CMAL's C and En
                   place term alone, no GAN)                trained on the place term alone
=================  ==========================  ===========  =============================

Every method, built-in or yours, is a node of ``extractors``, declared the same way: the
built-in ones in ``conf/extractors/builtin.yaml`` (:data:`BUILT_IN_FILE`), each a node whose
``_target_`` is :class:`Method` (a method with capabilities: a trained model it reads, a
choice it makes on the validation drives, the config nodes it reads); yours in your config,
with that ``_target_`` too or with any class or function of yours that makes an encoder
(:mod:`cmal_lcd.features.custom`; docs/extending.md). Every function below takes the composed
``extractors`` node; without it, the built-in nodes of :data:`BUILT_IN_FILE`.
"""

from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable, Mapping

from cmal_lcd.features.base import FeatureExtractor, check_finite_codes
from cmal_lcd.features.custom import TARGET, build_custom, check_extractor_node

__all__ = ["BUILT_IN_FILE", "FeatureExtractor", "METHOD_TARGET", "Method", "build_extractor",
           "built_in_nodes", "check_finite_codes", "configured_extractor", "configured_method",
           "configured_node",
           "extractor_conf", "located", "method_entry", "method_model", "method_names",
           "method_params", "trained_methods"]

#: The built-in methods' nodes (the package's ``conf/``).
BUILT_IN_FILE = Path(__file__).resolve().parents[3] / "conf" / "extractors" / "builtin.yaml"
#: The ``_target_`` of a node that declares a :class:`Method` (anything else is an encoder).
METHOD_TARGET = "cmal_lcd.features.Method"


def _plain(node: Any) -> Any:
    """A plain Python copy of an OmegaConf node (or the value itself)."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        return node
    if isinstance(node, (DictConfig, ListConfig)):
        return OmegaConf.to_container(node, resolve=True)
    return node


def located(function: Callable | str) -> Callable:
    """``function``, or the function a ``"module.function"`` path names (imported)."""
    if callable(function):
        return function
    module, _, name = str(function).rpartition(".")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Method:
    """A method with capabilities: the node ``{_target_: cmal_lcd.features.Method, ...}``.

    The callables may be given as ``"module.function"`` paths (as in ``conf/``): they are
    imported when first called (:func:`located`), so that composing the config imports no
    method's code.

    Attributes
    ----------
    build : callable or str
        ``build(conf, *, model_dir=None, device="cpu") -> FeatureExtractor``.
    extra_conf : callable or str, optional
        ``extra_conf(cfg, dataset_meta) -> dict`` of keys merged into the ``features`` node
        for this method (see :func:`extractor_conf`).
    model : str, optional
        The trained model whose ``models/<model>/model.pt`` the method reads (None: none); its
        conf then holds ``trained_model: <model>``.
    own_file : str, optional
        For a method without a trained model: the source file its codes depend on beyond
        the shared features code (``dvc.yaml`` needs one file per method).
    params : tuple of str
        Config nodes the method reads beyond those every features stage reads (the
        ``extract_features`` params of ``dvc.yaml``) and its own node.
    trained : bool
        Its codes come from weights the pipeline trains (the learned rows a sweep's objective
        averages).
    choose : callable or str, optional
        ``choose(cfg, conf, dataset, *, device, method) -> (selection | None, codes)``: what the
        method chooses on the validation drives (``dnn``: its layer and input side), recorded
        as ``layer_selection`` in ``info.json``.
    apply_choice : callable or str, optional
        ``apply_choice(conf, selection) -> conf``: the conf that builds the chosen extractor
        (with ``choose``).
    """

    build: Callable[..., FeatureExtractor] | str
    extra_conf: (Callable[[Mapping[str, Any], Mapping[str, Any] | None], dict[str, Any]]
                 | str | None) = None
    model: str | None = None
    own_file: str | None = None
    params: tuple[str, ...] = ()
    trained: bool = False
    choose: Callable[..., tuple[dict[str, Any] | None, dict[str, Any]]] | str | None = None
    apply_choice: Callable[[Mapping[str, Any], Mapping[str, Any] | None],
                           dict[str, Any]] | str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", tuple(self.params))


#: The keys of a :class:`Method` node beside ``_target_``.
METHOD_KEYS = tuple(f.name for f in fields(Method))


@functools.cache
def built_in_nodes() -> dict[str, dict[str, Any]]:
    """The built-in methods' nodes, by name, as :data:`BUILT_IN_FILE` declares them."""
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(BUILT_IN_FILE))


def __getattr__(name: str) -> Any:
    """``METHOD_NAMES``: the built-in names, in :data:`BUILT_IN_FILE`'s order (read when first
    asked for)."""
    if name == "METHOD_NAMES":
        return tuple(built_in_nodes())
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _nodes(extractors: Mapping[str, Any] | None) -> Mapping[str, Any]:
    """The composed ``extractors`` node, or the built-in nodes when None."""
    return built_in_nodes() if extractors is None else extractors


def method_from_node(name: str, node: Mapping[str, Any]) -> Method:
    """The :class:`Method` of a node of ``extractors``: declared by the node (its ``_target_``
    is :data:`METHOD_TARGET`), or an encoder of yours (:func:`~.custom.build_custom`)."""
    node = _plain(node)
    if node.get(TARGET) == METHOD_TARGET:
        return Method(**{k: v for k, v in node.items() if k != TARGET})
    return Method(build_custom, functools.partial(_custom_extra, name=name),
                  params=(f"extractors.{name}",))


def _custom_extra(cfg: Mapping[str, Any], dataset_meta: Mapping[str, Any] | None,
                  name: str) -> dict[str, Any]:
    """An encoder of yours: its name, its ``extractors.<name>`` node and the seed."""
    return {"name": name, "extractor": _plain(cfg["extractors"][name]), "seed": int(cfg["seed"])}


def method_entry(name: str, extractors: Mapping[str, Any] | None = None) -> Method:
    """The :class:`Method` of ``extractors[name]`` (default: the built-in nodes).

    Raises
    ------
    ValueError
        ``name: unknown feature method ...`` listing the configured names.
    """
    nodes = _nodes(extractors)
    if name not in nodes:
        raise ValueError(f"name: unknown feature method {name!r}; expected one of "
                         f"{method_names(extractors)}")
    return method_from_node(name, nodes[name])


def configured_node(cfg: Mapping[str, Any], name: str) -> Any:
    """``cfg.extractors.<name>`` as plain values, reading no other node (a stage's config slice
    holds its own only); the built-in node when ``cfg`` has no ``extractors``.

    Raises
    ------
    ValueError
        ``name: unknown feature method ...``.
    """
    extractors = cfg.get("extractors")
    nodes = extractors if extractors is not None else built_in_nodes()
    if name not in nodes:
        raise ValueError(f"name: unknown feature method {name!r}; expected one of "
                         f"{method_names(_plain(extractors))}")
    return _plain(nodes[name])


def configured_method(cfg: Mapping[str, Any], name: str) -> Method:
    """The :class:`Method` of ``name`` in the composed ``cfg`` (:func:`configured_node`)."""
    return method_from_node(name, configured_node(cfg, name))


def method_params(name: str, extractors: Mapping[str, Any] | None = None) -> tuple[str, ...]:
    """The config nodes method ``name`` reads beyond the common ones: a :class:`Method`'s
    ``params``, an encoder's own node ``extractors.<name>``."""
    return method_entry(name, extractors).params


def method_model(name: str, extractors: Mapping[str, Any] | None = None) -> str | None:
    """The trained model whose weights method ``name`` reads (``Method.model``), or None
    (also for a name that is not configured)."""
    nodes = _nodes(extractors)
    return method_entry(name, extractors).model if name in nodes else None


def needs_two_conditions(cfg: Mapping[str, Any]) -> bool:
    """Whether a method of ``cfg.methods`` reads a model that learns every condition (its
    config dataclass's ``conditional``: CMAL), so that the training frames need two conditions;
    True when ``methods`` is not given (what the ``dataset`` stage asks of folders)."""
    from cmal_lcd.models import MODEL_CONFIGS

    methods = cfg.get("methods")
    if methods is None:
        return True
    extractors = _plain(cfg.get("extractors"))
    models = {method_model(str(m), extractors) for m in methods}
    return any(MODEL_CONFIGS[m].conditional for m in models if m in MODEL_CONFIGS)


def trained_methods(extractors: Mapping[str, Any] | None = None) -> tuple[str, ...]:
    """The methods whose codes come from weights the pipeline trains (``Method.trained``)."""
    return tuple(name for name in _nodes(extractors)
                 if method_entry(name, extractors).trained)


def method_names(extractors: Mapping[str, Any] | None = None) -> list[str]:
    """The names of ``extractors`` (default: the built-in ones)."""
    return [str(k) for k in _nodes(extractors)]


def check_extractors(extractors: Mapping[str, Any] | None) -> None:
    """Refuse an ``extractors`` node that cannot make a method, naming the key.

    Raises
    ------
    ValueError
        ``extractors.<name>...`` naming the key: of a :class:`Method` node, an unknown key or
        a value of the wrong type; of an encoder's node, as
        :func:`~.custom.check_extractor_node`.
    """
    for name, node in (extractors or {}).items():
        node = _plain(node)
        if isinstance(node, Mapping) and node.get(TARGET) == METHOD_TARGET:
            check_method_node(str(name), node)
        else:
            check_extractor_node(str(name), node)


def check_method_node(name: str, node: Mapping[str, Any]) -> None:
    """Refuse a :class:`Method` node with an unknown key, no ``build``, or a value of the
    wrong type, naming ``extractors.<name>.<key>``."""
    where = f"extractors.{name}"
    unknown = sorted(str(k) for k in node if k != TARGET and k not in METHOD_KEYS)
    if unknown:
        raise ValueError(f"{where}.{unknown[0]}: not a key of a {METHOD_TARGET} node; known: "
                         f"{list(METHOD_KEYS)}")
    for key in ("build", "extra_conf", "choose", "apply_choice", "model", "own_file"):
        value = node.get(key)
        if (key == "build" or value is not None) and (
                not isinstance(value, str) or (key not in ("model", "own_file")
                                               and "." not in value)):
            raise ValueError(f"{where}.{key}: expected a "
                             f"{'string' if key in ('model', 'own_file') else 'module.function'}"
                             f", got {value!r}")
    params = node.get("params", [])
    if not isinstance(params, list) or not all(isinstance(p, str) for p in params):
        raise ValueError(f"{where}.params: expected a list of config keys, got {params!r}")
    if not isinstance(node.get("trained", False), bool):
        raise ValueError(f"{where}.trained: expected true or false, got {node['trained']!r}")
    if node.get("model") is None and node.get("own_file") is None:
        raise ValueError(f"{where}: a {METHOD_TARGET} node needs `model` (the trained weights "
                         f"it reads) or `own_file` (the file its codes depend on)")


def extractor_conf(cfg: Mapping[str, Any], name: str, *,
                   dataset_meta: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ``conf`` for :func:`build_extractor`: ``cfg.features`` plus what ``name`` needs.

    Parameters
    ----------
    cfg : mapping
        The composed config (``params.yaml``), checked by the schema
        (:func:`cmal_lcd.config.check_config`: its keys, types and ranges).
    name : str
        A node of ``cfg.extractors``.
    dataset_meta : mapping, optional
        ``dataset.json`` contents; needed by ``cmal_untrained``.

    Returns
    -------
    dict
        Plain Python values: the ``features`` node, ``method`` (the name), the node itself
        (``extractor``), ``trained_model`` when the method reads one, and what its
        ``extra_conf`` adds.
    """
    node = configured_node(cfg, name)
    method = method_from_node(name, node)
    conf = {**_plain(cfg["features"]), "method": name, "extractor": node}
    if method.model is not None:
        conf["trained_model"] = method.model
    if method.extra_conf is not None:
        conf.update(located(method.extra_conf)(cfg, dataset_meta))
    return conf


def build_extractor(name: str, *, conf: Mapping[str, Any], model_dir: str | Path | None = None,
                    device: str = "cpu") -> FeatureExtractor:
    """Build the feature extractor ``name``.

    Parameters
    ----------
    name : str
        A node of ``extractors``: ``conf["extractor"]`` when given (:func:`extractor_conf`),
        else the built-in node of that name.
    conf : mapping
        The ``features`` config node merged with what the method needs
        (:func:`extractor_conf` builds it).
    model_dir : path, optional
        Folder holding ``<model>/model.pt`` for methods that read a trained model (``models/``).
    device : str
        Torch device, ``"cpu"`` by default.

    Returns
    -------
    FeatureExtractor
        ``extractor(images uint8 (N, H, W, 3)) -> (N, F)``.

    Raises
    ------
    ValueError
        Naming ``name`` when unknown, or the missing parameter/file.
    """
    conf = _plain(conf)
    if not isinstance(conf, Mapping):
        raise ValueError(f"conf: expected a mapping, got {type(conf).__name__}")
    method = method_entry(name, {name: conf["extractor"]} if "extractor" in conf else None)
    if method.model is not None and "trained_model" not in conf:
        conf = {**conf, "trained_model": method.model}
    return located(method.build)(conf, model_dir=Path(model_dir) if model_dir is not None
                                 else None, device=device)


def configured_extractor(cfg: Mapping[str, Any], name: str, *,
                         model_dir: str | Path | None, device: str,
                         choice: Mapping[str, Any] | None = None,
                         dataset_meta: Mapping[str, Any] | None = None
                         ) -> tuple[FeatureExtractor, dict[str, Any]]:
    """``name``'s extractor as the composed config ``cfg`` declares it, and its conf.

    ``choice``: what the method chose on the validation drives (``Method.choose``: ``dnn``'s
    layer and input side), applied by its ``apply_choice``. The one call the
    ``extract_features`` stage and ``cmal-lcd match``/``loops``
    (:func:`cmal_lcd.workflows.folder_features.feature_function`) make.
    """
    entry = configured_method(cfg, name)
    conf = extractor_conf(cfg, name, dataset_meta=dataset_meta)
    if choice is not None and entry.apply_choice is not None:
        conf = located(entry.apply_choice)(conf, choice)
    return build_extractor(name, conf=conf, model_dir=model_dir, device=device), conf
