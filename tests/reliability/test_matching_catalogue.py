"""Catalogue: features and matching (docs/reliability.md, "Features and matching").

Non-finite codes and out-of-range parameters are rejected with a `ValueError` naming the input
or parameter; degenerate but finite inputs (constant codes, black tunnel stretches, a query
longer than the reference) never produce NaN in a scored result.
"""

from __future__ import annotations

import numpy as np
import pytest

from cmal_lcd.evaluation import (
    correct_matches,
    ground_truth_from_correspondence,
    ground_truth_from_poses,
    loop_closure_metrics,
)
from cmal_lcd.matching import (
    SeqSLAMParams,
    difference_matrix,
    match_sequences,
    matching_defaults,
    sad_thumbnails,
    sequence_search,
)

SMALL = SeqSLAMParams.defaults(ds=4, r_window=4)


def codes(n: int, seed: int = 0, dim: int = 8) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, dim)).astype(np.float32)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("side", ["reference", "query"])
def test_non_finite_codes_are_rejected_naming_the_side(bad, side):
    reference, query = codes(20, 0), codes(20, 1)
    (reference if side == "reference" else query)[7, 3] = bad
    with pytest.raises(ValueError, match=f"{side} contains NaN or infinite"):
        match_sequences(reference, query, metric="sqeuclidean", params=SMALL)
    with pytest.raises(ValueError, match=f"{side} contains NaN or infinite"):
        difference_matrix(reference, query, metric="sad")


def test_constant_codes_leave_every_query_unscored_without_nan_matches():
    same = np.ones((20, 8), np.float32)
    result = match_sequences(same, same, metric="sqeuclidean", params=SMALL)
    assert (result.match == -1).all()
    assert np.isnan(result.ratio).all()  # NaN only where not scored, as documented


def test_metrics_of_constant_codes_raise_a_message_naming_match():
    same = np.ones((20, 8), np.float32)
    result = match_sequences(same, same, metric="sqeuclidean", params=SMALL)
    truth = ground_truth_from_correspondence(20, 20)
    with pytest.raises(ValueError, match="match: no scored query"):
        loop_closure_metrics(result.match, result.confidence_score, truth, d_thresh=2)


def test_constant_codes_without_enhancement_are_scored_as_ties():
    same = np.ones((20, 8), np.float32)
    params = SeqSLAMParams.defaults(ds=4, r_window=4, enhance=False)
    result = match_sequences(same, same, metric="sqeuclidean", params=params)
    scored = result.match >= 0
    assert scored.sum() == 20 - params.ds
    assert np.isfinite(result.ratio[scored]).all() and np.isfinite(result.score[scored]).all()


def black_tunnel_drive(n: int, *, seed: int, tunnel: slice) -> np.ndarray:
    places = np.random.default_rng(0).integers(0, 256, (n, 24, 32, 3), np.uint8)
    noise = np.random.default_rng(seed).integers(-6, 7, places.shape)
    images = np.clip(places.astype(np.int16) + noise, 0, 255).astype(np.uint8)
    images[tunnel] = 0
    return images


@pytest.mark.parametrize("metric_features", ["sad", "codes"])
def test_all_black_tunnel_stretch_gives_finite_results_and_matches_outside_it(metric_features):
    tunnel = slice(12, 22)
    reference = black_tunnel_drive(40, seed=1, tunnel=tunnel)
    query = black_tunnel_drive(40, seed=2, tunnel=tunnel)
    if metric_features == "sad":
        ref_f = sad_thumbnails(reference, width=16, height=8, patch=4)
        qry_f = sad_thumbnails(query, width=16, height=8, patch=4)
        metric = "sad"
    else:  # a learned code of a black frame: the same constant vector every time
        ref_f = reference.reshape(40, -1)[:, ::97].astype(np.float32)
        qry_f = query.reshape(40, -1)[:, ::97].astype(np.float32)
        metric = "sqeuclidean"
    result = match_sequences(ref_f, qry_f, metric=metric, params=SMALL)
    scored = result.match >= 0
    assert np.isfinite(result.ratio[scored]).all() and np.isfinite(result.score[scored]).all()
    truth = ground_truth_from_correspondence(40, 40)
    metrics = loop_closure_metrics(result.match, result.confidence_score, truth, d_thresh=2)
    for key in ("auc_pr", "recall_at_100p", "recall_at_1"):
        assert 0.0 <= metrics[key] <= 1.0
    after = np.arange(40) >= tunnel.stop + SMALL.ds
    assert correct_matches(result.match, truth, d_thresh=2)[after].all()


