"""Which checkout a command works on, and its ``dvc.yaml``: no import beyond the standard
library, so the chain's paths (:mod:`cmal_lcd.paths`), the chain (:mod:`cmal_lcd.chain`) and
the libraries find them without importing the config machinery (:mod:`cmal_lcd.config`
re-exports these names)."""

from __future__ import annotations

import os
from pathlib import Path

#: The source checkout this package was installed from (``src/cmal_lcd/checkout.py`` -> repo).
#: Library defaults and tests only; commands use :func:`checkout_root` (the working
#: directory's checkout).
REPO_ROOT = Path(__file__).resolve().parents[2]
#: ``conf/`` of :data:`REPO_ROOT`: what library defaults and tests compose.
CONF_DIR = REPO_ROOT / "conf"

#: Environment variable naming the checkout commands work on (overrides the working directory).
REPO_ENV = "CMAL_LCD_REPO"


class CheckoutNotFoundError(FileNotFoundError):
    """No checkout (a folder holding ``conf/config.yaml``) where a command looked."""


def checkout_root(repo: str | os.PathLike | None = None, *,
                  start: str | os.PathLike | None = None) -> Path:
    """The checkout a command works on.

    Parameters
    ----------
    repo : path-like, optional
        An explicit checkout (``--repo``); else ``$CMAL_LCD_REPO``; else the nearest folder at
        or above ``start`` holding ``conf/config.yaml``.
    start : path-like, optional
        Where the search starts (default: the working directory).

    Raises
    ------
    CheckoutNotFoundError
        Naming the folder without ``conf/config.yaml`` (one line).
    """
    explicit = repo if repo is not None else os.environ.get(REPO_ENV) or None
    if explicit is not None:
        root = Path(explicit).expanduser().resolve()
        if not (root / "conf" / "config.yaml").is_file():
            source = "--repo" if repo is not None else f"${REPO_ENV}"
            raise CheckoutNotFoundError(f"{root}: no conf/config.yaml in this folder ({source})")
        return root
    here = Path(start if start is not None else os.getcwd()).resolve()
    for folder in (here, *here.parents):
        if (folder / "conf" / "config.yaml").is_file():
            return folder
    raise CheckoutNotFoundError(
        f"{here}: no conf/config.yaml here or in a parent folder; run in a cmal-lcd checkout, "
        f"pass --repo, or set {REPO_ENV}")


def checkout_dvc_yaml() -> Path:
    """The ``dvc.yaml`` of the checkout whose ``conf/`` is composed
    (:func:`checkout_root`: the one ``dvc repro`` runs in, or the app's), else
    that of the checkout this package was installed from (a folder holding only a ``conf/``
    runs the package's own chain).

    Raises
    ------
    FileNotFoundError
        When neither has one.
    """
    try:
        candidates = [checkout_root() / "dvc.yaml", REPO_ROOT / "dvc.yaml"]
    except CheckoutNotFoundError:
        candidates = [REPO_ROOT / "dvc.yaml"]
    found = next((path for path in candidates if path.is_file()), None)
    if found is None:
        raise FileNotFoundError(f"{candidates[0]}: no dvc.yaml, the chain's declaration")
    return found
