"""The feature-extractor object shared by every method, and helpers the torch methods share.

A :class:`FeatureExtractor` maps a batch of RGB frames ``uint8 (N, H, W, 3)`` to one code per
frame ``(N, F)``. It carries what the tables need: its ``label``, the ``metric`` SeqSLAM compares
codes with (one of ``cmal_lcd.matching.METRICS``) and a description of the ``weights`` it uses.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np

from cmal_lcd.kernels import cpu_model_name
from cmal_lcd.matching.difference import METRICS

logger = logging.getLogger(__name__)


def validate_images(images: np.ndarray) -> np.ndarray:
    """Check that ``images`` is a batch of RGB frames.

    Parameters
    ----------
    images : ndarray, uint8, shape (N, H, W, 3)

    Returns
    -------
    ndarray
        ``images`` itself (no copy).

    Raises
    ------
    ValueError
        Naming ``images`` when the dtype or shape is wrong.
    """
    images = np.asarray(images) if not isinstance(images, np.ndarray) else images
    if images.dtype != np.uint8:
        raise ValueError(f"images: expected dtype uint8, got {images.dtype}")
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images: expected shape (N, H, W, 3), got {images.shape}")
    return images


@dataclass(frozen=True)
class FeatureExtractor:
    """A named per-frame feature extractor.

    Attributes
    ----------
    name : str
        Method name, a key of ``cmal_lcd.features.METHODS`` (e.g. ``"dnn"``).
    label : str
        Label shown in tables and figures (e.g. ``"DNN (EfficientNet-Lite0)"``).
    metric : str
        One of ``cmal_lcd.matching.METRICS`` (``"sad"``, ``"sad_u8"``, ``"sqeuclidean"``): how
        SeqSLAM compares two codes.
    weights : str
        Which weights the codes come from (a file, a package, or the random init).
    encode : callable
        ``encode(images uint8 (N, H, W, 3)) -> ndarray (N, F)``; called through ``__call__``,
        which validates input and output.
    device : str
        Where the computation runs, e.g. ``"cpu"``.
    backend : str
        ``"torch"`` or ``"numpy"``; names the library in timing reports.
    batch_size : int, optional
        Frames per forward pass inside ``encode`` (``features.batch_size``, or
        ``features.dnn.batch_size`` for the DNN): callers encode and time in steps of it.
        None: the extractor does not batch.
    lookup : callable, optional
        For precomputed codes (:mod:`cmal_lcd.features.precomputed`): ``lookup(sources,
        frame_ids) -> (n, F)``, the codes of dataset frames ``frame_ids`` (``frames.csv``
        ``frame``) given ``dataset.json`` ``sources``; raises ``LookupError`` when some have
        none. The features stage uses it instead of ``encode``, which then refuses images.
    """

    name: str
    label: str
    metric: str
    weights: str
    encode: Callable[[np.ndarray], np.ndarray]
    device: str = "cpu"
    backend: str = "torch"
    batch_size: int | None = None
    lookup: Callable[..., np.ndarray] | None = None

    def __post_init__(self) -> None:
        if self.metric not in METRICS:
            raise ValueError(f"metric: expected one of {METRICS}, got {self.metric!r}")

    def __call__(self, images: np.ndarray) -> np.ndarray:
        """Codes of ``images``.

        Parameters
        ----------
        images : ndarray, uint8, shape (N, H, W, 3)
            RGB frames.

        Returns
        -------
        ndarray, shape (N, F)
            One code per frame, in input order.
        """
        images = validate_images(images)
        codes = np.asarray(self.encode(images))
        if codes.ndim != 2 or codes.shape[0] != images.shape[0]:
            raise ValueError(
                f"{self.name}: encoder returned shape {codes.shape} for {images.shape[0]} frames;"
                " expected (N, F)"
            )
        return codes

    def describe_device(self) -> str:
        """Human-readable device for timing tables.

        Returns
        -------
        str
            E.g. ``"cpu: Intel(R) Xeon(R) ... (torch 2.13.0, 1 thread)"``.
        """
        if self.backend == "torch":
            import torch

            threads = torch.get_num_threads()
            lib = f"torch {torch.__version__}, {threads} thread{'s' if threads != 1 else ''}"
        else:
            lib = f"numpy {np.__version__}"
        return f"{self.device}: {cpu_model_name()} ({lib})" if self.device == "cpu" else (
            f"{self.device} ({lib})")


def forward_batch_size(extractor: FeatureExtractor, conf) -> int:
    """Frames per forward pass: the extractor's own (``features.dnn.batch_size`` for the DNN),
    else the ``features`` node's ``batch_size``."""
    return int(extractor.batch_size or conf["batch_size"])


