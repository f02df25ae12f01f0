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
=================  ==========================  ===========  =============================

Add a method with one builder ``build_x(conf, *, model_dir=None, device="cpu") ->
FeatureExtractor`` and one :data:`METHODS` entry (plus, when it needs more than the
``features`` config node, a function giving those extra keys).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from cmal_lcd.features.base import FeatureExtractor, check_finite_codes
from cmal_lcd.features.dnn import build_dnn, build_dnn_head
from cmal_lcd.features.learned import build_bigan, build_cmal, build_cmal_untrained
from cmal_lcd.features.sad import build_sad

__all__ = ["FeatureExtractor", "METHODS", "METHOD_MODELS", "METHOD_NAMES", "Method",
           "build_extractor", "check_finite_codes", "extractor_conf"]


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
    """

    build: Callable[..., FeatureExtractor]
    extra_conf: (Callable[[Mapping[str, Any], Mapping[str, Any] | None], dict[str, Any]]
                 | None) = None
    model: str | None = None
    own_file: str | None = None
    params: tuple[str, ...] = ()


#: Feature methods by name, in the order of the paper's tables.
METHODS: dict[str, Method] = {
    "sad": Method(build_sad, _sad_extra, own_file="src/cmal_lcd/features/sad.py",
                  params=("matching.sad",)),
    # dnn chooses its layer and side, dnn_head its side, on the validation drives: the
    # validation monitor reads `matching`
    "dnn": Method(build_dnn, own_file="src/cmal_lcd/features/dnn.py",
                  params=("features.dnn", "matching")),
    "dnn_head": Method(build_dnn_head, own_file="src/cmal_lcd/features/dnn.py",
                       params=("features.dnn", "matching")),
    "bigan": Method(build_bigan, model="bigan"),
    "cmal": Method(build_cmal, model="cmal"),
    # the random encoder, under the trained CMAL classifier's weather decision
    "cmal_untrained": Method(build_cmal_untrained, _cmal_untrained_extra, model="cmal",
                             params=("models.cmal",)),
}

#: The method names accepted by :func:`build_extractor`.
METHOD_NAMES: tuple[str, ...] = tuple(METHODS)

#: The trained model each learned method loads (``<models>/<model>/model.pt``).
METHOD_MODELS: dict[str, str] = {name: m.model for name, m in METHODS.items() if m.model}


def _method(name: str) -> Method:
    if name not in METHODS:
        raise ValueError(f"name: unknown feature method {name!r}; expected one of {METHOD_NAMES}")
    return METHODS[name]


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
    method = _method(name)
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
        One of :data:`METHOD_NAMES`.
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
    method = _method(name)
    conf = _plain(conf)
    if not isinstance(conf, Mapping):
        raise ValueError(f"conf: expected a mapping, got {type(conf).__name__}")
    return method.build(conf, model_dir=Path(model_dir) if model_dir is not None else None,
                        device=device)
