"""Your own method: one Python file plus one ``extractors.<name>`` config node.

A node of ``extractors`` (``conf/config.yaml``) names, by Hydra's ``_target_``, a callable in
an importable module (a file under ``src/``, which every stage and the editable install put on
the path, or an installed package)::

    extractors:
      hog:
        _target_: my_hog.HOG          # a class or function: called with the other keys
        cell: 8                       # ... passed to it (Hydra's instantiate)
        label: HOG (OpenCV, 8 px cells)   # the row label of every table and figure
        metric: sqeuclidean           # how SeqSLAM compares two codes (default)

Every key but the reserved ones (:data:`RESERVED`) goes to the target, as
``hydra.utils.instantiate`` passes it (``_partial_: true`` makes the target itself the encoder).
What the target returns is the method:

- a :class:`~cmal_lcd.features.base.FeatureExtractor`: used as it is;
- a ``torch.nn.Module``: fed RGB frames as float32 ``(B, 3, H, W)`` in ``[0, 1]`` (resized to
  ``image_size`` first when set), in eval mode under ``torch.inference_mode``, on the device
  training uses; its output is flattened to ``(B, D)``;
- any other callable ``frames uint8 (B, H, W, 3) -> (B, D)`` (NumPy array or tensor);
- an object with ``codes(sources, frame_ids)`` (not callable): codes looked up by dataset
  frame, not computed (:class:`~cmal_lcd.features.precomputed.DescriptorFolder`).

``inputs`` (optional) is a file or folder the target reads: it is passed to the target like
any other key, and the method's stage depends on it instead of on the module's file.

It is built under ``torch.manual_seed(seed)`` (a network with random weights is the same in
every run). The method then runs wherever a built-in one does: the ``methods`` list takes every
extractor by default (``conf/config.yaml``), its ``extract_features@<name>`` stage depends on
its module's file and its node (:func:`method_source_file`), and ``cmal-lcd match --features
<name>`` and ``loops`` find it in the composed config.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import sys
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from cmal_lcd.features.base import FeatureExtractor, encode_in_batches, torch_device
from cmal_lcd.matching.difference import METRICS

#: The target, as Hydra names it.
TARGET = "_target_"
#: Keys of an ``extractors.<name>`` node read here, never passed to the target: what each does.
RESERVED = {
    "label": "row label in tables and figures (default: the method's name)",
    "metric": f"how SeqSLAM compares codes, one of {list(METRICS)} (default sqeuclidean)",
    "batch_size": "frames per call of the encoder (default features.batch_size)",
    "image_size": "[height, width] the frames are resized to first (default: as stored)",
    "weights": "what the codes come from, shown beside Table III (default: the target)",
}
#: Hydra's own keys, passed to ``instantiate`` as they are.
HYDRA_KEYS = (TARGET, "_partial_", "_args_", "_convert_", "_recursive_")


def check_extractor_node(name: str, node: Any) -> None:
    """Refuse an ``extractors.<name>`` node that cannot make a method, naming the key.

    Raises
    ------
    ValueError
        ``extractors.<name>.<key>: ...`` (a missing or non-string ``_target_``, a metric not in
        ``METRICS``, a batch size below 1, an ``image_size`` that is not two positive integers).
    """
    where = f"extractors.{name}"
    if not isinstance(node, Mapping):
        raise ValueError(f"{where}: expected a mapping with {TARGET}, got {node!r}")
    target = node.get(TARGET)
    if not isinstance(target, str) or "." not in target:
        raise ValueError(f"{where}.{TARGET}: expected a dotted path 'module.callable', got "
                         f"{target!r}")
    metric = node.get("metric", "sqeuclidean")
    if metric not in METRICS:
        raise ValueError(f"{where}.metric: must be one of {list(METRICS)}, got {metric!r}")
    batch = node.get("batch_size")
    if batch is not None and (isinstance(batch, bool) or not isinstance(batch, int) or batch < 1):
        raise ValueError(f"{where}.batch_size: expected an integer >= 1, got {batch!r}")
    size = node.get("image_size")
    if size is not None and (not isinstance(size, (list, tuple)) or len(size) != 2 or not all(
            isinstance(s, int) and not isinstance(s, bool) and s >= 1 for s in size)):
        raise ValueError(f"{where}.image_size: expected [height, width] (positive integers) or "
                         f"null, got {size!r}")
    for key in ("label", "weights", "inputs"):
        if node.get(key) is not None and not isinstance(node[key], str):
            raise ValueError(f"{where}.{key}: expected a string, got {node[key]!r}")


def method_source_file(target: str, *, root: str | os.PathLike | None = None) -> str:
    """The file defining ``target``'s module: what the method's features stage depends on.

    Looked up first under ``<root>/src`` (where a method's file goes; nothing is imported),
    then through the import system (an installed package; its parent packages are imported).
    Relative to ``root`` (the checkout, default: the working directory) when inside it.

    Parameters
    ----------
    target : str
        ``module.callable`` or ``package.module.Class``.

    Raises
    ------
    ValueError
        Naming ``target`` when no prefix of it is an importable module.
    """
    root = Path(root if root is not None else os.getcwd()).resolve()
    parts = target.split(".")
    for end in range(len(parts) - 1, 0, -1):
        base = root.joinpath("src", *parts[:end])
        for candidate in (base.with_suffix(".py"), base / "__init__.py"):
            if candidate.is_file():
                return candidate.relative_to(root).as_posix()
    for end in range(len(parts) - 1, 0, -1):
        try:
            spec = importlib.util.find_spec(".".join(parts[:end]))
        except (ImportError, ValueError, AttributeError):
            spec = None
        if spec is not None and spec.origin and Path(spec.origin).is_file():
            origin = Path(spec.origin).resolve()
            return (origin.relative_to(root).as_posix() if origin.is_relative_to(root)
                    else str(origin))
    raise ValueError(f"{TARGET}: cannot find the module of {target!r} (put its file under "
                     f"src/, or install its package)")


def target_kwargs(node: Mapping[str, Any]) -> dict[str, Any]:
    """The node without :data:`RESERVED`: what ``hydra.utils.instantiate`` gets."""
    return {k: v for k, v in node.items() if k not in RESERVED}


def build_custom(conf: Mapping[str, Any], *, model_dir: Path | None = None,
                 device: str = "cpu") -> FeatureExtractor:
    """The method of an ``extractors.<name>`` node.

    Parameters
    ----------
    conf : mapping
        The ``features`` node merged with ``name`` (the method), ``extractor`` (its node) and
        ``seed`` (:func:`cmal_lcd.features.extractor_conf` builds it).
    model_dir
        Unused (a user's method loads its own weights).
    device : str
        Torch device for a ``torch.nn.Module``.

    Raises
    ------
    ValueError
        ``extractors.<name>...`` naming what is wrong with the node, or what the target returned.
    """
    name, node = conf["name"], dict(conf["extractor"])
    check_extractor_node(name, node)
    made = instantiate_target(node, seed=int(conf["seed"]), where=f"extractors.{name}")
    batch_size = int(node.get("batch_size") or conf["batch_size"])
    if isinstance(made, FeatureExtractor):
        return dataclasses.replace(made, name=name, label=node.get("label") or made.label)
    if hasattr(made, "codes") and not callable(made) and not isinstance(made, type):
        return looked_up(name, node, made)
    size = node.get("image_size")
    encode, backend, device = as_encoder(made, device=device, where=f"extractors.{name}",
                                         seed=int(conf["seed"]))

    def encode_batch(batch: np.ndarray) -> np.ndarray:
        return encode(resized(batch, size) if size is not None else batch)

    return FeatureExtractor(
        name=name, label=node.get("label") or name, metric=node.get("metric", "sqeuclidean"),
        weights=node.get("weights") or f"user method {node[TARGET]}",
        encode=lambda images: encode_in_batches(images, encode_batch, batch_size=batch_size),
        device=device, backend=backend, batch_size=batch_size)


def looked_up(name: str, node: Mapping[str, Any], made: Any) -> FeatureExtractor:
    """The method of precomputed codes (an object with ``codes(sources, frame_ids)``, e.g.
    :class:`~cmal_lcd.features.precomputed.DescriptorFolder`): looked up by dataset frame."""
    where = f"extractors.{name}"

    def refuse(images: np.ndarray) -> np.ndarray:
        raise ValueError(f"{where}: precomputed codes are looked up by dataset frame, not "
                         f"computed from images (give `cmal-lcd match` the descriptor files "
                         f"themselves)")

    return FeatureExtractor(
        name=name, label=node.get("label") or name, metric=node.get("metric", "sqeuclidean"),
        weights=node.get("weights") or f"precomputed: {node.get('inputs', node[TARGET])}",
        encode=refuse, device="cpu", backend="numpy", lookup=made.codes)


def instantiate_target(node: Mapping[str, Any], *, seed: int, where: str) -> Any:
    """``hydra.utils.instantiate`` of the node (reserved keys left out), under
    ``torch.manual_seed(seed)`` and with the caller's random state restored afterwards."""
    import torch
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    put_checkout_src_on_path()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        try:
            return instantiate(target_kwargs(node))
        except InstantiationException as err:
            message = " ".join(line.strip() for line in str(err).splitlines() if line.strip())
            raise ValueError(f"{where}.{TARGET}: {message}") from err


def put_checkout_src_on_path() -> None:
    """Append the working directory's checkout's ``src/`` to ``sys.path`` (where a method's
    file goes; DVC stages run with ``PYTHONPATH=src``, commands may not)."""
    from cmal_lcd.checkout import CheckoutNotFoundError, checkout_root

    try:
        src = str(checkout_root() / "src")
    except CheckoutNotFoundError:
        return
    if src not in sys.path:
        sys.path.append(src)


def as_encoder(made: Any, *, device: str, where: str, seed: int = 0
               ) -> tuple[Callable[[np.ndarray], np.ndarray], str, str]:
    """``(encode(frames uint8 (B, H, W, 3)) -> float32 (B, D), backend, device)`` of what the
    target returned: a ``torch.nn.Module`` or a callable.

    A module runs under ``torch.manual_seed(seed)`` too, with the caller's random state
    restored: a lazily initialised layer (``torch.nn.LazyLinear``) gets the same weights in
    every run."""
    import torch

    if isinstance(made, torch.nn.Module):
        dev = torch_device(device)
        module = made.to(dev).eval()

        def encode_module(frames: np.ndarray) -> np.ndarray:
            batch = torch.from_numpy(np.ascontiguousarray(frames)).to(dev)
            with torch.random.fork_rng(devices=[]), torch.inference_mode():
                torch.manual_seed(seed)
                out = module(batch.permute(0, 3, 1, 2).float().div_(255.0))
            return codes_array(out, len(frames), where=where)

        return encode_module, "torch", str(dev)
    if not callable(made):
        raise ValueError(f"{where}.{TARGET}: returned {type(made).__name__}, which is neither "
                         f"a FeatureExtractor, a torch.nn.Module nor a callable "
                         f"(use _partial_: true to make the target itself the encoder)")
    return (lambda frames: codes_array(made(frames), len(frames), where=where)), "numpy", "cpu"


def codes_array(out: Any, n: int, *, where: str) -> np.ndarray:
    """``out`` (array or tensor) as float32 ``(n, D)``; ValueError for another row count."""
    if hasattr(out, "detach"):
        out = out.detach().float().cpu().numpy()
    codes = np.asarray(out, dtype=np.float32)
    if codes.ndim == 0 or codes.shape[0] != n:
        raise ValueError(f"{where}: the encoder returned shape {codes.shape} for {n} frames; "
                         f"expected ({n}, D)")
    return codes.reshape(n, -1)


def resized(frames: np.ndarray, size) -> np.ndarray:
    """``frames uint8 (B, H, W, 3)`` resized to ``size = [height, width]`` (``cv2.INTER_AREA``
    when shrinking, ``INTER_LINEAR`` when enlarging)."""
    import cv2

    height, width = int(size[0]), int(size[1])
    if frames.shape[1:3] == (height, width):
        return frames
    shrink = height * width < frames.shape[1] * frames.shape[2]
    interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    return np.stack([cv2.resize(f, (width, height), interpolation=interp) for f in frames])
