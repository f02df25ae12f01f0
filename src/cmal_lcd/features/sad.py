"""The ``sad`` method: SeqSLAM's patch-normalised grey thumbnails (the original SeqSLAM feature).

The codes are ``cmal_lcd.matching.sad_thumbnails`` (grey, resize to ``width`` x ``height``,
patch normalisation) with the ``matching.sad`` config node, compared with the sum of absolute
differences. They are stored as float32 z-scores: ``width * height * 4`` bytes per frame
(64 x 32: 8 KiB); OpenSeqSLAM quantises the same thumbnails to uint8 (2 KiB per frame).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from cmal_lcd.features.base import FeatureExtractor, config_int, encode_in_batches

def sad_conf(cfg: Mapping[str, Any], dataset_meta: Mapping[str, Any] | None) -> dict[str, Any]:
    """``extra_conf`` of ``sad``: the thumbnail parameters live in ``matching.sad`` (shared with
    SeqSLAM)."""
    from omegaconf import DictConfig, OmegaConf

    sad = cfg["matching"]["sad"]
    return {"sad": OmegaConf.to_container(sad, resolve=True) if isinstance(sad, DictConfig)
            else dict(sad)}


def build_sad(conf: Mapping[str, Any], *, model_dir: Path | None = None,
              device: str = "cpu") -> FeatureExtractor:
    """The ``sad`` extractor.

    Parameters
    ----------
    conf : mapping
        The ``features`` node merged with ``sad`` = the ``matching.sad`` node
        (``width``, ``height``, ``patch``; ``patch: 0`` disables patch normalisation), and
        ``batch_size``.
    model_dir, device
        Unused (NumPy on the CPU).

    Returns
    -------
    FeatureExtractor
        Metric ``sad`` (``sad_u8`` when ``quantise``); codes float32 ``(N, height * width)``.
    """
    from cmal_lcd.matching import sad_metric, sad_thumbnails

    sad_conf = dict(conf.get("sad") or {})
    width, height, patch = (config_int(sad_conf, key, where="matching.sad", minimum=low)
                            for key, low in (("width", 1), ("height", 1), ("patch", 0)))
    batch_size = config_int(conf, "batch_size", where="features")

    def encode_batch(batch: np.ndarray) -> np.ndarray:
        return np.asarray(sad_thumbnails(batch, width=width, height=height, patch=patch),
                          dtype=np.float32)

    return FeatureExtractor(
        name="sad", label="SAD", metric=sad_metric(sad_conf),
        weights=f"none (grey {width}x{height} thumbnails, " + (
            f"{patch}x{patch} patch normalisation)" if patch else "no patch normalisation)"),
        encode=lambda images: encode_in_batches(images, encode_batch, batch_size=batch_size),
        device="cpu", backend="numpy", batch_size=batch_size,
    )
