"""The paper's published numbers, kept as data."""

import math

import pytest

from cmal_lcd.reports import paper


def test_table2_has_two_routes_three_pairs_four_methods():
    table = paper.PAPER_TABLE2_RECALL_AT_100P
    assert list(table) == ["route1", "route2"]
    for pairs in table.values():
        assert list(pairs) == ["foggy-rainy", "foggy-sunny", "rainy-sunny"]
        for methods in pairs.values():
            assert set(methods) == set(paper.PAPER_METHOD_LABELS)
            assert all(0.0 <= v <= 1.0 for v in methods.values())


@pytest.mark.parametrize("route, pair, method, percent", [
    ("route1", "foggy-rainy", "sad", 34.8),    # first cell of Table II
    ("route1", "foggy-sunny", "cmal", 48.3),
    ("route2", "foggy-rainy", "cmal", 31.9),
    ("route2", "rainy-sunny", "sad", 73.1),   # last SAD cell
    ("route1", "foggy-rainy", "dnn", 0.1),
    ("route2", "rainy-sunny", "bigan", 5.4),  # last cell
])
def test_table2_cells_as_printed_in_the_paper(route, pair, method, percent):
    assert paper.paper_recall_at_100p(route, pair, method) == pytest.approx(percent / 100)


@pytest.mark.parametrize("route", ["Route 1", "route_1", "ROUTE-1", "route1"])
def test_route_spellings_are_normalised(route):
    assert paper.normalise_route(route) == "route1"
    assert paper.paper_recall_at_100p(route, "foggy-rainy", "sad") == pytest.approx(0.348)


@pytest.mark.parametrize("route, pair, method", [
    ("nordland", "summer-winter", "cmal"),       # a dataset the paper did not use
    ("route1", "sunny-foggy", "cmal"),           # pair order matters: reference first
    ("route1", "foggy-rainy", "cmal_untrained"),  # our control, not in the paper
])
def test_no_paper_value_is_nan(route, pair, method):
    assert math.isnan(paper.paper_recall_at_100p(route, pair, method))


def test_inference_ms_range_from_table3():
    assert paper.paper_inference_ms_range("sad") == (3.2, 3.4)
    assert paper.paper_inference_ms_range("cmal") == (3.4, 3.6)
    assert all(math.isnan(v) for v in paper.paper_inference_ms_range("dnn"))


def test_cmal_code_is_4kb():
    assert paper.PAPER_BYTES_PER_FRAME["cmal"] == 4096
