"""Shared test fixtures and settings.

- One compute thread for torch and numba: the development machine has 2 cores shared by several
  people, and tiny tests gain nothing from threads. (Thread-count independence of the numba
  kernels is tested explicitly in ``tests/matching``.)
- ``reference_run``: one uninterrupted ``dvc repro`` of the tiny pipeline per session, in a
  scratch repository (``tests/pipeline_runs.py``). Tests that change or re-run anything in it
  work on a ``shutil.copytree`` of it, so every test sees the same finished run and the session
  pays for one run, not one per test module.
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
#: VPR-Bench's Corridor (111 + 111 real frames, ``ground_truth_new.npy``), beside the checkout.
CORRIDOR_DIR = REPO_ROOT.parent / "shared" / "data" / "vpr_bench_corridor"


#: The test files that use ``reference_run``. Under pytest-xdist (the README's test command,
#: ``-n auto --dist loadfile``) they run on one worker, so the tiny pipeline runs once per
#: session; every other file runs whole on one worker, so its module fixtures are built once.
REFERENCE_RUN_FILES = (
    "tests/reliability/test_determinism.py",
    "tests/reliability/test_interruptions.py",
    "tests/reliability/test_old_or_new.py",
    "tests/test_pipeline.py",
)


def file_of_test(nodeid: str) -> str:
    """The file part of a test id (``tests/x.py::test_y[1]`` -> ``tests/x.py``)."""
    return nodeid.split("::", 1)[0]


def pytest_itemcollected(item):
    """A test that uses ``reference_run`` outside :data:`REFERENCE_RUN_FILES` is refused: under
    xdist it would build a second reference run on another worker."""
    path = file_of_test(item.nodeid)
    if "reference_run" in getattr(item, "fixturenames", ()) and path not in REFERENCE_RUN_FILES:
        raise pytest.UsageError(f"{path} uses the reference_run fixture: add it to "
                                f"REFERENCE_RUN_FILES in tests/conftest.py")


def pytest_collection_modifyitems(config, items):
    """On an xdist worker, the ``reference_run`` files first: they are the longest chain of
    work (three tiny pipeline runs), so the scheduler should start them before anything else."""
    if hasattr(config, "workerinput"):
        items.sort(key=lambda item: file_of_test(item.nodeid) not in REFERENCE_RUN_FILES)


try:
    from xdist.scheduler import LoadFileScheduling
except ImportError:  # pragma: no cover (xdist is in the test extras)
    pass
else:
    class _ReferenceRunFiles(LoadFileScheduling):
        """``--dist loadfile``, with :data:`REFERENCE_RUN_FILES` as one unit of work.

        (xdist's own ``loadgroup`` marks cannot do this under pytest 9.2: xdist 3.8 renames
        ``item._nodeid``, which pytest 9.2 no longer reads.)
        """

        def _split_scope(self, nodeid: str) -> str:
            path = file_of_test(nodeid)
            return "reference_run" if path in REFERENCE_RUN_FILES else path

    def pytest_xdist_make_scheduler(config, log):
        if config.getvalue("dist") != "loadfile":
            return None
        config.option.loadscopereorder = False  # keep the workers' order: reference_run first
        return _ReferenceRunFiles(config, log)


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
def reference_run(tmp_path_factory) -> Path:
    """A scratch repository after one uninterrupted ``dvc repro`` of the tiny pipeline.

    Read it, compare with it, ``git clone`` it or copy it; never change it in place.
    """
    from pipeline_runs import make_scratch_repo, run

    repo = make_scratch_repo(tmp_path_factory.mktemp("reference"))
    run(["dvc", "repro"], repo)
    return repo


@pytest.fixture(scope="session")
def nordland_dir() -> Path:
    """``../shared/data/nordland_summer_winter`` with ``summer/`` and ``winter/``, or skip."""
    for sub in ("summer", "winter"):
        if not (NORDLAND_DIR / sub).is_dir():
            pytest.skip(f"real Nordland frames not found at {NORDLAND_DIR / sub} "
                        f"(../shared beside the checkout); skipping the real-data test")
    return NORDLAND_DIR


@pytest.fixture(scope="session")
def corridor_dir() -> Path:
    """``../shared/data/vpr_bench_corridor`` (VPR-Bench's Corridor: ``ref/``, ``query/``,
    ``ground_truth_new.npy``), or skip."""
    for sub in ("ref", "query", "ground_truth_new.npy"):
        if not (CORRIDOR_DIR / sub).exists():
            pytest.skip(f"VPR-Bench's Corridor not found at {CORRIDOR_DIR / sub} (../shared "
                        f"beside the checkout); skipping the real-data test")
    return CORRIDOR_DIR
