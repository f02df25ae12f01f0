"""What each method's ``extract_features@<method>`` stage reads: ``feature_inputs`` in params.yaml.

Every features stage reads the dataset, the features code and the params ``dvc.yaml`` lists
for every method (``extract_features``: ``seed``, ``runtime.threads``, ``features.*``). Beyond
that, each method reads one file (its trained weights ``models/<model>/model.pt``, or, for a
method that has none, its own source file) and a few config nodes of its own
(its node ``extractors.<method>`` and the nodes its :class:`cmal_lcd.features.Method` entry
names). ``dvc.yaml`` declares exactly these, so that a change to
one model re-runs only the methods that read it (``models.cmal.iterations`` re-runs ``cmal``
and ``cmal_untrained``; SAD, DNN and BiGAN stay cached).

An encoder of yours (``extractors.<name>``, :mod:`cmal_lcd.features.custom`) reads the file
of its ``_target_``'s module (or its ``inputs``: the file or folder it reads) and its own node.

A DVC ``matrix`` cannot look a value up per item (nested ``${...}`` is not supported), and a
list cannot be interpolated into ``deps`` or ``params``. So the composed config carries,
derived from ``methods`` and ``extractors`` by the resolver
``${cmal_lcd.feature_inputs:${methods},${extractors}}`` (``conf/config.yaml``), one entry per
method::

    feature_inputs:
      sad: {file: src/cmal_lcd/features/sad.py,
            params: [extractors.sad, matching.sad, runtime.threads]}
      cmal: {file: models/cmal/model.pt, params: [extractors.cmal, runtime.threads, runtime.threads]}
      hog: {file: src/my_hog.py, params: [extractors.hog, runtime.threads, runtime.threads]}

and ``extract_features`` is a ``foreach`` over it (stage names ``extract_features@<method>``,
as before). ``params`` always has :data:`PARAM_SLOTS` entries (dvc.yaml names each slot),
padded with ``runtime.threads``, which every features stage declares anyway (DVC merges repeats).

The resolver ``${cmal_lcd.with_extractors:[sad, ...],${extractors}}`` makes the default
``methods``: the list given, then every node of ``extractors`` that is not a built-in one
(``conf/extractors/builtin.yaml``: the extensions ``cmal_place`` and ``place_encoder`` run
only when ``methods`` names them).

The resolvers are registered when :mod:`cmal_lcd.config` is imported (``compose-params``,
``cmal-lcd-run``) and by the Hydra plugin module ``hydra_plugins.cmal_lcd_resolvers``, which
Hydra's plugin scan imports in any process that composes, ``dvc exp run`` included.
"""

from __future__ import annotations

from typing import Any, Iterable, Mapping

#: Per-method params entries in dvc.yaml (``${item.params.0}`` .. ``${item.params.2}``): the
#: method's own node and up to two more.
PARAM_SLOTS = 3
#: The filler of unused slots: a node every features stage declares anyway (dvc.yaml).
PAD = "runtime.threads"
#: The resolvers' names in ``conf/config.yaml``.
RESOLVER = "cmal_lcd.feature_inputs"
METHODS_RESOLVER = "cmal_lcd.with_extractors"


def method_inputs(method: str, extractors: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``{"file": path, "params": [key, key, key]}``: what ``method`` reads beyond the common
    inputs: its own node ``extractors.<method>`` and the nodes its entry names
    (``Method.params``); its trained weights ``models/<model>/model.pt`` (``Method.model``),
    else its ``own_file``, else its ``inputs``, else the file of its ``_target_``'s module.

    Raises
    ------
    ValueError
        ``methods: unknown feature method ...`` for a name not in ``extractors``;
        ``_target_: cannot find the module ...`` for an encoder of yours.
    """
    from cmal_lcd.features import method_entry, method_names
    from cmal_lcd.features.custom import TARGET

    if method not in method_names(extractors):
        raise ValueError(f"methods: unknown feature method {method!r}; expected some of "
                         f"{method_names(extractors)}")
    entry = method_entry(method, extractors)
    node = (extractors or {}).get(method) or {}
    params = list(dict.fromkeys([f"extractors.{method}", *entry.params]))
    if entry.model:
        own_file = f"models/{entry.model}/model.pt"
    elif entry.own_file or node.get("inputs") is not None:
        own_file = str(entry.own_file or node["inputs"])
    else:
        own_file = target_file(str(node[TARGET]))
    if len(params) > PARAM_SLOTS:
        raise ValueError(f"extractors.{method}.params: at most {PARAM_SLOTS - 1} config nodes "
                         f"beside its own, got {list(entry.params)}")
    return {"file": own_file, "params": [*params, *[PAD] * (PARAM_SLOTS - len(params))]}


def target_file(target: str) -> str:
    """The file of ``target``'s module, relative to the checkout when inside it
    (:func:`~cmal_lcd.features.custom.method_source_file`)."""
    from cmal_lcd.checkout import CheckoutNotFoundError, checkout_root
    from cmal_lcd.features.custom import method_source_file

    try:
        root = checkout_root()
    except CheckoutNotFoundError:
        root = None
    return method_source_file(target, root=root)


def feature_inputs(methods: Iterable[str], extractors: Mapping[str, Any] | None = None
                   ) -> dict[str, dict[str, Any]]:
    """``{method: method_inputs(method)}`` for the names of ``methods`` it can derive, in order.

    A name it cannot derive (unknown, or a user's method whose module is not found) gets no
    entry: composition must not fail inside the resolver, where the error could not name the
    item; :func:`cmal_lcd.config.check_config` refuses it next, naming ``methods[i]`` or
    ``extractors.<name>``.
    """
    inputs = {}
    for method in map(str, methods):
        try:
            inputs[method] = method_inputs(method, extractors)
        except (ValueError, KeyError, TypeError):
            continue
    return inputs


def with_extractors(methods: Iterable[str], extractors: Mapping[str, Any] | None
                    ) -> list[str]:
    """``methods``, then every name of ``extractors`` neither in it nor built in (the default
    ``methods``)."""
    from cmal_lcd.features import built_in_nodes

    names = [str(m) for m in methods]
    return [*names, *(str(k) for k in (extractors or {})
                      if str(k) not in names and str(k) not in built_in_nodes())]


def register_resolver() -> None:
    """Register ``${cmal_lcd.feature_inputs:<methods>,<extractors>}`` and
    ``${cmal_lcd.with_extractors:<methods>,<extractors>}`` with OmegaConf (idempotent)."""
    from omegaconf import OmegaConf

    def plain(node: Any) -> Any:  # the one plain-copy helper, imported when first resolving
        from cmal_lcd.features import _plain

        return _plain(node)

    # containers, not dicts and lists: OmegaConf.resolve puts them in place of the string
    OmegaConf.register_new_resolver(
        RESOLVER, lambda methods, extractors=None: OmegaConf.create(
            feature_inputs(list(methods), plain(extractors))), replace=True)
    OmegaConf.register_new_resolver(
        METHODS_RESOLVER, lambda methods, extractors=None: OmegaConf.create(
            with_extractors(list(methods), plain(extractors))), replace=True)
