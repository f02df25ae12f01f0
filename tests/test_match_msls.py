"""``cmal-lcd match`` on Mapillary SLS sides: seq_info.csv order, sequences apart, UTM truth.

The city is synthetic (MSLS cannot be downloaded here) but laid out exactly as MSLS ships it
(``mapillary_sls`` README, ``datasets/msls.py``): ``images/<key>.jpg`` with random keys,
``seq_info.csv`` (index, key, sequence_key, frame_number) and ``postprocessed.csv`` (index,
key, ..., easting, northing, ...), both read with ``index_col=0``.
"""

import json
import string

import cv2
import numpy as np
import pandas as pd
import pytest

from cmal_lcd.commands import main
from cmal_lcd.data.frames import FrameReadError, list_frame_files
from cmal_lcd.data.msls import read_msls_side
from cmal_lcd.matching import SeqSLAMParams, match_sequences, sad_thumbnails

STEP_M = 3.0  # metres between frames along the road
#: Each drive: (sequence_key, first place, number of frames). The database's drives overlap.
DATABASE = [("dbA", 0, 24), ("dbB", 20, 30), ("dbC", 48, 30)]
QUERY = [("qX", 5, 16), ("qY", 40, 22)]


def texture(seed: int = 0) -> np.ndarray:
    """A long road panorama: place ``p`` is columns ``4p .. 4p + 32``."""
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.random((24, 4 * 100 + 32)), (3, 3), 0)


def write_side(folder, drives, *, brightness: float, seed: int):
    """An MSLS side whose keys are random strings (so their name order is not travel order)."""
    rng = np.random.default_rng(seed)
    road = texture()
    (folder / "images").mkdir(parents=True)
    rows, places = [], []
    for sequence_key, first, n in drives:
        for frame in range(n):
            place = first + frame
            key = "".join(rng.choice(list(string.ascii_letters), 22))
            crop = np.clip(brightness * road[:, 4 * place:4 * place + 32]
                           + 0.03 * rng.normal(size=(24, 32)), 0, 1)
            assert cv2.imwrite(str(folder / "images" / f"{key}.jpg"),
                               (255 * crop).astype(np.uint8))
            rows.append({"key": key, "sequence_key": sequence_key, "frame_number": frame})
            places.append(place)
    seq_info = pd.DataFrame(rows)
    seq_info.to_csv(folder / "seq_info.csv")
    positions = pd.DataFrame({"key": seq_info["key"], "lon": 0.0, "lat": 0.0,
                              "ca": 90.0, "captured_at": 0,
                              "easting": 500000.0 + STEP_M * np.array(places),
                              "northing": 4100000.0, "night": False,
                              "view_direction": "Forward"})
    positions.to_csv(folder / "postprocessed.csv")
    return np.array(places)


@pytest.fixture
def city(tmp_path):
    database = tmp_path / "city" / "database"
    query = tmp_path / "city" / "query"
    db_places = write_side(database, DATABASE, brightness=1.0, seed=1)
    q_places = write_side(query, QUERY, brightness=0.7, seed=2)
    return database, query, db_places, q_places


def run_match(tmp_path, *args):
    out = tmp_path / "out"
    return main(["match", *map(str, args), "--out", str(out), "--no-figures"]), out


def labels(drives):
    return np.repeat(np.arange(len(drives)), [n for _, _, n in drives])


def test_match_on_an_msls_city_follows_seq_info_and_keeps_sequences_apart(tmp_path, city,
                                                                         capsys):
    database, query, db_places, q_places = city
    code, out = run_match(tmp_path, database, query, "--ground-truth", "msls", "--ds", "6")
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    truth = metrics["ground_truth"]
    assert truth["source"].startswith("Mapillary SLS postprocessed.csv easting/northing")
    assert truth["tolerance"].startswith("25 m (easting/northing")
    order = "Mapillary SLS seq_info.csv row order"
    assert truth["frame_order"] == f"reference: {order} (3 sequences); query: {order} " \
                                   f"(2 sequences)"
    # independent ground truth: pairs within 25 m
    distance = STEP_M * np.abs(q_places[:, None] - db_places[None, :])
    assert truth["n_right_pairs"] == int(np.sum(distance <= 25.0))
    # the same numbers as the library run on the frames in seq_info.csv order
    images = [np.stack([cv2.imread(str(f))[:, :, ::-1] for f in list_frame_files(side)])
              for side in (database, query)]
    expected = match_sequences(sad_thumbnails(images[0]), sad_thumbnails(images[1]),
                               metric="sad", params=SeqSLAMParams.defaults(ds=6),
                               reference_sequences=labels(DATABASE),
                               query_sequences=labels(QUERY))
    matches = pd.read_csv(out / "matches.csv")
    np.testing.assert_array_equal(matches["match"].fillna(-1).astype(int), expected.match)
    assert metrics["n_scored"] == sum(n - 6 for _, _, n in QUERY) == expected.n_scored
    # every sequence match ends a trajectory inside one database drive, and is right here
    start = np.repeat(np.cumsum([0] + [n for _, _, n in DATABASE])[:-1],
                      [n for _, _, n in DATABASE])
    scored = expected.match >= 0
    assert (expected.match[scored] - start[expected.match[scored]] >= 6 * 0.8 - 1).all()
    assert metrics["recall_at_1"] > 0.9
    # the frames are named by their keys, in seq_info.csv order
    keys = pd.read_csv(query / "seq_info.csv", index_col=0)["key"]
    assert list(matches["query_frame"]) == [f"{k}.jpg" for k in keys]


