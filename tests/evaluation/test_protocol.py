"""Matching protocols: candidates, selection on validation scores, round trip."""

import pytest

from cmal_lcd.evaluation.protocol import (MatchingProtocol, candidate_protocols,
                                          paper_protocol, select_protocol)
from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.matching.normalise import CodeNormalisation


def test_candidates_cover_the_grid_and_include_the_paper_protocol():
    params = SeqSLAMParams.defaults()
    candidates = candidate_protocols(params, centres=["none", "reference"], l2=[False, True],
                                     enhance_windows=[10, 20])
    assert len(candidates) == 2 * 2 * 3
    assert paper_protocol(params) in candidates
    off = [c for c in candidates if not c.enhance]
    assert {c.r_window for c in off} == {params.r_window}


def test_the_paper_protocol_is_added_when_the_grid_lacks_it():
    candidates = candidate_protocols(SeqSLAMParams.defaults(), centres=["reference"], l2=[True],
                                     enhance_windows=[20])
    assert candidates[0] == paper_protocol(SeqSLAMParams.defaults())


def test_selection_maximises_the_criterion_and_breaks_ties_by_auc_pr():
    a = MatchingProtocol(CodeNormalisation("none"), enhance=True, r_window=10)
    b = MatchingProtocol(CodeNormalisation("reference", True), enhance=False, r_window=10)
    c = MatchingProtocol(CodeNormalisation("condition", True), enhance=True, r_window=20)
    scores = {a: (0.5, 0.9), b: (0.7, 0.8), c: (0.7, 0.85)}

    def evaluate(p):
        r, auc = scores[p]
        return [{"recall_at_100p": r, "auc_pr": auc}, {"recall_at_100p": r, "auc_pr": auc}]

    best, table = select_protocol([a, b, c], evaluate, criterion="recall_at_100p")
    assert best == c
    assert [row["mean_recall_at_100p"] for row in table] == [0.5, 0.7, 0.7]
    best, _ = select_protocol([a, b, c], evaluate, criterion="auc_pr")
    assert best == a


def test_a_protocol_survives_its_json_form():
    p = MatchingProtocol(CodeNormalisation("condition", True), enhance=True, r_window=40)
    assert MatchingProtocol.from_dict(p.as_dict()) == p
    assert p.seqslam(SeqSLAMParams.defaults()).r_window == 40


def test_unknown_criterion_and_centre_are_named():
    with pytest.raises(ValueError, match="criterion"):
        select_protocol([paper_protocol(SeqSLAMParams.defaults())], lambda p: [], criterion="speed")
    with pytest.raises(ValueError, match="matching.protocol.centre"):
        candidate_protocols(SeqSLAMParams.defaults(), centres=["query"], l2=[False], enhance_windows=[])
