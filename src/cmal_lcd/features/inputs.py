"""What each method's ``extract_features@<method>`` stage reads: ``feature_inputs`` in params.yaml.

Every features stage reads the dataset, the features code and :data:`COMMON_PARAMS`. Beyond
that, each method reads one file (its trained weights ``models/<model>/model.pt``, or, for a
method that has none, its own source file) and a few config nodes of its own
(:class:`cmal_lcd.features.Method`). ``dvc.yaml`` declares exactly these, so that a change to
one model re-runs only the methods that read it (``models.cmal.iterations`` re-runs ``cmal``
and ``cmal_untrained``; SAD, DNN and BiGAN stay cached).

A DVC ``matrix`` cannot look a value up per item (nested ``${...}`` is not supported), and a
list cannot be interpolated into ``deps`` or ``params``. So the composed config carries,
derived from ``methods`` by the resolver ``${cmal_lcd.feature_inputs:${methods}}``
(``conf/config.yaml``), one entry per method::

    feature_inputs:
      sad: {file: src/cmal_lcd/features/sad.py, params: [matching.sad, runtime.threads]}
      cmal: {file: models/cmal/model.pt, params: [runtime.threads, runtime.threads]}

and ``extract_features`` is a ``foreach`` over it (stage names ``extract_features@<method>``,
as before). ``params`` always has :data:`PARAM_SLOTS` entries (dvc.yaml names each slot),
padded with ``runtime.threads``, which every features stage declares anyway (DVC merges repeats).

The resolver is registered when :mod:`cmal_lcd.config` is imported (``compose-params``,
``cmal-lcd-run``) and by the Hydra plugin module ``hydra_plugins.cmal_lcd_resolvers``, which
Hydra's plugin scan imports in any process that composes, ``dvc exp run`` included.
"""

from __future__ import annotations

from typing import Any, Iterable

#: Config nodes every features stage reads (declared on all of them in dvc.yaml).
COMMON_PARAMS = ("seed", "runtime.threads", "features.batch_size", "features.timing",
                 "features.train_frames_per_condition")
#: Per-method params entries in dvc.yaml (``${item.params.0}``, ``${item.params.1}``).
PARAM_SLOTS = 2
#: The filler of unused slots: a node every features stage declares anyway.
PAD = "runtime.threads"
#: The resolver's name in ``conf/config.yaml``.
RESOLVER = "cmal_lcd.feature_inputs"


def method_inputs(method: str) -> dict[str, Any]:
    """``{"file": path, "params": [key, key]}``: what ``method`` reads beyond the common inputs.

    Raises
    ------
    ValueError
        ``methods: unknown feature method ...`` for a name not in the registry.
    """
    from cmal_lcd.features import METHOD_NAMES, METHODS

    if method not in METHODS:
        raise ValueError(f"methods: unknown feature method {method!r}; expected some of "
                         f"{list(METHOD_NAMES)}")
    entry = METHODS[method]
    own_file = f"models/{entry.model}/model.pt" if entry.model else entry.own_file
    if own_file is None or len(entry.params) > PARAM_SLOTS:
        raise ValueError(f"cmal_lcd.features.METHODS[{method!r}]: needs a model or an own_file "
                         f"and at most {PARAM_SLOTS} params")
    return {"file": own_file,
            "params": [*entry.params, *[PAD] * (PARAM_SLOTS - len(entry.params))]}


def feature_inputs(methods: Iterable[str]) -> dict[str, dict[str, Any]]:
    """``{method: method_inputs(method)}`` for the known names of ``methods``, in its order.

    An unknown name gets no entry: composition must not fail inside the resolver, where the
    error could not name the item; :func:`cmal_lcd.config.check_config` refuses it next,
    naming ``methods[i]``.
    """
    from cmal_lcd.features import METHODS

    return {str(m): method_inputs(str(m)) for m in methods if str(m) in METHODS}


def register_resolver() -> None:
    """Register ``${cmal_lcd.feature_inputs:<methods>}`` with OmegaConf (idempotent)."""
    from omegaconf import OmegaConf

    # a DictConfig, not a dict: OmegaConf.resolve puts a container in place of the string
    OmegaConf.register_new_resolver(
        RESOLVER, lambda methods: OmegaConf.create(feature_inputs(list(methods))), replace=True)
