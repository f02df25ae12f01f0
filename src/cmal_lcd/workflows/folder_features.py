"""Features of a user's frames outside the pipeline's dataset (``cmal-lcd match``, ``loops``).

:func:`feature_function` turns a method name into ``extract(images) -> codes``: ``sad`` from
``matching.sad`` of ``conf/`` (importing neither torch nor Hydra), any other method through
:func:`cmal_lcd.features.configured_extractor`, the call the ``extract_features`` stage makes,
with the choice that stage recorded on validation (:func:`recorded_choice`) so that the codes
are those the method's matching protocol was chosen for.
"""

from __future__ import annotations

import functools
import logging
import pickle
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from cmal_lcd.data.pair_inputs import PRECOMPUTED, DescriptorFile

if TYPE_CHECKING:  # imported lazily at run time
    from cmal_lcd.data.frames import FrameFolder

logger = logging.getLogger(__name__)

def check_feature_name(name: str, *, config_overrides: Sequence[str] = ()) -> None:
    """Refuse a ``--features`` value that names no extractor (before any file is read): a
    built-in method, or a node of ``extractors`` in the checkout's ``conf/`` composed with
    ``config_overrides`` (:func:`cmal_lcd.config.command_config`; composed only for a name
    that is not built in).

    Raises
    ------
    ValueError
        ``--features must be one of [...], got '<name>'``.
    """
    from cmal_lcd.features import method_names

    if name in (PRECOMPUTED, *method_names()):
        return
    from cmal_lcd.config import command_config

    names = method_names(command_config(config_overrides).get("extractors"))
    if name not in names:
        raise ValueError(f"--features must be one of {names} (your own: an extractors.<name> "
                         f"node in conf/config.yaml), got {name!r}")


def feature_function(name: str, *, model_dir, features_dir: Path | None = None,
                     quantise_sad: bool = False, config_overrides: Sequence[str] = ()):
    """``(extract(images uint8 (N, H, W, 3)) -> (N, F), metric, info)`` for a feature name.

    ``sad`` imports neither torch nor Hydra; the extractors do. A method that chooses on
    validation (``dnn``: its layer and input side) takes the choice the features stage
    recorded in ``features_dir/info.json`` (the folder of the protocol's training codes,
    :func:`recorded_choice`); else the configured one.
    ``quantise_sad`` compares the SAD thumbnails as bytes (``sad_u8``) whatever
    ``matching.sad.quantise`` says. The config is ``conf/`` composed with ``config_overrides``
    (:func:`cmal_lcd.config.command_config`; for ``sad``, its ``matching.sad`` node).
    """
    if name == "sad":
        from cmal_lcd.config import command_matching
        from cmal_lcd.matching import sad_metric, sad_thumbnails, thumbnail_options

        sad = command_matching(config_overrides)["sad"]
        if quantise_sad:  # --quantise-sad: the bytes whatever the configuration says
            sad["quantise"] = True
        return (functools.partial(sad_thumbnails, **thumbnail_options(sad)), sad_metric(sad),
                {"features": "sad", "label": "SAD", "sad": sad})
    from cmal_lcd.config import command_config
    from cmal_lcd.features import configured_extractor, configured_method
    from cmal_lcd.features.base import encode_with_progress, forward_batch_size
    from cmal_lcd.models.device import pick_device

    cfg = command_config(config_overrides)
    check_feature_name(name, config_overrides=config_overrides)
    entry = configured_method(cfg, name)
    try:
        choice = recorded_choice(features_dir) if entry.apply_choice is not None else None
        extractor, conf = configured_extractor(cfg, name, model_dir=model_dir,
                                               device=pick_device(), choice=choice)
    except (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile) as err:
        if entry.model is None:
            raise
        model_file = Path(model_dir or ".") / entry.model / "model.pt"
        raise ValueError(f"{model_file}: not a readable trained model (truncated, corrupt, or "
                         f"holding objects other than tensors, which are never loaded: "
                         f"{type(err).__name__}); re-run the train stage") from err
    info = {"features": name, "label": extractor.label, "weights": extractor.weights}
    # a bar on a terminal, or a line every 30 s: a DNN takes minutes on thousands of frames
    extract = functools.partial(encode_with_progress, extractor,
                                batch_size=forward_batch_size(extractor, conf),
                                desc=f"match: encode {name}",
                                logger=logger)
    return extract, extractor.metric, info


def recorded_choice(features_dir: Path | None) -> dict | None:
    """The ``layer_selection`` the features stage recorded in ``features_dir/info.json`` (what
    a method chose on validation, ``Method.choose``: ``dnn``'s layer and input side), so that
    the codes are those the protocol and its centring means were made for; None when there is
    no such file or choice."""
    import json

    if features_dir is None:
        return None
    try:
        info = json.loads((Path(features_dir) / "info.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    selection = info.get("layer_selection") if isinstance(info, dict) else None
    if not isinstance(selection, dict) or "selected" not in selection:
        return None
    logger.info("match: %s at %s px, as chosen on validation in %s", selection["selected"],
                selection.get("image_size", "the configured"), Path(features_dir) / "info.json")
    return selection


def extract_pair(features: str, reference: FrameFolder, query: FrameFolder, *, model_dir,
                 features_dir: Path | None = None, quantise_sad: bool = False,
                 config_overrides: Sequence[str] = ()):
    """Codes ``(R, F)`` and ``(Q, F)`` of both folders, their metric and the extractor info
    (``features_dir``, ``quantise_sad``, ``config_overrides``: see :func:`feature_function`);
    descriptor files' own rows, with ``sqeuclidean``."""
    if isinstance(reference, DescriptorFile):
        from cmal_lcd.matching.difference import CODE_METRICS

        return reference.descriptors, query.descriptors, CODE_METRICS["float64"], {
            "features": PRECOMPUTED, "label": f"descriptors ({reference.path.name})",
            "descriptor_key": reference.key, "dimensions": int(reference.descriptors.shape[1])}
    extract, metric, extractor_info = feature_function(features, model_dir=model_dir,
                                                       features_dir=features_dir,
                                                       quantise_sad=quantise_sad,
                                                       config_overrides=config_overrides)
    logger.info("match: %s features of %d reference frames", features, len(reference))
    ref_features = extract(reference.images)
    logger.info("match: %s features of %d query frames", features, len(query))
    query_features = extract(query.images)
    return ref_features, query_features, metric, extractor_info
