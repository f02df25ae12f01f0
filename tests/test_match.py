"""``cmal-lcd match`` on folders of different lengths: which folder is the reference, which
ground truth, which tolerance.

The reference folder holds 60 crops of a panorama (places 0..59, 1 m apart); the query folder
40 crops of places 15..54 under another brightness (offset start, shorter drive). Every
expected value is counted from this construction, not from the code under test.
"""

import json

import cv2
import numpy as np
import pytest

from cmal_lcd.commands import main
from cmal_lcd.evaluation import loop_closure
from cmal_lcd.matching import SeqSLAMParams

DS = SeqSLAMParams.defaults().ds
REFERENCE = np.arange(0, 60)
QUERY = np.arange(15, 55)
PANORAMA = cv2.GaussianBlur(np.random.default_rng(0).random((32, 64 + 4 * 80)), (0, 0), 2)


def write_drive(folder, places, *, brightness, seed, poses=None, y=0.0):
    """One PNG per place (the panorama crop at 4 px per place); ``poses.csv`` (x, ``y``)
    when given."""
    rng = np.random.default_rng(seed)
    folder.mkdir()
    for i, place in enumerate(places):
        crop = PANORAMA[:, 4 * place:4 * place + 64] * brightness + 0.05 * rng.random((32, 64))
        grey = np.clip(255 * crop / PANORAMA.max(), 0, 255).astype(np.uint8)
        assert cv2.imwrite(str(folder / f"frame-{i:04d}.png"), grey)
    if poses is not None:
        lines = ["name,x,y"] + [f"frame-{i:04d}.png,{x},{y}" for i, x in enumerate(poses)]
        (folder / "poses.csv").write_text("\n".join(lines) + "\n")
    return folder


@pytest.fixture
def calls(monkeypatch):
    """The lengths of the reference and query features handed to the evaluation (the
    ``evaluate`` stage's :func:`~cmal_lcd.evaluation.loop_closure.evaluate_pair`)."""
    seen = []
    real = loop_closure.evaluate_pair

    def recording(reference, query, truth, **kw):
        seen.append((len(reference), len(query)))
        return real(reference, query, truth, **kw)

    monkeypatch.setattr(loop_closure, "evaluate_pair", recording)
    return seen


def run(tmp_path, *args, reference=None, query=None):
    out = tmp_path / "out"
    assert main(["match", str(reference), str(query), "--out", str(out), *args]) == 0
    return json.loads((out / "metrics.json").read_text())


def test_first_folder_is_the_reference_with_offset_unequal_drives_and_poses(tmp_path, calls):
    ref = write_drive(tmp_path / "ref", REFERENCE, brightness=1.0, seed=1,
                      poses=[float(p) for p in REFERENCE])
    qry = write_drive(tmp_path / "qry", QUERY, brightness=0.7, seed=2,
                      poses=[float(p) for p in QUERY])
    metrics = run(tmp_path, "--d-thresh", "1", "--poses-tolerance", "0.5",
                  reference=ref, query=qry)
    assert calls == [(len(REFERENCE), len(QUERY))]
    assert (metrics["n_reference"], metrics["n_query"]) == (len(REFERENCE), len(QUERY))
    assert metrics["params"]["ground_truth"] == "poses"
    # every query place is in the reference; the first DS queries are never scored
    assert metrics["n_scored"] == metrics["n_positive"] == len(QUERY) - DS
    assert metrics["recall_at_1"] > 0.9


def test_the_reversed_direction_has_queries_absent_from_the_reference(tmp_path, calls):
    """Query 60 frames against a 40-frame reference: 20 query places have no true place."""
    long = write_drive(tmp_path / "long", REFERENCE, brightness=1.0, seed=1,
                       poses=[float(p) for p in REFERENCE])
    short = write_drive(tmp_path / "short", QUERY, brightness=0.7, seed=2,
                        poses=[float(p) for p in QUERY])
    metrics = run(tmp_path, "--d-thresh", "1", "--poses-tolerance", "0.5",
                  reference=short, query=long)
    assert calls == [(len(QUERY), len(REFERENCE))]
    scored_queries = REFERENCE[DS:]
    assert metrics["n_positive"] == int(np.sum((scored_queries >= 15) & (scored_queries < 55)))


def test_without_poses_query_frame_i_is_reference_frame_i_even_when_lengths_differ(tmp_path,
                                                                                   calls):
    ref = write_drive(tmp_path / "ref", REFERENCE, brightness=1.0, seed=1)
    qry = write_drive(tmp_path / "qry", REFERENCE[:40], brightness=0.7, seed=2)
    metrics = run(tmp_path, "--d-thresh", "1", reference=ref, query=qry)
    assert calls == [(60, 40)]
    assert metrics["params"]["ground_truth"] == "frame index"
    assert metrics["n_positive"] == 40 - DS and metrics["recall_at_1"] > 0.9


@pytest.mark.parametrize("d_thresh, good", [(3, True), (2, False)])
def test_d_thresh_counts_a_match_exactly_that_far_as_correct(tmp_path, d_thresh, good):
    """Query images show the place 3 further on than their poses: every match is 3 off."""
    ref = write_drive(tmp_path / "ref", REFERENCE, brightness=1.0, seed=1,
                      poses=[float(p) for p in REFERENCE])
    qry = write_drive(tmp_path / "qry", QUERY + 3, brightness=0.7, seed=2,
                      poses=[float(p) for p in QUERY])
    metrics = run(tmp_path, "--d-thresh", str(d_thresh), "--poses-tolerance", "0.5",
                  reference=ref, query=qry)
    assert metrics["params"]["d_thresh"] == d_thresh
    if good:
        assert metrics["recall_at_1"] > 0.9
    else:
        assert metrics["recall_at_1"] < 0.1


def test_poses_tolerance_decides_which_queries_have_a_true_place(tmp_path):
    """Query poses 0.7 m beside the route: within a 1 m radius every place is present, within
    0.5 m none is (and the command refuses to score recall on no positives)."""
    ref = write_drive(tmp_path / "ref", REFERENCE, brightness=1.0, seed=1,
                      poses=[float(p) for p in REFERENCE])
    qry = write_drive(tmp_path / "qry", QUERY, brightness=0.7, seed=2,
                      poses=[float(p) for p in QUERY], y=0.7)
    metrics = run(tmp_path, "--d-thresh", "1", "--poses-tolerance", "1.0",
                  reference=ref, query=qry)
    assert metrics["n_positive"] == len(QUERY) - DS
    assert main(["match", str(ref), str(qry), "--out", str(tmp_path / "tight"),
                 "--poses-tolerance", "0.5"]) != 0