def test_a_query_longer_than_the_reference_is_matched():
    reference, query = codes(15, 0), codes(45, 1)
    result = match_sequences(reference, query, metric="sqeuclidean", params=SMALL)
    assert result.match.shape == (45,)
    assert (result.match[SMALL.ds:] >= 0).all() and result.match.max() < 15


@pytest.mark.parametrize("kwargs, name", [
    ({"ds": 0}, "ds"),
    ({"ds": -3}, "ds"),
    ({"ds": 2.5}, "ds"),
    ({"v_min": 1.2, "v_max": 1.1}, "v_min"),
    ({"v_min": 0.0}, "v_min"),
    ({"v_min": float("nan")}, "v_min"),
    ({"v_step": 0.0}, "v_step"),
    ({"v_step": -0.1}, "v_step"),
    ({"r_window": -1}, "r_window"),
    ({"r_window": 1}, "r_window"),
    ({"score": "max"}, "score"),
    ({"enhance": "yes"}, "enhance"),
])
def test_out_of_range_seqslam_parameter_is_named(kwargs, name):
    with pytest.raises(ValueError, match=rf"^{name}\b|\b{name}="):
        SeqSLAMParams.defaults(**kwargs)
    with pytest.raises(ValueError, match=name):
        SeqSLAMParams.from_config({**matching_defaults(), **kwargs})


def test_out_of_range_search_arguments_are_named():
    D = np.random.default_rng(0).random((20, 20)).astype(np.float32)
    with pytest.raises(ValueError, match="ds"):
        sequence_search(D, ds=0, v_min=0.8, v_max=1.1, v_step=0.1, r_window=4)
    with pytest.raises(ValueError, match="v_min"):
        sequence_search(D, ds=4, v_min=1.5, v_max=1.1, v_step=0.1, r_window=4)


@pytest.mark.parametrize("d_thresh", [-1, float("nan")])
def test_negative_or_nan_frame_tolerance_is_named(d_thresh):
    match = truth = np.arange(5)
    with pytest.raises(ValueError, match="d_thresh"):
        loop_closure_metrics(match, np.zeros(5), truth, d_thresh=d_thresh)


@pytest.mark.parametrize("max_distance", [-0.5, float("nan"), float("inf")])
def test_negative_or_non_finite_pose_tolerance_is_named(max_distance):
    xy = np.zeros((3, 2))
    with pytest.raises(ValueError, match="max_distance"):
        ground_truth_from_poses(xy, xy, max_distance=max_distance)


def test_unknown_metric_and_mismatched_feature_sizes_are_named():
    with pytest.raises(ValueError, match="metric"):
        difference_matrix(codes(4), codes(4), metric="cosine")
    with pytest.raises(ValueError, match=r"feature|\(4, 8\)|\(4, 6\)|F"):
        difference_matrix(codes(4, dim=8), codes(4, dim=6), metric="sqeuclidean")


def test_match_command_rejects_a_bad_parameter_without_a_traceback(tmp_path, capsys):
    from cmal_lcd.commands import main

    code = main(["match", str(tmp_path), str(tmp_path), "--ds", "0", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "--ds: must be >= 1, got 0" in err and "Traceback" not in err


# ------------------------------------------------------- codes on disk between the stages

def write_features(folder, codes: np.ndarray) -> None:
    import json

    folder.mkdir(parents=True, exist_ok=True)
    np.save(folder / "codes.npy", codes)
    (folder / "info.json").write_text(json.dumps(
        {"method": "cmal", "label": "CMAL", "metric": "sqeuclidean", "dim": codes.shape[1],
         "bytes_per_frame": codes.shape[1] * 4}))


def test_codes_file_with_nan_rows_is_refused_naming_the_file_and_row(tmp_path):
    from cmal_lcd.data.codes import load_features

    bad = codes(10)
    bad[6, 1] = np.nan
    write_features(tmp_path / "cmal", bad)
    with pytest.raises(ValueError, match=r"cmal/codes\.npy: row 6 holds NaN or inf"):
        load_features(tmp_path / "cmal", expected_rows=10)


def test_truncated_codes_file_is_refused_naming_the_file(tmp_path):
    from cmal_lcd.data.codes import load_features

    write_features(tmp_path / "cmal", codes(10))
    path = tmp_path / "cmal" / "codes.npy"
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(ValueError, match=r"cmal/codes\.npy: not a readable \.npy"):
        load_features(tmp_path / "cmal", expected_rows=10)


def test_extractor_output_with_nan_is_refused_naming_the_method():
    from cmal_lcd.features import check_finite_codes

    bad = codes(4)
    bad[2, 0] = np.inf
    with pytest.raises(ValueError, match="bigan"):
        check_finite_codes(bad, method="bigan")
