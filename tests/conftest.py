"""Shared test fixtures and settings.

- One compute thread for torch and numba: the development machine has 2 cores shared by several
  people, and tiny tests gain nothing from threads. (Thread-count independence of the numba
  kernels is tested explicitly in ``tests/matching``.)
- ``nordland_dir``: the real Nordland summer/winter frames, found beside the checkout at
  ``../shared/data/nordland_summer_winter`` (relative to the repository root, never an absolute
  path); tests that use it skip with the reason when it is absent (a fresh clone has no
  ``../shared``).
"""

from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
NORDLAND_DIR = REPO_ROOT.parent / "shared" / "data" / "nordland_summer_winter"


def pytest_configure(config):
    try:
        import numba

        numba.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (the folder holding ``pyproject.toml``)."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def nordland_dir() -> Path:
    """``../shared/data/nordland_summer_winter`` with ``summer/`` and ``winter/``, or skip."""
    for sub in ("summer", "winter"):
        if not (NORDLAND_DIR / sub).is_dir():
            pytest.skip(f"real Nordland frames not found at {NORDLAND_DIR / sub} "
                        f"(../shared beside the checkout); skipping the real-data test")
    return NORDLAND_DIR
