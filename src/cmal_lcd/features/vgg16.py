"""VGG16 (configuration D) laid out exactly as torchvision's ``vgg16``, without torchvision.

The parameter names are torchvision's (``features.0.weight`` ... ``classifier.6.bias``), so the
ImageNet state dict ``vgg16-397923af.pth`` loads with ``strict=True``. Only the layers used as
place-recognition features are exposed beyond the classifier: ``fc6`` (first fully connected
layer, 4096-d after ReLU) and ``fc7`` (second, 4096-d after ReLU).
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch
from torch import nn

from cmal_lcd.schema import VGG16_FC_LAYERS

logger = logging.getLogger(__name__)

#: torchvision's file name for the ImageNet VGG16 weights (in ``$TORCH_HOME/hub/checkpoints``).
VGG16_FILE_NAME = "vgg16-397923af.pth"

#: Output channels of the 13 conv layers, ``"M"`` = 2x2 max pooling (torchvision cfg "D").
VGG16_LAYOUT = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M",
                512, 512, 512, "M")

#: Fully connected layers usable as features (:data:`cmal_lcd.schema.VGG16_FC_LAYERS`): name ->
#: index of its ReLU in ``classifier``.
FC_LAYERS = dict(zip(VGG16_FC_LAYERS, (1, 4)))

#: ImageNet RGB mean and std on the 0..255 scale (torchvision's normalisation times 255).
IMAGENET_MEAN_255 = (0.485 * 255, 0.456 * 255, 0.406 * 255)
IMAGENET_STD_255 = (0.229 * 255, 0.224 * 255, 0.225 * 255)


def vgg16_conv_stack() -> nn.Sequential:
    """The 31-module ``features`` stack: conv3x3 + ReLU, max-pool after each stage."""
    layers: list[nn.Module] = []
    in_channels = 3
    for item in VGG16_LAYOUT:
        if item == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(in_channels, int(item), kernel_size=3, padding=1),
                       nn.ReLU(inplace=True)]
            in_channels = int(item)
    return nn.Sequential(*layers)


class VGG16(nn.Module):
    """VGG16 with torchvision's module tree: ``features``, ``avgpool``, ``classifier``.

    Parameters
    ----------
    num_classes : int, optional
        Width of the last linear layer (``classifier.6``), 1000 for ImageNet.
    """

    def __init__(self, *, num_classes: int = 1000) -> None:
        super().__init__()
        self.features = vgg16_conv_stack()
        self.avgpool = nn.AdaptiveAvgPool2d((7, 7))
        self.classifier = nn.Sequential(
            nn.Linear(512 * 7 * 7, 4096), nn.ReLU(inplace=True), nn.Dropout(p=0.5),
            nn.Linear(4096, 4096), nn.ReLU(inplace=True), nn.Dropout(p=0.5),
            nn.Linear(4096, num_classes),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Class logits.

        Parameters
        ----------
        x : Tensor, float32, shape (N, 3, H, W)
            ImageNet-normalised RGB (H, W >= 32; 224 as trained).

        Returns
        -------
        Tensor, shape (N, num_classes)
        """
        return self.classifier(torch.flatten(self.avgpool(self.features(x)), 1))

    def fully_connected_features(self, x: torch.Tensor, *, layer: str = "fc6") -> torch.Tensor:
        """Activations of a fully connected layer after its ReLU.

        Parameters
        ----------
        x : Tensor, float32, shape (N, 3, H, W)
            ImageNet-normalised RGB.
        layer : {"fc6", "fc7"}
            ``fc6`` = ``classifier.0`` + ReLU, ``fc7`` = ``classifier.3`` + ReLU.

        Returns
        -------
        Tensor, shape (N, 4096)
        """
        if layer not in FC_LAYERS:
            raise ValueError(f"layer: expected one of {sorted(FC_LAYERS)}, got {layer!r}")
        h = torch.flatten(self.avgpool(self.features(x)), 1)
        return self.classifier[: FC_LAYERS[layer] + 1](h)


def load_vgg16(path: str | Path, *, device: str | torch.device = "cpu") -> VGG16:
    """Build :class:`VGG16` and load a torchvision-format state dict into it (strict).

    The module is created on the ``meta`` device and the loaded tensors are assigned, so no
    random initialisation is computed and the 138 M parameters are held once.

    Parameters
    ----------
    path : path
        A ``.pth`` file holding a torchvision VGG16 state dict (e.g. ``vgg16-397923af.pth``).
    device : str or torch.device

    Returns
    -------
    VGG16
        In eval mode, on ``device``.

    Raises
    ------
    ValueError
        When the file is missing or its keys/shapes are not torchvision's VGG16.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"vgg16_weights: no such file {path}")
    state = torch.load(path, map_location="cpu", weights_only=True)
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    num_classes = (int(state["classifier.6.weight"].shape[0])
                   if "classifier.6.weight" in state else 1000)
    with torch.device("meta"):
        net = VGG16(num_classes=num_classes)
    try:
        net.load_state_dict(state, strict=True, assign=True)
    except RuntimeError as exc:
        raise ValueError(f"vgg16_weights: {path} is not a torchvision VGG16 state dict: "
                         f"{exc}") from exc
    logger.info("loaded VGG16 weights from %s", path)
    return net.to(device).eval()
