"""One source of configuration: Hydra's ``conf/``, composed into ``params.yaml`` for DVC.

DVC stages read ``params.yaml`` (:func:`load_params`); the Hydra app and the tests compose
``conf/`` directly (:func:`compose`). :func:`compose_params_yaml` writes the composition to
``params.yaml`` with DVC's own ``compose_and_dump``, byte-identical to what ``dvc exp run``
writes when ``hydra.enabled`` is set.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf

#: Repository root (``src/cmal_lcd/config.py`` -> repo).
REPO_ROOT = Path(__file__).resolve().parents[2]
CONF_DIR = REPO_ROOT / "conf"
PARAMS_FILE = REPO_ROOT / "params.yaml"


def load_params(path: str | Path = "params.yaml") -> DictConfig:
    """Load a composed ``params.yaml``.

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist (run ``cmal-lcd compose-params``).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no such params file; compose it from conf/ with `cmal-lcd compose-params`"
        )
    cfg = OmegaConf.load(path)
    if not isinstance(cfg, DictConfig):
        raise ValueError(f"{path}: expected a mapping at the top level")
    return cfg


def compose(overrides: Sequence[str] = (), *, config_dir: str | Path = CONF_DIR,
            config_name: str = "config") -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with Hydra overrides, resolved.

    Parameters
    ----------
    overrides : sequence of str
        Hydra overrides, e.g. ``["debug=tiny", "matching.ds=5"]``.
    """
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(Path(config_dir).resolve()), version_base="1.3"):
        cfg = hydra_compose(config_name=config_name, overrides=list(overrides))
    OmegaConf.resolve(cfg)
    return cfg


def compose_params_yaml(overrides: Sequence[str] = (), *, output: str | Path = PARAMS_FILE,
                        config_dir: str | Path = CONF_DIR, config_name: str = "config") -> Path:
    """Write the composition of ``conf/`` (plus overrides) to ``output`` as DVC does."""
    from dvc.utils.hydra import compose_and_dump

    output = Path(output)
    compose_and_dump(output, str(Path(config_dir).resolve()), None, config_name,
                     str(output.parent), list(overrides))
    return output
