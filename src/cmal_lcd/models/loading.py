"""Model classes by name, a fresh model by name, a trained model from ``model.pt``."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Mapping

import torch

from cmal_lcd.models.base import GANModel
from cmal_lcd.models.config import TrainingConfig, model_config


def model_class(config: type[TrainingConfig]) -> type[GANModel]:
    """The class ``config.model_class`` names (``"module.Class"``), imported."""
    module, _, name = config.model_class.rpartition(".")
    cls = getattr(importlib.import_module(module), name)
    if not (isinstance(cls, type) and issubclass(cls, GANModel)) or cls.name != config.name:
        raise TypeError(f"{config.__name__}.model_class: {config.model_class} is not a GANModel "
                        f"named {config.name!r}")
    return cls


def model_classes(configs: Mapping[str, type[TrainingConfig]]) -> dict[str, type[GANModel]]:
    """``{name: class}`` of every model config (:data:`cmal_lcd.models.MODEL_CONFIGS`)."""
    return {name: model_class(config) for name, config in configs.items()}


def _plain(cfg: Any) -> Any:
    from cmal_lcd.models.training import _plain as plain

    return plain(cfg)


def build_model(name: str, cfg: TrainingConfig | Mapping[str, Any], *, image_size: int,
                n_conditions: int, seed: int | None = None) -> GANModel:
    """A freshly initialised model by name.

    Parameters
    ----------
    name : str
        One of :data:`cmal_lcd.models.MODEL_NAMES` (``cmal``, ``bigan``, ``cmal_place``,
        ``place_encoder``).
    cfg : TrainingConfig or mapping
        The model's config, ``models.<name>`` (``conf/model/<name>.yaml``): its config
        dataclass, or a mapping checked into one (:func:`~cmal_lcd.models.config.model_config`;
        ``SchemaError`` naming the key).
    image_size : int
        Side of the square input (power of two >= 8).
    n_conditions : int
        Number of weather conditions (``len(dataset.json["conditions"])``).
    seed : int, optional
        When given, the initial weights come from ``torch.manual_seed(seed)`` inside a forked
        RNG (the global torch RNG is left untouched); otherwise from the global RNG.

    Returns
    -------
    GANModel
        In train mode, on the CPU.
    """
    from cmal_lcd.models import MODELS

    config = cfg if isinstance(cfg, TrainingConfig) else model_config(name, _plain(cfg))
    if config.name != name:
        raise ValueError(f"cfg: a {type(config).__name__} (model {config.name!r}), not the "
                         f"config of {name!r}")
    if seed is None:
        return MODELS[name](config, image_size=image_size, n_conditions=n_conditions)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return MODELS[name](config, image_size=image_size, n_conditions=n_conditions)


def load_trained(path: str | Path, *, device: str = "cpu") -> tuple[GANModel, dict]:
    """Load a model written by :func:`cmal_lcd.models.training.train_model`.

    Parameters
    ----------
    path : path
        ``models/<name>/`` or its ``model.pt``.
    device : str
        Where to put the weights (``cpu``, ``cuda``).

    Returns
    -------
    model : GANModel
        In eval mode on ``device``.
    meta : dict
        ``name, config, conditions, image_size, iteration`` (and ``seed``).

    Raises
    ------
    FileNotFoundError
        When ``path`` has no ``model.pt``.
    ValueError
        When the file is not a model written by ``train_model``.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "model.pt"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no trained model here (run the train stage)")
    state = torch.load(path, map_location=device, weights_only=True)
    missing = [k for k in ("name", "config", "conditions", "image_size", "state_dict",
                           "iteration") if k not in state]
    if missing:
        raise ValueError(f"{path}: not a trained model file (missing {missing})")
    model = build_model(state["name"], state["config"], image_size=int(state["image_size"]),
                        n_conditions=len(state["conditions"]))
    model.load_state_dict(state["state_dict"])
    model.to(device).eval()
    meta = {k: v for k, v in state.items() if k != "state_dict"}
    return model, meta
