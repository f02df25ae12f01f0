"""Schema fields: a type and a range, never a default (values live in ``conf/*.yaml`` only).

The dataclasses of :mod:`cmal_lcd.schema`, and the config dataclasses each model declares
(``cmal_lcd.models.<model>_config``), are built from these two helpers. A field's metadata
holds its range, which :func:`cmal_lcd.schema.check_ranges` reads:

- ``ge``, ``gt``, ``le``, ``lt``: a number, or the name of a sibling field
  (``v_min: le="v_max"``);
- ``choices``: the allowed values;
- ``length``: the number of items of a list;
- ``ordered``: a list's items never decrease (``[low, high]`` ranges, :data:`LOW_HIGH`).

A rule on a list field applies to every item. No import of torch or of the package's other
modules: the schema check stays light.
"""

from __future__ import annotations

from dataclasses import field
from typing import Any

from omegaconf import MISSING

#: Metadata keys of a field that :func:`cmal_lcd.schema.check_ranges` reads.
RULES = ("ge", "gt", "le", "lt", "choices", "length", "ordered")
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
