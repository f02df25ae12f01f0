"""What every model's config has: the training loop's keys (``conf/model/<name>.yaml``).

Each model declares its config dataclass in a module of its own, without torch
(``cmal_config.py``, ``bigan_config.py``), subclassing :class:`TrainingConfig`, with class
variables: ``name`` (the key of ``models`` in the config and of :data:`cmal_lcd.models.MODELS`),
``model_class`` (``"module.Class"``, imported when the model is first built) and its
capabilities (``conditional``), which generic code reads without importing torch. The schema
(:mod:`cmal_lcd.schema`) types each node of ``models`` by its model's dataclass, and the
training loop knows a model's keys from it; no generic module lists a model's keys.

Fields carry a type and a range, never a default (:mod:`cmal_lcd.fields`). A model is built
from an instance of its dataclass (:func:`model_config`), checked once, by those rules: the
models and the training loop read its attributes and check nothing again.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar, Optional

from omegaconf import OmegaConf

from cmal_lcd.fields import SchemaError, checked_node, given_value, value

#: Normalisation layers of the conv pyramids (``cmal_lcd.models.networks``).
NORMS = ("instance", "batch", "none")
#: ``select``: ``best_validation`` keeps the validated iteration (``validate_every`` multiples
#: and the last; never the untrained iteration 0) with the highest validation R@100P
#: (``cmal_lcd.models.training.SELECTION_CRITERION``), the earliest on a tie, chosen on the
#: validation drives only; ``last`` keeps the weights after ``iterations``.
SELECTIONS = ("best_validation", "last")
#: ``precision``: ``float32``, every op in float32; ``bfloat16``, the step under
#: ``torch.autocast`` in bfloat16 (convolutions and matrix products in bfloat16, reductions and
#: losses in float32; weights and optimiser state stay float32): for GPUs and CPUs with bfloat16
#: units (AMX, AVX512-BF16), which then need ``CMAL_LCD_NATIVE_KERNELS=1`` (the AVX2 pin
#: emulates bfloat16, ~10x slower). Encoding for matching is float32 either way.
PRECISIONS = ("float32", "bfloat16")
#: ``compile``: ``torch.compile`` backends for the training step's modules (null: eager).
#: ``inductor`` generates kernels (for a GPU, where the step is launch-bound); ``aot_eager``
#: traces through the same graph capture without code generation (a quick check of the path).
COMPILE_BACKENDS = ("inductor", "aot_eager")


@dataclass
class TrainingConfig:
    """Fields every trained model has: input size, code, and the training schedule."""

    name: ClassVar[str] = ""
    model_class: ClassVar[str] = ""
    #: ``conf/`` groups of the model's own that set part of its node: group -> schema
    groups: ClassVar[dict[str, type]] = {}
    #: the model learns every condition (CMAL translates between them), so training needs at
    #: least two conditions and frames of each
    conditional: ClassVar[bool] = False

    image_size: int = value(ge=8)                # pixels, a power of two
    code_dim: int = value(ge=1)
    width: int = value(ge=1)                     # channels of the first conv level
    encoder_norm: str = value(choices=NORMS)
    iterations: int = value(ge=1)
    batch_size: int = value(ge=1)
    checkpoint_every: int = value(ge=1)
    log_every: int = value(ge=1)
    validate_every: int = value(ge=0)            # 0 = off
    select: str = value(choices=SELECTIONS)      # the weights model.pt keeps
    precision: str = value(choices=PRECISIONS)   # arithmetic of the training step
    compile: Optional[str] = value(choices=COMPILE_BACKENDS)  # torch.compile (null: eager)
    sample_every: int = value(ge=0)
    sample_count: int = value(ge=1)
    heldout_fraction: float = value(ge=0.0, lt=1.0)

    @staticmethod
    def node_rules(values: Any, *, prefix: str = "") -> None:
        """The rule joining two fields: validation at logged iterations only
        (``validate_every`` a multiple of ``log_every``). Fields not given are skipped."""
        validate_every, log_every = (given_value(values, k) for k in ("validate_every",
                                                                       "log_every"))
        if validate_every and log_every and validate_every % log_every:
            raise SchemaError(f"{prefix}validate_every: expected a multiple of log_every "
                              f"({log_every}), got {validate_every}")


def config_keys(config: type[TrainingConfig]) -> frozenset[str]:
    """The keys a model's config node may hold: the fields of its dataclass."""
    return frozenset(f.name for f in dataclasses.fields(config))


def model_config(name: str, node: Any) -> TrainingConfig:
    """``models.<name>`` (a mapping, e.g. ``conf/model/<name>.yaml`` composed, or the ``config``
    of a ``model.pt``) as an instance of the model's config dataclass
    (:data:`cmal_lcd.models.MODEL_CONFIGS`), checked by its fields' types and rules.

    Raises
    ------
    SchemaError
        One line naming the key: an unknown name, key or type, a value out of range, or a field
        the node lacks (``models.cmal.ema_decay: missing from the model config``; a
        ``model.pt`` written before the key existed is refused so).
    """
    from cmal_lcd.models import MODEL_CONFIGS, MODEL_NAMES

    if name not in MODEL_CONFIGS:
        raise SchemaError(f"name: expected one of {MODEL_NAMES}, got {name!r}")
    prefix = f"models.{name}."
    typed = checked_node(MODEL_CONFIGS[name], node, prefix=prefix)
    missing = sorted(OmegaConf.missing_keys(typed))
    if missing:
        raise SchemaError(f"{prefix}{missing[0]}: missing from the model config")
    return OmegaConf.to_object(typed)
