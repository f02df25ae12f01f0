"""Catalogue: determinism (docs/reliability.md, "Determinism").

Two uninterrupted runs of the tiny pipeline from scratch (the second in a `git clone` of the
first's scratch repository, so both run the same code), same seed, give byte-identical
metrics and tables (except Table III, which holds wall-clock timings), and the same dataset,
codes and model weights.
"""

from __future__ import annotations

import pytest

from pipeline_runs import TIMED_TABLES, clone_scratch_repo, comparable_outputs, run


@pytest.fixture(scope="module")
def second_run(reference_run, tmp_path_factory):
    """A clone of the reference run's sources, run from scratch."""
    repo = clone_scratch_repo(reference_run, tmp_path_factory.mktemp("second") / "repo")
    run(["dvc", "repro"], repo)
    return repo


def test_metrics_files_are_byte_identical(reference_run, second_run):
    for name in ("metrics.json", "metrics_paper.json"):
        first = (reference_run / "reports" / name).read_bytes()
        assert first == (second_run / "reports" / name).read_bytes(), name
        assert len(first) > 100, name


def test_tables_are_byte_identical_except_the_timings(reference_run, second_run):
    tables = sorted(p.name for p in (reference_run / "reports" / "tables").iterdir())
    assert tables == sorted(p.name for p in (second_run / "reports" / "tables").iterdir())
    compared = [t for t in tables if not t.startswith(TIMED_TABLES)]
    assert len(compared) >= 12, compared
    for name in compared:
        assert (reference_run / "reports" / "tables" / name).read_bytes() == \
            (second_run / "reports" / "tables" / name).read_bytes(), name


def test_every_intermediate_output_is_identical(reference_run, second_run):
    first, second = comparable_outputs(reference_run), comparable_outputs(second_run)
    assert any(k.startswith("data/features/") for k in first)
    assert any(k.startswith("models/") for k in first)
    differing = sorted(k for k in first.keys() | second.keys() if first.get(k) != second.get(k))
    assert differing == []
