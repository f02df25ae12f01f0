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

Your own method needs no edit here: one file and one ``extractors.<name>`` config node
(:mod:`cmal_lcd.features.custom`; docs/extending.md). Every function below takes a method of
``extractors`` beside the built-in ones.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from cmal_lcd.features.base import FeatureExtractor, check_finite_codes
from cmal_lcd.features.custom import build_custom, check_extractor_node
from cmal_lcd.features.dnn import (build_dnn, build_dnn_head, choose_on_validation,
                                   with_choice)
from cmal_lcd.features.learned import (build_bigan, build_cmal, build_cmal_untrained,
                                      build_trained)
from cmal_lcd.features.sad import build_sad

__all__ = ["FeatureExtractor", "METHODS", "METHOD_MODELS", "METHOD_NAMES", "Method",
           "TRAINED_METHODS",
           "build_extractor", "check_finite_codes", "extractor_conf", "method_entry",
           "method_names"]


def _plain(node: Any) -> Any:
    """A plain Python copy of an OmegaConf node (or the value itself)."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        return node
    if isinstance(node, (DictConfig, ListConfig)):
        return OmegaConf.to_container(node, resolve=True)
    return node


def _sad_extra(cfg: Mapping[str, Any], dataset_meta: Mapping[str, Any] | None) -> dict[str, Any]:
    """``sad``: the thumbnail parameters live in ``matching.sad`` (shared with SeqSLAM)."""
    return {"sad": _plain(cfg["matching"]["sad"])}


def _cmal_untrained_extra(cfg: Mapping[str, Any],
                          dataset_meta: Mapping[str, Any] | None) -> dict[str, Any]:
    """``cmal_untrained``: the CMAL model config, the seed, and sizes from ``dataset.json``."""
    if dataset_meta is None:
        raise ValueError("dataset_meta: cmal_untrained needs dataset.json (conditions, image_size)")
    model_conf = _plain(cfg["models"]["cmal"])
    image_size = model_conf.get("image_size") if isinstance(model_conf, dict) else None
    return {
        "model": model_conf,
        "seed": int(cfg["seed"]),
        "n_conditions": len(dataset_meta["conditions"]),
        "image_size": _plain(image_size if image_size is not None else dataset_meta["image_size"]),
    }


@dataclass(frozen=True)
class Method:
    """A registry entry.

    Attributes
    ----------
    build : callable
        ``build(conf, *, model_dir=None, device="cpu") -> FeatureExtractor``.
    extra_conf : callable, optional
        ``extra_conf(cfg, dataset_meta) -> dict`` of keys merged into the ``features`` node
        for this method (see :func:`extractor_conf`).
    model : str, optional
        The trained model whose ``models/<model>/model.pt`` the method reads (None: none).
    own_file : str, optional
        For a method without a trained model: the source file its codes depend on beyond
        the shared features code (``dvc.yaml`` needs one file per method).
    params : tuple of str
        Config nodes the method reads beyond those every features stage reads
        (:data:`cmal_lcd.features.inputs.COMMON_PARAMS`).
    trained : bool
        Its codes come from weights the pipeline trains (the learned rows a sweep's objective
        averages).
    choose : callable, optional
        ``choose(cfg, conf, dataset, *, device, method) -> (selection | None, codes)``: what the
        method chooses on the validation drives (``dnn``: its layer and input side), recorded
        as ``layer_selection`` in ``info.json``.
    apply_choice : callable, optional
        ``apply_choice(conf, selection) -> conf``: the conf that builds the chosen extractor
        (with ``choose``).
    """

    build: Callable[..., FeatureExtractor]
    extra_conf: (Callable[[Mapping[str, Any], Mapping[str, Any] | None], dict[str, Any]]
                 | None) = None
    model: str | None = None
    own_file: str | None = None
    params: tuple[str, ...] = ()
    trained: bool = False
    choose: Callable[..., tuple[dict[str, Any] | None, dict[str, Any]]] | None = None
    apply_choice: Callable[[Mapping[str, Any], Mapping[str, Any] | None],
                           dict[str, Any]] | None = None


#: Feature methods by name, in the order of the paper's tables.
METHODS: dict[str, Method] = {
    "sad": Method(build_sad, _sad_extra, own_file="src/cmal_lcd/features/sad.py",
                  params=("matching.sad",)),
    # dnn chooses its layer and side, dnn_head its side, on the validation drives: the
    # validation monitor reads `matching`
    "dnn": Method(build_dnn, own_file="src/cmal_lcd/features/dnn.py",
                  params=("features.dnn", "matching"), choose=choose_on_validation,
                  apply_choice=with_choice),
    "dnn_head": Method(build_dnn_head, own_file="src/cmal_lcd/features/dnn.py",
                       params=("features.dnn", "matching"), choose=choose_on_validation,
                       apply_choice=with_choice),
    "bigan": Method(build_bigan, model="bigan", trained=True),
    "cmal": Method(build_cmal, model="cmal", trained=True),
    # the random encoder, under the trained CMAL classifier's weather decision
    "cmal_untrained": Method(build_cmal_untrained, _cmal_untrained_extra, model="cmal",
                             params=("models.cmal",)),
    # extensions (not the paper): place supervision, and its ablation without the GAN
    "cmal_place": Method(functools.partial(build_trained, "cmal_place"), model="cmal_place",
                         trained=True),
    "place_encoder": Method(functools.partial(build_trained, "place_encoder"),
                            model="place_encoder", trained=True),
}

#: The method names accepted by :func:`build_extractor`.
METHOD_NAMES: tuple[str, ...] = tuple(METHODS)

#: The trained model each learned method loads (``<models>/<model>/model.pt``).
METHOD_MODELS: dict[str, str] = {name: m.model for name, m in METHODS.items() if m.model}

#: The methods whose codes come from trained weights (``Method.trained``).
TRAINED_METHODS: tuple[str, ...] = tuple(name for name, m in METHODS.items() if m.trained)


def _custom_extra(cfg: Mapping[str, Any], dataset_meta: Mapping[str, Any] | None,
                  name: str) -> dict[str, Any]:
    """A user's method: its name, its ``extractors.<name>`` node and the seed."""
    return {"name": name, "extractor": _plain(cfg["extractors"][name]), "seed": int(cfg["seed"])}


