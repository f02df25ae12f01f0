"""The learned methods: trained BiGAN and CMAL encoders, and the untrained CMAL control.

``bigan`` and ``cmal`` load ``<model_dir>/<name>/model.pt`` with ``cmal_lcd.models.load_trained``
and encode frames with ``model.encode(preprocess(images, image_size=meta["image_size"]))``
(CMAL: ``En(x | C(x))``). ``cmal_untrained`` builds the same CMAL network from the config with
the seed-determined random initialisation and no training, so a reader sees what training adds.
The control is encoded like trained CMAL: under the *trained* classifier's decision,
``En_untrained(x | C_trained(x))`` (an untrained classifier calls every frame the same weather,
which would feed the control a condition input trained CMAL never gets); only the encoder is
untrained. Without a trained CMAL model it falls back to its own untrained classifier and says
so in its ``weights`` description.
All codes are float32, 1024-d, compared with the squared Euclidean distance (paper eq. 13).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from cmal_lcd.features.base import (
    FeatureExtractor,
    config_int,
    encode_in_batches,
    torch_device,
)

logger = logging.getLogger(__name__)

#: Table label of the untrained control (a trained model's label is its own, ``GANModel.label``).
UNTRAINED_LABEL = "CMAL (untrained control)"


def encoder_batch_function(model, *, image_size, device) -> Callable[[np.ndarray], np.ndarray]:
    """``uint8 frames (b, H, W, 3) -> float32 codes (b, F)`` through ``model.encode``.

    Parameters
    ----------
    model : torch.nn.Module
        Has ``encode(x float32 (N, 3, h, w) in [-1, 1]) -> (N, F)``; put in eval mode here.
    image_size
        Passed to ``cmal_lcd.models.preprocess``.
    device : torch.device
    """
    import torch

    from cmal_lcd.models import preprocess

    model.eval()

    def encode_batch(batch: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            x = preprocess(batch, image_size=image_size).to(device)
            codes = model.encode(x)
            return codes.reshape(len(batch), -1).to("cpu", torch.float32).numpy()

    return encode_batch


def learned_extractor(name: str, model, *, image_size, weights: str, batch_size: int,
                      device, label: str | None = None) -> FeatureExtractor:
    """Wrap an encoder model as a :class:`FeatureExtractor` (metric ``sqeuclidean``), labelled
    ``label`` (default the model's own ``label``, else ``name``)."""
    encode_batch = encoder_batch_function(model, image_size=image_size, device=device)
    label = label if label is not None else getattr(model, "label", name)
    return FeatureExtractor(
        name=name, label=label, metric="sqeuclidean", weights=weights,
        encode=lambda images: encode_in_batches(images, encode_batch, batch_size=batch_size),
        device=str(device), backend="torch", batch_size=int(batch_size),
    )


def trained_model_path(model_dir: Path | str | None, name: str) -> Path:
    """``<model_dir>/<name>/model.pt``, checked to exist.

    Raises
    ------
    ValueError
        Naming ``model_dir`` when it is None or the file is missing.
    """
    if model_dir is None:
        raise ValueError(f"model_dir: method {name!r} needs the trained models folder "
                         f"(e.g. models/)")
    path = Path(model_dir) / name / "model.pt"
    if not path.is_file():
        raise ValueError(f"model_dir: no trained {name} model at {path} "
                         f"(run the train@{name} stage)")
    return path


def training_record(meta: Mapping[str, Any]) -> str:
    """``iteration 200, trained on <processor>``: which weights, and the processor that trained
    them (weights differ across processor families; a model saved before the processor was
    recorded gives the iteration only)."""
    cpu = (meta.get("kernels") or {}).get("cpu")
    return f"iteration {meta.get('iteration')}" + (f", trained on {cpu}" if cpu else "")


def build_trained(conf: Mapping[str, Any], *, model_dir: Path | None = None,
                  device: str = "cpu") -> FeatureExtractor:
    """Extractor for the trained model ``conf["trained_model"]`` (``bigan``, ``cmal``,
    ``cmal_place``, ``place_encoder``): its encoder, labelled by the model (``GANModel.label``)."""
    from cmal_lcd.models import load_trained

    name = conf["trained_model"]
    path = trained_model_path(model_dir, name)
    dev = torch_device(device)
    model, meta = load_trained(path, device=str(dev))
    if meta.get("name", name) != name:
        raise ValueError(f"model_dir: {path} holds a {meta.get('name')!r} model, expected {name!r}")
    weights = f"trained {name} {path} ({training_record(meta)})"
    logger.info("%s: %s", name, weights)
    return learned_extractor(name, model, image_size=meta["image_size"], weights=weights,
                             batch_size=config_int(conf, "batch_size", where="features"),
                             device=dev)


def untrained_conf(cfg: Mapping[str, Any],
                   dataset_meta: Mapping[str, Any] | None) -> dict[str, Any]:
    """``extra_conf`` of ``cmal_untrained``: the CMAL model config, the seed, and sizes from
    ``dataset.json``."""
    from omegaconf import DictConfig, OmegaConf

    if dataset_meta is None:
        raise ValueError("dataset_meta: cmal_untrained needs dataset.json (conditions, image_size)")
    model_conf = cfg["models"]["cmal"]
    if isinstance(model_conf, DictConfig):
        model_conf = OmegaConf.to_container(model_conf, resolve=True)
    image_size = model_conf.get("image_size") if isinstance(model_conf, dict) else None
    image_size = image_size if image_size is not None else dataset_meta["image_size"]
    return {
        "model": model_conf,
        "seed": int(cfg["seed"]),
        "n_conditions": len(dataset_meta["conditions"]),
        "image_size": list(image_size) if isinstance(image_size, (list, tuple)) else image_size,
    }


def build_cmal_untrained(conf: Mapping[str, Any], *, model_dir: Path | None = None,
                         device: str = "cpu") -> FeatureExtractor:
    """The control row: the CMAL encoder with its random initial weights, never trained.

    Parameters
    ----------
    conf : mapping
        The ``features`` node merged with ``model`` (the ``models.cmal`` node), ``seed``,
        ``n_conditions`` and ``image_size`` (see ``cmal_lcd.features.extractor_conf``).
    model_dir
        Folder holding ``cmal/model.pt``, whose trained classifier decides the condition.
    device : str

    Notes
    -----
    The initialisation runs under ``torch.manual_seed(seed)`` inside ``torch.random.fork_rng``,
    so it is reproducible and leaves the caller's random state untouched.
    """
    import torch

    from cmal_lcd.models import build_model

    for key in ("model", "seed", "n_conditions", "image_size"):
        if conf.get(key) is None:
            raise ValueError(f"conf: cmal_untrained needs {key!r} "
                             f"(use cmal_lcd.features.extractor_conf)")
    seed, n_conditions, image_size = (int(conf["seed"]), int(conf["n_conditions"]),
                                      conf["image_size"])
    dev = torch_device(device)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = build_model("cmal", conf["model"], image_size=image_size, n_conditions=n_conditions)
    model = model.to(dev)
    weights = f"encoder: random initialisation, torch.manual_seed({seed}), no training"
    trained = Path(model_dir) / "cmal" / "model.pt" if model_dir is not None else None
    if trained is not None and trained.is_file():
        from cmal_lcd.models import load_trained

        trained_model, meta = load_trained(trained, device=str(dev))
        model.classifier.load_state_dict(trained_model.classifier.state_dict())
        weights += (f"; condition from the trained classifier C of {trained} "
                    f"({training_record(meta)})")
    else:
        logger.warning("cmal_untrained: no trained CMAL model in %s; the control is encoded "
                       "under its own untrained classifier", model_dir)
        weights += "; condition from its own untrained classifier (no trained CMAL model found)"
    return learned_extractor("cmal_untrained", model, image_size=image_size, weights=weights,
                             label=UNTRAINED_LABEL,
                             batch_size=config_int(conf, "batch_size", where="features"),
                             device=dev)
