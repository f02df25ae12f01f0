"""``cmal-lcd match`` applies a method's matching protocol as the ``evaluate`` stage does.

A learned method's codes go through the protocol ``select_protocol`` chose on the validation
drives (``data/protocol/<method>.json``): code normalisation (centring, L2) and eq. 14 on or off,
applied by the same library function as the stage
(:func:`cmal_lcd.evaluation.loop_closure.evaluate_pair`). Centring statistics come from the
training codes of the pipeline's features folder, never from the query folder. SAD keeps the
paper's matching unless a protocol file is given.

The checkout here is a temporary folder laid out as the pipeline writes it (``models/``,
``data/protocol/cmal.json``, ``data/features/cmal/train_*.npy``); the learned extractor is a
stand-in (block means of the grey image) so that no model is trained.
"""

import json
import shutil

import numpy as np
import pytest

from cmal_lcd.workflows import folder_features as feature_folders
from cmal_lcd.commands import main
from cmal_lcd.evaluation import loop_closure
from cmal_lcd.evaluation.protocol import MatchingProtocol
from cmal_lcd.data.codes import load_centring_means
from test_cli import write_route

N_CONDITIONS = 3
CODE_DIM = 32  # 4 x 8 blocks of 8 x 8 pixels of a 32 x 64 frame
CONDITION_CENTRED = {"centre": "condition", "l2": True, "enhance": False, "r_window": 10}
REFERENCE_CENTRED = {"centre": "reference", "l2": True, "enhance": True, "r_window": 20}


