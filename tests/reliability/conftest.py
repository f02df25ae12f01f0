"""Fixtures shared by the reliability tests: one uninterrupted tiny pipeline run per session."""

from __future__ import annotations

import pytest

from pipeline_runs import make_scratch_repo, run


@pytest.fixture(scope="session")
def reference_run(tmp_path_factory):
    """A scratch repository after one uninterrupted ``dvc repro`` of the tiny pipeline."""
    repo = make_scratch_repo(tmp_path_factory.mktemp("reference"))
    run(["dvc", "repro"], repo)
    return repo