def test_two_msls_sides_take_their_positions_by_default(tmp_path, city):
    database, query, *_ = city
    code, out = run_match(tmp_path, database, query, "--ds", "6",
                          "--positive-dist-threshold", "10")
    assert code == 0
    truth = json.loads((out / "metrics.json").read_text())["ground_truth"]
    assert truth["source"].startswith("Mapillary SLS") and truth["tolerance"].startswith("10 m")


def test_a_gap_in_frame_numbers_starts_a_new_sequence(tmp_path, city):
    database, *_ = city
    table = pd.read_csv(database / "seq_info.csv", index_col=0)
    table.loc[10:, "frame_number"] += table.index[10:].isin(range(10, 24)) * 5  # gap in dbA
    table.to_csv(database / "seq_info.csv")
    side = read_msls_side(database)
    assert side.n_sequences == 4
    np.testing.assert_array_equal(np.bincount(side.sequences), [10, 14, 30, 30])


@pytest.mark.parametrize("case, named", [
    ("missing image", "no such image, but"),
    ("keys differ", "postprocessed.csv: its keys differ from seq_info.csv's at row 3"),
    ("no easting", "postprocessed.csv: no column easting"),
    ("not msls", "plain is not a Mapillary SLS side"),
    ("no seq_info", "it has images/: a Mapillary SLS side also needs its seq_info.csv"),
])
def test_bad_msls_sides_are_refused_in_one_line(tmp_path, city, capsys, case, named):
    database, query, *_ = city
    if case == "missing image":
        next((database / "images").iterdir()).unlink()
    elif case == "keys differ":
        table = pd.read_csv(query / "postprocessed.csv", index_col=0)
        table.loc[3, "key"] = "elsewhere"
        table.to_csv(query / "postprocessed.csv")
    elif case == "no easting":
        table = pd.read_csv(query / "postprocessed.csv", index_col=0)
        table.drop(columns="easting").to_csv(query / "postprocessed.csv")
    elif case == "not msls":  # the query's images as a plain folder of frames
        (query / "images").rename(tmp_path / "plain")
        query = tmp_path / "plain"
    else:
        (database / "seq_info.csv").unlink()
    code, out = run_match(tmp_path, database, query, "--ground-truth", "msls", "--ds", "6")
    err = capsys.readouterr().err.strip()
    assert code == 2 and not out.exists()
    assert named in err and len(err.splitlines()) == 1, err


def test_a_side_listing_a_key_without_its_image_names_the_file(tmp_path, city):
    database, *_ = city
    victim = next((database / "images").iterdir())
    victim.unlink()
    with pytest.raises(FrameReadError, match=victim.name):
        list_frame_files(database)



# ------------------------------------------------------------------------------- pipeline


@pytest.fixture(scope="module")
def msls_run(tmp_path_factory):
    """``cmal-lcd-run`` with SAD on a synthetic MSLS city (``data.ground_truth: msls``), and
    ``cmal-lcd match`` on the same sides: both output folders."""
    import shutil
    import sys

    from cmal_lcd.config import REPO_ROOT
    from subprocess_helpers import run_checked

    root = tmp_path_factory.mktemp("msls")
    write_side(root / "city" / "database", DATABASE, brightness=1.0, seed=1)
    write_side(root / "city" / "query", QUERY, brightness=0.7, seed=2)
    shutil.copytree(REPO_ROOT / "conf", root / "conf")
    run_checked([sys.executable, "-m", "cmal_lcd.commands", "match", str(root / "city" / "database"),
                 str(root / "city" / "query"), "--ground-truth", "msls", "--no-figures",
                 "--out", str(root / "match")], root)
    run_checked([sys.executable, "-m", "cmal_lcd.app", "experiment=corridor", "methods=[sad]",
                 f"data.test.dir={root / 'city'}", "data.test.route=city",
                 "data.test.reference=database", "data.test.query=query",
                 "data.ground_truth=msls", "data.ground_truth_file=null",
                 "data.image_size=[24,32]", "hydra.run.dir=outputs/msls"], root, timeout=900)
    return root / "outputs" / "msls", root / "match"


def test_the_pipeline_matches_msls_drives_apart_as_match_does(msls_run):
    run, matched = msls_run
    meta = json.loads((run / "data" / "dataset" / "dataset.json").read_text())
    starts = {d["name"]: d.get("sequence_starts") for d in meta["drives"]}
    assert starts == {"city/database": [0, 24, 54], "city/query": [0, 16]}
    assert meta["ground_truth_source"]["source"].startswith("Mapillary SLS postprocessed.csv")
    expected = json.loads((matched / "metrics.json").read_text())
    scored = json.loads((run / "reports" / "metrics.json").read_text())["city"]
    (pair,) = scored.values()
    assert expected["n_scored"] == sum(n - 10 for _, _, n in QUERY)  # ds = 10 per drive
    for key in ("auc_pr", "recall_at_100p", "recall_at_1", "recall_at_5",
                "single_frame_recall_at_1"):
        assert pair["sad"][key] == pytest.approx(expected[key], abs=1e-12), key
