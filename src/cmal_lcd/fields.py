"""Schema fields: a type and a range, never a default (values live in ``conf/*.yaml`` only),
and the one check of them.

The dataclasses of :mod:`cmal_lcd.schema`, and the config dataclasses each model declares
(``cmal_lcd.models.<model>_config``), are built from :func:`value` and :func:`node`. A field's
metadata holds its range, which :func:`check_ranges` reads:

- ``ge``, ``gt``, ``le``, ``lt``: a number, or the name of a sibling field
  (``v_min: le="v_max"``);
- ``choices``: the allowed values;
- ``length``: the number of items of a list;
- ``ordered``: a list's items never decrease (``[low, high]`` ranges, :data:`LOW_HIGH`).

A rule on a list field applies to every item. :func:`checked_node` applies a dataclass's
types and rules to given values (the composed config, :func:`cmal_lcd.schema.validate`; a
model's node, :func:`cmal_lcd.models.config.model_config`), :func:`check_values` to plain
scalars; both raise :class:`SchemaError`, one line naming the key. No import of torch or of the
package's other modules: the check stays light.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from dataclasses import field
from typing import Any

import numpy as np
from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException

#: Metadata keys of a field that :func:`check_ranges` reads.
RULES = ("ge", "gt", "le", "lt", "choices", "length", "ordered")


class SchemaError(ValueError):
    """A config breaks its schema: unknown key, wrong type or value out of range."""


#: A number in [0, 1].
FRACTION = {"ge": 0.0, "le": 1.0}
#: A ``[low, high]`` range: two items, ``low <= high``.
LOW_HIGH = {"length": 2, "ordered": True}


def value(**rules: Any) -> Any:
    """A field with no default (its value comes from ``conf/``) and range ``rules``."""
    unknown = sorted(set(rules) - set(RULES))
    if unknown:
        raise TypeError(f"unknown rules {unknown}; known: {list(RULES)}")
    return field(default=MISSING, metadata=rules)


def node(schema: type) -> Any:
    """A field holding a nested schema (its values come from ``conf/``)."""
    return field(default_factory=schema)


# ---------------------------------------------------------------------------------- the check


def merged(schema: DictConfig, given: Any, *, prefix: str = "") -> DictConfig:
    """``given`` merged into the structured ``schema``: OmegaConf refuses unknown keys and wrong
    types (:class:`SchemaError` ``<prefix><key>: ...``)."""
    try:
        return OmegaConf.merge(schema, given)
    except ConfigKeyError as err:
        raise SchemaError(f"{prefix}{err.full_key}: unknown key; known: "
                          f"{', '.join(_known_keys(err.object_type))}") from None
    except OmegaConfBaseException as err:
        message = (err.msg or str(err)).splitlines()[0]
        raise SchemaError(f"{prefix}{err.full_key}: {message}") from None


def checked_node(schema_type: type, given: Any, *, prefix: str = "") -> DictConfig:
    """``given`` (a mapping or DictConfig) typed by the dataclass ``schema_type`` and checked:
    keys, types with no silent conversion, and ranges. Fields absent from ``given`` stay
    ``???``.

    Raises
    ------
    SchemaError
        ``<prefix><key>: <what is wrong>``, e.g. ``models.cmal.r1_gamma: must be >= 0.0, got
        -1.0``.
    """
    if isinstance(given, DictConfig):
        given = OmegaConf.to_container(given, resolve=True)
    typed = merged(OmegaConf.structured(schema_type), given, prefix=prefix)
    typed_as_given(given, OmegaConf.to_container(typed), key=prefix.rstrip("."))
    check_ranges(typed, prefix=prefix)
    return typed


def _known_keys(schema_type: Any) -> list[str]:
    """Field names of a schema dataclass (the parent of an unknown key)."""
    if dataclasses.is_dataclass(schema_type):
        return [f.name for f in dataclasses.fields(schema_type)]
    return []


def typed_as_given(given: Any, typed: Any, *, key: str) -> Any:
    """``given`` with each value as its schema types it (``typed``: OmegaConf's merge of
    ``given`` into the schema, as a container), in ``given``'s layout: its keys in its order,
    none of the fields the schema adds. An integer where a float is expected becomes a float
    (``pose_tolerance: 5`` -> ``5.0``); any other conversion OmegaConf made silently (``'20'``
    to 20, ``1`` to True) is refused.

    Raises
    ------
    SchemaError
        ``<key>: expected int, got str '20'``.
    """
    if isinstance(given, dict):
        return {k: typed_as_given(v, typed[k], key=f"{key}.{k}" if key else str(k))
                for k, v in given.items()}
    if isinstance(given, list):
        return [typed_as_given(v, t, key=f"{key}[{i}]")
                for i, (v, t) in enumerate(zip(given, typed))]
    if type(given) is not type(typed) and not (type(given) is int and type(typed) is float):
        raise SchemaError(f"{key}: expected {type(typed).__name__}, got "
                          f"{type(given).__name__} {given!r}")
    return typed


def check_values(schema_type: type, values: Mapping[str, Any], *,
                 prefix: str = "") -> dict[str, Any]:
    """Check some scalar fields of ``schema_type`` given as plain values, by the same rules as
    :func:`cmal_lcd.schema.validate` (the one check of each value, for objects built without a config:
    :class:`cmal_lcd.matching.SeqSLAMParams`, :func:`cmal_lcd.matching.trajectory_velocities`).

    NumPy scalars are accepted; an integer is accepted where a float is expected.

    Returns
    -------
    dict
        The values as the schema's Python types (``numpy.int64(5)`` -> ``5``, ``5`` -> ``5.0``
        for a float field).

    Raises
    ------
    SchemaError
        ``<prefix><field>: <what is wrong>``, e.g. ``ds: must be >= 1, got 0``.
    """
    hints = typing.get_type_hints(schema_type)
    rules = {f.name: f.metadata for f in dataclasses.fields(schema_type)}
    typed = {}
    for name, given in values.items():
        if name not in rules:
            raise SchemaError(f"{prefix}{name}: unknown key; known: "
                              f"{', '.join(_known_keys(schema_type))}")
        typed[name] = as_scalar(given, hints[name], key=f"{prefix}{name}")
    for name, item in typed.items():
        if item is not None:
            _check_scalar(item, rules[name], typed, key=f"{prefix}{name}")
    if hasattr(schema_type, "node_rules"):
        schema_type.node_rules(typed, prefix=prefix)
    return typed


def as_scalar(given: Any, hint: Any, *, key: str) -> Any:
    """``given`` as the scalar type ``hint`` (``int``, ``float``, ``bool``, ``str``, or
    ``Optional`` of one), with no silent conversion but int -> float."""
    if typing.get_origin(hint) is typing.Union:  # Optional[X]
        if given is None:
            return None
        hint = next(h for h in typing.get_args(hint) if h is not type(None))
    if isinstance(given, np.generic):
        given = given.item()
    if hint is float and type(given) is int:
        return float(given)
    if type(given) is not hint:
        raise SchemaError(f"{key}: expected {hint.__name__}, got {type(given).__name__} "
                          f"{given!r}")
    return given


def given_value(values: Any, name: str) -> Any:
    """``values[name]``, or None when it is absent or ``???`` (a mapping or a DictConfig)."""
    if isinstance(values, DictConfig):
        return None if name not in values or OmegaConf.is_missing(values, name) \
            else values[name]
    return values.get(name)


def check_ranges(typed: DictConfig, *, prefix: str = "") -> None:
    """Check the range rules of every field of a typed config (recursively).

    Raises
    ------
    SchemaError
        ``matching.ds: must be >= 1, got 0``.
    """
    schema_type = OmegaConf.get_type(typed)
    rules = ({f.name: f.metadata for f in dataclasses.fields(schema_type)}
             if dataclasses.is_dataclass(schema_type) else {})
    for k in typed.keys():
        key = f"{prefix}{k}"
        if OmegaConf.is_missing(typed, k):
            continue
        child = typed[k]
        if isinstance(child, DictConfig):
            check_ranges(child, prefix=f"{key}.")
        elif isinstance(child, ListConfig):
            for i, item in enumerate(child):
                if isinstance(item, DictConfig):
                    check_ranges(item, prefix=f"{key}[{i}].")
        if k in rules and child is not None:
            _check_rules(child, rules[k], typed, key=key)
    if hasattr(schema_type, "node_rules"):
        schema_type.node_rules(typed, prefix=prefix)


def _check_rules(value_: Any, rules: Any, siblings: Any, *, key: str) -> None:
    """Apply a field's rules to its value (to every item of a list)."""
    if isinstance(value_, ListConfig):
        items = list(value_)
        if "length" in rules and len(items) != rules["length"]:
            raise SchemaError(f"{key}: must have {rules['length']} items, got {len(items)}")
        if rules.get("ordered") and any(a is not None and b is not None and a > b
                                        for a, b in zip(items, items[1:])):
            raise SchemaError(f"{key}: must be [low, high] with low <= high, got {items}")
        for i, item in enumerate(items):
            if item is not None and not isinstance(item, (DictConfig, ListConfig)):
                _check_scalar(item, rules, siblings, key=f"{key}[{i}]")
    else:
        _check_scalar(value_, rules, siblings, key=key)


_COMPARISONS = {"ge": (">=", lambda a, b: a >= b), "gt": (">", lambda a, b: a > b),
                "le": ("<=", lambda a, b: a <= b), "lt": ("<", lambda a, b: a < b)}


def _check_scalar(item: Any, rules: Any, siblings: Any, *, key: str) -> None:
    """Check one value against ``choices`` and the bounds ``ge gt le lt``."""
    if "choices" in rules and item not in rules["choices"]:
        raise SchemaError(f"{key}: must be one of {list(rules['choices'])}, got {item!r}")
    if isinstance(item, float) and not math.isfinite(item):
        raise SchemaError(f"{key}: must be a finite number, got {item!r}")
    for rule, (symbol, holds) in _COMPARISONS.items():
        if rule not in rules:
            continue
        bound, name = rules[rule], str(rules[rule])
        if isinstance(bound, str):  # a sibling field
            if given_value(siblings, bound) is None:
                continue
            name = f"{key.rpartition('.')[0]}.{bound} ({siblings[bound]})".lstrip(".")
            bound = siblings[bound]
        if not holds(item, bound):
            raise SchemaError(f"{key}: must be {symbol} {name}, got {item!r}")
