"""CMAL and BiGAN: networks, update rules, the shared training loop and checkpoints.

Public API
----------
- :data:`MODEL_CONFIGS`: each model's config dataclass by name (no torch: the schema reads it);
- :data:`MODELS`: the model classes by name, :func:`build_model` ``(name, cfg, *, image_size,
  n_conditions)`` -> ``nn.Module`` with ``encode(x (N, 3, S, S) in [-1, 1]) -> (N, code_dim)``;
- :func:`load_trained` ``(path, *, device="cpu")`` -> ``(model, meta)``;
- :func:`preprocess` ``(images uint8 (N, H, W, 3), *, image_size)`` -> float32 ``(N, 3, S, S)``;
- :func:`train_model` trains and writes ``model.pt``.

Importing this package does not import torch: every name but :data:`MODEL_CONFIGS` and
:data:`MODEL_NAMES` is imported from its module when first used (PEP 562).

Add a model: its class (a :class:`GANModel`), its config dataclass (a subclass of
:class:`~cmal_lcd.models.config.TrainingConfig` naming the class, in a module without torch)
and an entry below; ``conf/model/<name>.yaml`` holds its values (docs/architecture.md).
"""

from __future__ import annotations

import importlib
from typing import Any

from cmal_lcd.models.bigan_config import BiganConfig
from cmal_lcd.models.cmal_config import CmalConfig, CmalPlaceConfig, PlaceEncoderConfig
from cmal_lcd.models.config import TrainingConfig

#: Every model's config dataclass, by model name (the keys of ``models`` in the config).
MODEL_CONFIGS: dict[str, type[TrainingConfig]] = {config.name: config for config in (
    CmalConfig, BiganConfig, CmalPlaceConfig, PlaceEncoderConfig)}
MODEL_NAMES = tuple(MODEL_CONFIGS)

#: Names imported from their module when first used.
_LAZY = {
    "GANModel": "base", "TrainingBatch": "base",
    "BiGAN": "bigan",
    "CMAL": "cmal", "CMALPlace": "cmal", "PlaceEncoder": "cmal",
    "condition_accuracy": "cmal", "reconstruct_and_translate": "cmal",
    "pick_device": "device",
    "preprocess": "images", "to_uint8": "images",
    "build_model": "loading", "load_trained": "loading",
    "TrainingDivergedError": "training", "heldout_split": "training", "train_model": "training",
}

__all__ = ["MODELS", "MODEL_CONFIGS", "MODEL_NAMES", *_LAZY]


def __getattr__(name: str) -> Any:
    """``MODELS`` and the names of :data:`_LAZY`, imported when first asked for."""
    if name == "MODELS":
        from cmal_lcd.models.loading import model_classes

        found = model_classes(MODEL_CONFIGS)
    elif name in _LAZY:
        found = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = found
    return found