def block_codes(images):
    """Stand-in learned codes: ``float32 (N, 32)``, 8 x 8 block means of the first channel."""
    grey = images[..., 0].astype(np.float32)
    n, h, w = grey.shape
    return grey.reshape(n, h // 8, 8, w // 8, 8).mean(axis=(2, 4)).reshape(n, -1)


@pytest.fixture
def stand_in_extractor(monkeypatch):
    def feature_function(name, *, model_dir, features_dir=None, quantise_sad=False,
                         config_overrides=()):
        return block_codes, "sqeuclidean", {"features": name, "label": f"stand-in {name}",
                                            "weights": "none"}

    monkeypatch.setattr(feature_folders, "feature_function", feature_function)


def write_checkout(root, *, method="cmal", selected=CONDITION_CENTRED, protocol=True):
    """``root/models``, ``root/data/features/<method>`` (training codes of 3 conditions) and,
    when ``protocol``, ``root/data/protocol/<method>.json`` selecting ``selected``."""
    (root / "models").mkdir(parents=True)
    features = root / "data" / "features" / method
    features.mkdir(parents=True)
    rng = np.random.default_rng(7)
    labels = np.repeat(np.arange(N_CONDITIONS), 20)
    codes = rng.normal(size=(len(labels), CODE_DIM)) + 40.0 * labels[:, None]
    np.save(features / "train_codes.npy", codes.astype(np.float32))
    np.save(features / "train_labels.npy", labels.astype(np.int64))
    (features / "info.json").write_text(json.dumps({"method": method}))
    if protocol:
        path = root / "data" / "protocol" / f"{method}.json"
        path.parent.mkdir(parents=True)
        path.write_text(json.dumps({"method": method, "selected": selected,
                                    "paper": {"centre": "none", "l2": False, "enhance": True,
                                              "r_window": 10}}))
    return root


@pytest.fixture
def drives(tmp_path):
    return (write_route(tmp_path / "sunny", brightness=1.0, seed=1),
            write_route(tmp_path / "foggy", brightness=0.6, seed=2))


@pytest.fixture
def evaluated(monkeypatch):
    """Every call of ``evaluate_pair``: its ``protocol``, ``train_means`` and ``params``."""
    seen = []
    real = loop_closure.evaluate_pair

    def recording(reference, query, truth, **kw):
        seen.append(kw)
        return real(reference, query, truth, **kw)

    monkeypatch.setattr(loop_closure, "evaluate_pair", recording)
    return seen


@pytest.fixture
def normalised(monkeypatch):
    """The normalised reference and query codes of every matching (the stage's function)."""
    seen = []
    real = loop_closure.normalise_pair

    def recording(reference, query, normalisation, *, train_means=None):
        out = real(reference, query, normalisation, train_means=train_means)
        seen.append(tuple(np.array(a, dtype=np.float64) for a in out))
        return out

    monkeypatch.setattr(loop_closure, "normalise_pair", recording)
    return seen


def match(tmp_path, reference, query, *args, out="out"):
    code = main(["match", str(reference), str(query), "--out", str(tmp_path / out), *args])
    assert code == 0
    return json.loads((tmp_path / out / "metrics.json").read_text())


# ------------------------------------------------------------------------- learned features


def test_a_learned_method_uses_the_protocol_the_pipeline_wrote_beside_model_dir(
        tmp_path, drives, stand_in_extractor, evaluated, capsys):
    checkout = write_checkout(tmp_path / "checkout")
    metrics = match(tmp_path, *drives, "--features", "cmal", "--model-dir",
                    str(checkout / "models"))
    expected = MatchingProtocol.from_dict(CONDITION_CENTRED)
    (call,) = evaluated
    assert call["protocol"] == expected
    features_dir = checkout / "data" / "features" / "cmal"
    np.testing.assert_array_equal(call["train_means"],
                                  load_centring_means(features_dir, N_CONDITIONS))
    chosen = metrics["params"]["protocol"]
    assert chosen["label"] == expected.label == "centre(condition)+L2, no enhancement"
    assert chosen["file"] == str(checkout / "data" / "protocol" / "cmal.json")
    assert chosen["train_features"] == str(features_dir) and chosen["warning"] is None
    assert metrics["params"]["enhance"] is False  # the protocol's, recorded as used
    assert f"protocol: {expected.label} ({checkout / 'data' / 'protocol' / 'cmal.json'}" in \
        capsys.readouterr().out


def test_float32_codes_switch_the_codes_metric_and_record_it(
        tmp_path, drives, stand_in_extractor, evaluated):
    checkout = write_checkout(tmp_path / "checkout")
    args = ("--features", "cmal", "--model-dir", str(checkout / "models"), "--no-figures")
    exact = match(tmp_path, *drives, *args, out="exact")
    fast = match(tmp_path, *drives, *args, "--float32-codes", out="fast")
    assert [call["metric"] for call in evaluated] == ["sqeuclidean", "sqeuclidean_f32"]
    assert (exact["params"]["metric"], fast["params"]["metric"]) == \
        ("sqeuclidean", "sqeuclidean_f32")
    for key in ("auc_pr", "recall_at_100p"):
        assert fast[key] == pytest.approx(exact[key], abs=0.01)


def test_float32_codes_leave_sad_as_it_is(tmp_path, drives):
    metrics = match(tmp_path, *drives, "--float32-codes", "--no-figures")
    assert metrics["params"]["metric"] == "sad"


@pytest.mark.parametrize("method, selected, dim, label", [
    ("dnn", "block4", 40 * 16, "DNN (EfficientNet-Lite0, block 4, 4x4, 64 px)"),
    ("dnn_head", "head", 1280, "DNN (EfficientNet-Lite0, pooled head, 64 px)"),
])
def test_the_dnn_uses_the_layer_and_input_side_its_training_codes_were_made_with(
        tmp_path, drives, monkeypatch, method, selected, dim, label):
    """The features stage chose (for ``dnn``) block 4 at 64 px, or (for ``dnn_head``) the head
    at 64 px, on validation (``info.json``); the protocol's centring means are codes of that
    choice, so match must encode with it, not with the configured layer at 224 px (whose codes
    would not even fit the means, or would silently differ)."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "no_vgg16"))
    checkout = write_checkout(tmp_path / "checkout", method=method)
    features = checkout / "data" / "features" / method
    labels = np.load(features / "train_labels.npy")
    np.save(features / "train_codes.npy",
            np.random.default_rng(3).normal(size=(len(labels), dim)).astype(np.float32))
    (features / "info.json").write_text(json.dumps({"method": method, "layer_selection": {
        "selected": selected, "image_size": 64, "candidates": []}}))
    metrics = match(tmp_path, *drives, "--features", method, "--model-dir",
                    str(checkout / "models"), "--no-figures")
    assert metrics["params"]["label"] == label


def test_the_dnn_choice_is_read_from_info_json_and_absent_choices_change_nothing(tmp_path):
    from cmal_lcd.features.dnn import layer_overrides

    def overrides(folder):
        return layer_overrides(feature_folders.recorded_choice(folder))

    folder = tmp_path / "dnn"
    assert feature_folders.recorded_choice(None) is None
    assert overrides(folder) == {}  # no such folder
    folder.mkdir()
    (folder / "info.json").write_text(json.dumps({"method": "dnn", "layer_selection": None}))
    assert feature_folders.recorded_choice(folder) is None
    (folder / "info.json").write_text(json.dumps({"layer_selection": {"selected": "block7"}}))
    assert overrides(folder) == {"efficientnet_layer": "block7"}
    (folder / "info.json").write_text(json.dumps({"layer_selection": {"selected": "block4",
                                                                      "image_size": 96}}))
    assert overrides(folder) == {"efficientnet_layer": "block4", "image_size": 96}


def test_an_explicit_protocol_file_wins_and_its_centring_means_come_from_beside_it(
        tmp_path, drives, stand_in_extractor, evaluated):
    beside_models = write_checkout(tmp_path / "a", selected=REFERENCE_CENTRED)
    other = write_checkout(tmp_path / "b", selected=CONDITION_CENTRED)
    metrics = match(tmp_path, *drives, "--features", "cmal",
                    "--model-dir", str(beside_models / "models"),
                    "--protocol", str(other / "data" / "protocol" / "cmal.json"))
    assert evaluated[0]["protocol"] == MatchingProtocol.from_dict(CONDITION_CENTRED)
    assert metrics["params"]["protocol"]["train_features"] == str(
        other / "data" / "features" / "cmal")


def test_without_a_protocol_file_a_learned_method_falls_back_to_raw_codes_and_says_so(
        tmp_path, drives, stand_in_extractor, evaluated, capsys):
    checkout = write_checkout(tmp_path / "checkout", protocol=False)
    metrics = match(tmp_path, *drives, "--features", "cmal", "--model-dir",
                    str(checkout / "models"))
    chosen = metrics["params"]["protocol"]
    assert (chosen["centre"], chosen["l2"], chosen["enhance"]) == ("none", False, True)
    assert chosen["source"].startswith("fallback: no protocol file")
    assert str(checkout / "data" / "protocol" / "cmal.json") in chosen["warning"]
    assert evaluated[0]["train_means"] is None
    captured = capsys.readouterr()
    assert "cmal-lcd match: warning: no protocol chosen for cmal" in captured.err
    assert "protocol: raw, eq. 14 (r_window 10) (fallback" in captured.out


def test_protocol_raw_uses_the_enhancement_options_without_a_warning(
        tmp_path, drives, stand_in_extractor, evaluated, capsys):
    checkout = write_checkout(tmp_path / "checkout")
    metrics = match(tmp_path, *drives, "--features", "cmal", "--model-dir",
                    str(checkout / "models"), "--protocol", "raw", "--no-enhance")
    assert evaluated[0]["protocol"].label == "raw, no enhancement"
    assert metrics["params"]["protocol"]["source"] == "--protocol raw"
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("selected", [CONDITION_CENTRED, REFERENCE_CENTRED],
                         ids=["centre-condition", "centre-reference"])
def test_centring_statistics_never_come_from_the_query_folder(
        tmp_path, drives, stand_in_extractor, evaluated, normalised, selected):
    """Permuting or truncating the query folder leaves the centring means and the normalised
    reference unchanged and permutes or truncates the normalised queries: each query is
    normalised from itself, the reference drive and the training statistics only."""
    reference, query = drives
    checkout = write_checkout(tmp_path / "checkout", selected=selected)
    files = sorted(query.glob("*.png"))
    order = np.random.default_rng(3).permutation(len(files))
    permuted = tmp_path / "permuted"
    permuted.mkdir()
    for new, old in enumerate(order):  # sorted names of `permuted` follow `order`
        shutil.copy(files[old], permuted / f"p-{new:04d}.png")
    truncated = tmp_path / "truncated"
    truncated.mkdir()
    for file in files[:25]:
        shutil.copy(file, truncated / file.name)

    options = ["--features", "cmal", "--model-dir", str(checkout / "models"), "--d-thresh", "40"]
    for out, folder in (("a", query), ("b", permuted), ("c", truncated)):
        match(tmp_path, reference, folder, *options, out=out)

    (ref_a, query_a), (ref_b, query_b), (ref_c, query_c) = normalised
    means = [call["train_means"] for call in evaluated]
    if selected["centre"] == "condition":
        np.testing.assert_array_equal(means[0], means[1])
        np.testing.assert_array_equal(means[0], means[2])
    else:
        assert means == [None, None, None]
    np.testing.assert_array_equal(ref_a, ref_b)
    np.testing.assert_array_equal(ref_a, ref_c)
    np.testing.assert_allclose(query_b, query_a[order], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(query_c, query_a[:25], rtol=1e-6, atol=1e-7)


# ------------------------------------------------------------------------- SAD


def test_sad_keeps_the_papers_matching_by_default(tmp_path, drives, evaluated):
    """No protocol look-up for SAD: raw thumbnails, eq. 14 as the options say."""
    metrics = match(tmp_path, *drives)
    assert evaluated[0]["protocol"].label == "raw, eq. 14 (r_window 10)"
    assert metrics["params"]["protocol"]["source"].startswith("sad default")


def test_sad_honours_a_given_protocol_file(tmp_path, drives, evaluated):
    checkout = write_checkout(tmp_path / "checkout", method="sad", selected=REFERENCE_CENTRED)
    metrics = match(tmp_path, *drives, "--protocol",
                    str(checkout / "data" / "protocol" / "sad.json"))
    assert evaluated[0]["protocol"] == MatchingProtocol.from_dict(REFERENCE_CENTRED)
    assert (metrics["params"]["enhance"], metrics["params"]["r_window"]) == (True, 20)
    assert metrics["params"]["protocol"]["train_features"] is None  # no condition centring


# ------------------------------------------------------------------------- refusals


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and "Traceback" not in err, err
    return err


def test_a_protocol_file_chosen_for_another_method_is_refused(tmp_path, drives, capsys):
    checkout = write_checkout(tmp_path / "checkout")
    path = checkout / "data" / "protocol" / "cmal.json"
    assert main(["match", *map(str, drives), "--protocol", str(path),
                 "--out", str(tmp_path / "out")]) == 2
    err = one_line_error(capsys)
    assert f"--protocol {path}: chosen for 'cmal', not for --features 'sad'" in err
    assert not (tmp_path / "out").exists()


def test_a_missing_or_broken_protocol_file_is_one_line_naming_it(tmp_path, drives, capsys):
    missing = tmp_path / "nothing.json"
    assert main(["match", *map(str, drives), "--protocol", str(missing),
                 "--out", str(tmp_path / "out")]) == 2
    assert f"--protocol {missing}: missing" in one_line_error(capsys)
    broken = tmp_path / "broken.json"
    broken.write_text('{"selected": {"centre": "sideways"}}')
    assert main(["match", *map(str, drives), "--protocol", str(broken),
                 "--out", str(tmp_path / "out")]) == 2
    assert f"--protocol {broken}: not a protocol record" in one_line_error(capsys)


def test_enhancement_options_that_contradict_a_protocol_file_are_refused(
        tmp_path, drives, stand_in_extractor, capsys):
    checkout = write_checkout(tmp_path / "checkout")
    assert main(["match", *map(str, drives), "--features", "cmal", "--model-dir",
                 str(checkout / "models"), "--no-enhance", "--out", str(tmp_path / "out")]) == 2
    err = one_line_error(capsys)
    assert err.startswith("cmal-lcd match: error: --no-enhance/--r-window:")
    assert "--protocol raw" in err


def test_missing_training_codes_for_condition_centring_name_the_file_and_the_option(
        tmp_path, drives, stand_in_extractor, capsys):
    checkout = write_checkout(tmp_path / "checkout")
    codes = checkout / "data" / "features" / "cmal" / "train_codes.npy"
    codes.unlink()
    assert main(["match", *map(str, drives), "--features", "cmal", "--model-dir",
                 str(checkout / "models"), "--out", str(tmp_path / "out")]) == 2
    err = one_line_error(capsys)
    assert "--train-features" in err and str(codes) in err
    assert not (tmp_path / "out").exists()

