"""SAD thumbnails as in SeqSLAM: grey, downsampled, patch-normalised.

Conventions (decided from ``docs`` and the SeqSLAM reference implementations):

- Grey is ``0.2989 R + 0.5870 G + 0.1140 B`` in floating point (MATLAB's ``rgb2gray`` weights).
- Downsampling to ``width x height`` uses ``cv2.INTER_AREA`` (pixel-area averaging); an image
  already at that size is left unchanged.
- Patch normalisation over non-overlapping ``patch x patch`` squares: ``z = (p - mean) / std``
  with the sample standard deviation (``ddof=1``). The values are **kept as float z-scores**
  (OpenSeqSLAM stores ``127 + round(z)`` as ``uint8``); a constant patch (``0 / 0``, e.g. a black
  tunnel frame) becomes ``z = 0``. Of the conventions measured on Nordland this one gave the
  highest AUC-PR (see ``seqslam_notes.md``); the integer variant with constant patches mapped to
  0 costs about 0.14 AUC-PR. "Constant" means a sample std below :data:`FLAT_PATCH_STD`
  (``1e-3`` grey levels): resampling a uniform region is not exact.
- ``patch=0`` turns the normalisation off (raw grey levels, an ablation).

The difference between two thumbnails is their mean absolute difference
(:func:`cmal_lcd.matching.difference_matrix` with ``metric="sad"``).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

#: RGB -> grey weights (MATLAB ``rgb2gray``, as OpenSeqSLAM).
GREY_WEIGHTS = (0.2989, 0.5870, 0.1140)

#: A patch whose sample std is below this many grey levels (of 0..255) counts as constant:
#: area resampling of a uniform region leaves noise of about 1e-6 levels, which would otherwise be
#: blown up to z-scores of order 1.
FLAT_PATCH_STD = 1e-3

_BATCH = 256  # images converted per batch, bounds the float working memory

#: The keys of the ``matching.sad`` node that shape the thumbnails (``quantise`` shapes the
#: comparison instead: :func:`sad_metric`).
THUMBNAIL_KEYS = ("width", "height", "patch")


def _checked_sizes(**sizes: Any) -> tuple[int, int, int]:
    """``width, height, patch`` checked by the rules of ``matching.sad``
    (:class:`cmal_lcd.schema.SadSchema`, the one check of them): ``ValueError``
    ``patch: must be 0 (off) or >= 2, got 1``."""
    from cmal_lcd.fields import check_values
    from cmal_lcd.schema import SadSchema

    checked = check_values(SadSchema, sizes)
    return checked["width"], checked["height"], checked["patch"]


def thumbnail_options(sad: Mapping[str, Any]) -> dict[str, Any]:
    """``width``, ``height``, ``patch`` of a ``matching.sad`` node, for :func:`sad_thumbnails`."""
    return {key: sad[key] for key in THUMBNAIL_KEYS if key in sad}


def sad_metric(sad: Mapping[str, Any]) -> str:
    """The difference metric of the thumbnails: ``sad_u8`` when ``sad["quantise"]``, else ``sad``.

    ``sad_u8`` rounds the z-scores to steps of 1/16 and compares bytes
    (:mod:`cmal_lcd.matching.difference`).
    """
    return "sad_u8" if sad.get("quantise", False) else "sad"


def sad_thumbnails(images: np.ndarray, *, width: int | None = None, height: int | None = None,
                   patch: int | None = None) -> np.ndarray:
    """Greyscale, downsampled, patch-normalised thumbnails, one flat row per image.

    Parameters
    ----------
    images : numpy.ndarray
        ``uint8 (N, H, W, 3)`` RGB or ``uint8 (N, H, W)`` grey.
    width, height : int, optional
        Thumbnail size in pixels.
    patch : int, optional
        Side of the non-overlapping normalisation patches, pixels; must divide ``width`` and
        ``height``, and be ``>= 2``; ``0`` disables the normalisation.

    Each of ``width``, ``height``, ``patch`` left out takes ``matching.sad`` of
    ``conf/matching/seqslam.yaml`` (64 x 32, patch 8, as SeqSLAM;
    :func:`cmal_lcd.matching.matching_defaults`).

    Returns
    -------
    numpy.ndarray
        ``float32 (N, height * width)``: row ``n`` is the thumbnail of image ``n`` flattened in
        row-major (``height``, ``width``) order.

    Raises
    ------
    ValueError
        When ``images`` has the wrong shape or dtype, or ``width``, ``height``, ``patch`` are
        invalid.
    """
    if width is None or height is None or patch is None:
        from cmal_lcd.matching.params import matching_defaults

        sad = matching_defaults()["sad"]
        width = sad["width"] if width is None else width
        height = sad["height"] if height is None else height
        patch = sad["patch"] if patch is None else patch
    images = np.asarray(images)
    if images.dtype != np.uint8:
        raise ValueError(f"images must be uint8, got {images.dtype}")
    if images.ndim == 4:
        if images.shape[-1] != 3:
            raise ValueError(f"images must be (N, H, W, 3) RGB or (N, H, W) grey, "
                             f"got shape {images.shape}")
    elif images.ndim != 3:
        raise ValueError(f"images must be (N, H, W, 3) RGB or (N, H, W) grey, got shape "
                         f"{images.shape}")
    width, height, patch = _checked_sizes(width=width, height=height, patch=patch)
    if images.shape[1] < 1 or images.shape[2] < 1:
        raise ValueError(f"images have an empty spatial size: shape {images.shape}")

    n = images.shape[0]
    out = np.empty((n, height * width), dtype=np.float32)

    def convert(start: int) -> None:
        batch = images[start:start + _BATCH]
        grey = grey_levels(batch)
        small = np.stack([_resize_area(g, width=width, height=height) for g in grey]) \
            if len(grey) else np.empty((0, height, width))
        if patch:
            small = patch_normalise(small, patch=patch)
        out[start:start + len(batch)] = small.reshape(len(batch), -1)

    starts = range(0, n, _BATCH)
    if len(starts) < 2:
        for start in starts:
            convert(start)
        return out
    # Batches on threads (NumPy and OpenCV release the GIL on whole-array work): 0.25 -> 0.15 s
    # for 7,200 frames on 2 cores; every batch is computed as alone, so the rows are the same.
    from concurrent.futures import ThreadPoolExecutor

    from cmal_lcd.kernels import usable_cores

    with ThreadPoolExecutor(max_workers=min(len(starts), usable_cores(), 8)) as pool:
        list(pool.map(convert, starts))
    return out


def grey_levels(images: np.ndarray) -> np.ndarray:
    """Grey levels ``0.2989 R + 0.5870 G + 0.1140 B``.

    Parameters
    ----------
    images : numpy.ndarray
        ``(N, H, W, 3)`` RGB or ``(N, H, W)`` grey.

    Returns
    -------
    numpy.ndarray
        ``float64 (N, H, W)``.
    """
    images = np.asarray(images)
    if images.ndim == 3:
        return images.astype(np.float64)
    r, g, b = GREY_WEIGHTS
    return (r * images[..., 0].astype(np.float64) + g * images[..., 1]
            + b * images[..., 2])


def _resize_area(grey: np.ndarray, *, width: int, height: int) -> np.ndarray:
    """One ``(H, W)`` float image resized to ``(height, width)`` by pixel-area averaging."""
    if grey.shape == (height, width):
        return grey
    import cv2

    return cv2.resize(grey, (width, height), interpolation=cv2.INTER_AREA)


def patch_normalise(grey: np.ndarray, *, patch: int) -> np.ndarray:
    """Normalise every non-overlapping ``patch x patch`` square to zero mean, unit sample std.

    Parameters
    ----------
    grey : numpy.ndarray
        ``float (N, h, w)`` with ``h`` and ``w`` multiples of ``patch``.
    patch : int
        Patch side, ``>= 2``.

    Returns
    -------
    numpy.ndarray
        ``float64 (N, h, w)``: ``(p - mean) / std`` per patch (``ddof=1``); 0 in flat patches
        (sample std below :data:`FLAT_PATCH_STD`).
    """
    grey = np.asarray(grey, dtype=np.float64)
    n, h, w = grey.shape
    if patch < 2 or h % patch or w % patch:
        raise ValueError(f"patch={patch} must be >= 2 and divide the image size {h}x{w}")
    blocks = grey.reshape(n, h // patch, patch, w // patch, patch)
    mean = blocks.mean(axis=(2, 4), keepdims=True)
    centred = blocks - mean
    std = np.sqrt((centred ** 2).sum(axis=(2, 4), keepdims=True) / (patch * patch - 1))
    flat = std < FLAT_PATCH_STD
    z = np.where(flat, 0.0, centred / np.where(flat, 1.0, std))
    return z.reshape(n, h, w)
