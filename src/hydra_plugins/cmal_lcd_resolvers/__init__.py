"""Registers cmal-lcd's OmegaConf resolvers in every process that composes ``conf/``.

Hydra's plugin scan imports every module under ``hydra_plugins`` before it composes, in any
process: ``dvc exp run`` (DVC composes ``params.yaml`` itself, with ``hydra.enabled``),
``cmal-lcd-run`` and ``cmal-lcd compose-params``. So ``${cmal_lcd.feature_inputs:${methods}}``
in ``conf/config.yaml`` resolves everywhere (:mod:`cmal_lcd.features.inputs`). No Hydra plugin
class is defined here.
"""

from cmal_lcd.features.inputs import register_resolver

register_resolver()