def encode_in_batches(images: np.ndarray, encode_batch: Callable[[np.ndarray], np.ndarray], *,
                      batch_size: int) -> np.ndarray:
    """Apply ``encode_batch`` to consecutive slices of ``images`` and stack the results.

    Slicing keeps memory bounded when ``images`` is a memory-mapped dataset.

    Parameters
    ----------
    images : ndarray, shape (N, ...)
    encode_batch : callable
        ``encode_batch(images[i:i + batch_size]) -> ndarray (b, F)``.
    batch_size : int
        Frames per call, >= 1.

    Returns
    -------
    ndarray, shape (N, F)
    """
    batch_size = int(batch_size)
    if batch_size < 1:
        raise ValueError(f"batch_size: expected >= 1, got {batch_size}")
    parts = [encode_batch(np.ascontiguousarray(images[i:i + batch_size]))
             for i in range(0, len(images), batch_size)]
    if not parts:
        raise ValueError("images: no frames to encode (N = 0)")
    return np.concatenate(parts, axis=0)


#: Batches per progress step of :func:`encode_with_progress`.
BATCHES_PER_STEP = 8


def encode_with_progress(extractor: Callable[[np.ndarray], np.ndarray], images: np.ndarray, *,
                         batch_size: int, desc: str, logger: logging.Logger | None = None
                         ) -> np.ndarray:
    """``extractor(images)``, in steps of whole batches, with progress (frames/s).

    ``extractor`` is a :class:`FeatureExtractor` or any ``images -> codes (N, F)`` function
    that batches by ``batch_size`` from the start of what it is given.

    A bar on a terminal, an INFO line on ``logger`` every ``cmal_lcd.progress.LOG_INTERVAL_S``
    seconds otherwise (``dvc repro``). Steps start at multiples of ``batch_size``, so the
    extractor's own batches, and the codes, are those of a single call.

    Parameters
    ----------
    images : ndarray, uint8, shape (N, H, W, 3)

    Returns
    -------
    ndarray, shape (N, F)
    """
    from cmal_lcd import progress

    step = max(1, int(batch_size)) * BATCHES_PER_STEP
    parts = []
    with progress.Progress(len(images), desc=desc, unit="frame",
                           logger=logger or logging.getLogger("cmal_lcd.features"),
                           interval=progress.LOG_INTERVAL_S) as bar:
        for start in range(0, len(images), step):
            parts.append(extractor(images[start:start + step]))
            bar.update(len(parts[-1]))
    return np.concatenate(parts, axis=0)


def first_nonfinite_row(codes: np.ndarray) -> int:
    """Index of the first row of ``codes`` holding NaN or inf, or ``-1`` when all are finite.

    Parameters
    ----------
    codes : ndarray, shape (N, F)
    """
    if np.issubdtype(codes.dtype, np.integer):
        return -1
    bad = ~np.isfinite(codes).all(axis=1)
    return int(np.argmax(bad)) if bad.any() else -1


def check_finite_codes(codes: np.ndarray, *, method: str) -> np.ndarray:
    """Raise when any code holds NaN or inf.

    Parameters
    ----------
    codes : ndarray, shape (N, F)
    method : str
        Named in the error message.

    Raises
    ------
    ValueError
        Naming ``method`` and the first bad frame (row index).
    """
    row = first_nonfinite_row(codes)
    if row >= 0:
        n_bad = int((~np.isfinite(codes).all(axis=1)).sum())
        raise ValueError(
            f"{method}: codes contain NaN or inf (first bad frame: test row {row}, "
            f"{n_bad} bad frames of {len(codes)})"
        )
    return codes


def torch_device(device: str):
    """``torch.device(device)``, with a clear error for an unknown or unavailable device."""
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"device: cannot use {device!r}: {exc}") from exc
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device: {device!r} requested but CUDA is not available")
    return dev



def config_int(conf, key: str, *, where: str, default: int | None = None,
               minimum: int = 1) -> int:
    """An integer option ``conf[key]`` (or ``default`` when absent), checked.

    Parameters
    ----------
    conf : mapping
        A config node.
    key : str
        The option.
    where : str
        The node's path in the composed config (e.g. ``"features"``), for the message.
    default : int, optional
        Used when ``key`` is absent; ``None`` makes the key required.
    minimum : int
        Smallest accepted value.

    Raises
    ------
    ValueError
        Naming ``where.key`` when it is missing, not an integer, or below ``minimum``.
    """
    value = conf.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{where}.{key}: expected an integer >= {minimum}, got {value!r}")
    return int(value)