def method_entry(name: str, extractors: Mapping[str, Any] | None = None) -> Method:
    """The registry entry of ``name``: a built-in one, or the user's method of
    ``extractors[name]`` (its stage reads the node ``extractors.<name>``).

    Raises
    ------
    ValueError
        ``name: unknown feature method ...`` listing the built-in and configured names.
    """
    if name in METHODS:
        return METHODS[name]
    if extractors is not None and name in extractors:
        return Method(build_custom, functools.partial(_custom_extra, name=name),
                      params=method_params(name))
    raise ValueError(f"name: unknown feature method {name!r}; expected one of "
                     f"{method_names(extractors)}")


def method_params(name: str) -> tuple[str, ...]:
    """The config nodes method ``name`` reads beyond the common ones: a built-in method's
    ``params``, a user's method's node ``extractors.<name>``."""
    return METHODS[name].params if name in METHODS else (f"extractors.{name}",)


def method_names(extractors: Mapping[str, Any] | None = None) -> list[str]:
    """The built-in names (:data:`METHOD_NAMES`), then those of ``extractors``."""
    return [*METHOD_NAMES, *(str(k) for k in (extractors or {}) if str(k) not in METHODS)]


def check_extractors(extractors: Mapping[str, Any] | None) -> None:
    """Refuse an ``extractors`` node that shadows a built-in name or cannot make a method.

    Raises
    ------
    ValueError
        ``extractors.<name>...`` naming the key (:func:`~.custom.check_extractor_node`).
    """
    for name, node in (extractors or {}).items():
        if name in METHODS:
            raise ValueError(f"extractors.{name}: {name!r} is a built-in method; give yours "
                             f"another name")
        check_extractor_node(str(name), _plain(node))


def extractor_conf(cfg: Mapping[str, Any], name: str, *,
                   dataset_meta: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ``conf`` for :func:`build_extractor`: ``cfg.features`` plus what ``name`` needs.

    Parameters
    ----------
    cfg : mapping
        The composed config (``params.yaml``), checked by the schema
        (:func:`cmal_lcd.config.check_config`: its keys, types and ranges).
    name : str
        A method name.
    dataset_meta : mapping, optional
        ``dataset.json`` contents; needed by ``cmal_untrained``.

    Returns
    -------
    dict
        Plain Python values.
    """
    method = method_entry(name, cfg.get("extractors"))
    conf = dict(_plain(cfg["features"]))
    if method.extra_conf is not None:
        conf.update(method.extra_conf(cfg, dataset_meta))
    return conf


def build_extractor(name: str, *, conf: Mapping[str, Any], model_dir: str | Path | None = None,
                    device: str = "cpu") -> FeatureExtractor:
    """Build the feature extractor ``name``.

    Parameters
    ----------
    name : str
        One of :data:`METHOD_NAMES`, or a user's method (``conf["extractor"]`` holds its node).
    conf : mapping
        The ``features`` config node merged with what the method needs
        (:func:`extractor_conf` builds it).
    model_dir : path, optional
        Folder holding ``<name>/model.pt`` for trained methods (``models/``).
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
    return method.build(conf, model_dir=Path(model_dir) if model_dir is not None else None,
                        device=device)
