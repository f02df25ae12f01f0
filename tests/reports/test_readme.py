"""README findings are computed from the metrics, and the page lists every table and figure."""

import math

import pytest

from cmal_lcd.reports import paper, readme
from cmal_lcd.reports.readme import Entry, RunInfo, Tally

LABELS = {"sad": "SAD", "dnn": "DNN (EfficientNet-Lite0)", "bigan": "BiGAN", "cmal": "CMAL",
          "cmal_untrained": "CMAL (untrained control)"}


def nested_from(recall: dict, **extra) -> dict:
    """``{route: {pair: {method: r}}}`` -> nested metrics with recall, AUCs = recall."""
    return {route: {pair: {m: {"recall_at_100p": r, "auc_roc": r, "auc_pr": r, **extra}
                           for m, r in methods.items()}
                    for pair, methods in pairs.items()}
            for route, pairs in recall.items()}


def as_paper() -> dict:
    """Our metrics equal to the paper's Table II."""
    return nested_from(paper.PAPER_TABLE2_RECALL_AT_100P)


def reversed_paper() -> dict:
    """Our metrics in the reverse order of the paper's on every pair."""
    return nested_from({route: {pair: {m: 1.0 - r for m, r in methods.items()}
                                for pair, methods in pairs.items()}
                        for route, pairs in paper.PAPER_TABLE2_RECALL_AT_100P.items()})


def test_best_methods_per_pair_with_ties_and_missing_values():
    nested = nested_from({"r": {"a-b": {"sad": 0.5, "cmal": 0.5, "dnn": 0.1},
                                "c-d": {"sad": 0.2, "cmal": 0.3, "dnn": math.nan},
                                "e-f": {"sad": math.nan, "cmal": math.nan, "dnn": math.nan}}})
    best = readme.best_methods(nested, methods=["sad", "cmal", "dnn"], metric="recall_at_100p")
    assert best == {("r", "a-b"): ["sad", "cmal"], ("r", "c-d"): ["cmal"], ("r", "e-f"): []}


def test_head_to_head_counts_wins_losses_ties_and_skips_missing():
    nested = nested_from({"r": {"p1": {"cmal": 0.5, "sad": 0.4}, "p2": {"cmal": 0.1, "sad": 0.4},
                                "p3": {"cmal": 0.3, "sad": 0.3}, "p4": {"cmal": math.nan,
                                                                        "sad": 0.1}}})
    t = readme.head_to_head(nested, method="cmal", other="sad", metric="recall_at_100p")
    assert t == Tally(wins=1, losses=1, ties=1)
    assert t.n == 3


def test_paper_claims_are_tallied_on_the_papers_own_table():
    claims = readme.paper_claims(as_paper(), methods=["sad", "dnn", "bigan", "cmal"])
    by_claim = {(c["winner"], c["loser"]): c["paper"] for c in claims}
    # Table II: CMAL above DNN on all six pairs, above BiGAN on five, below SAD on four
    assert by_claim[("cmal", "dnn")] == Tally(6, 0, 0)
    assert by_claim[("cmal", "bigan")] == Tally(5, 1, 0)
    assert by_claim[("sad", "cmal")] == Tally(4, 2, 0)
    assert all(c["ours"] == c["paper"] for c in claims)


def test_claims_need_both_methods():
    claims = readme.paper_claims(as_paper(), methods=["sad", "cmal"])
    assert [(c["winner"], c["loser"]) for c in claims] == [("sad", "cmal")]


def test_ordering_agreement_identical_and_reversed():
    methods = ["sad", "dnn", "bigan", "cmal", "cmal_untrained"]
    same = readme.ordering_agreement(as_paper(), methods=methods)
    assert len(same) == 6
    assert all(r["same_best"] and r["kendall_tau"] == pytest.approx(1.0) for r in same)
    assert "cmal_untrained" not in same[0]["ours"]
    rev = readme.ordering_agreement(reversed_paper(), methods=methods)
    assert all(not r["same_best"] and r["kendall_tau"] == pytest.approx(-1.0) for r in rev)


def test_ordering_agreement_is_empty_for_other_datasets():
    nested = nested_from({"nordland": {"summer-winter": {"sad": 0.3, "cmal": 0.2}}})
    assert readme.ordering_agreement(nested, methods=["sad", "cmal"]) == []


def test_ablation_effect_means_and_counts():
    selected = nested_from({"r": {"p1": {"cmal": 0.2}, "p2": {"cmal": 0.4}}})
    paper_setting = nested_from({"r": {"p1": {"cmal": 0.6}, "p2": {"cmal": 0.4}}})
    effect = readme.ablation_effect(selected, paper_setting, methods=["cmal"])
    assert effect["cmal"] == {"selected": pytest.approx(0.3), "paper": pytest.approx(0.5),
                              "paper_better": 1, "n": 2}


@pytest.mark.parametrize("label, expected", [("DNN (VGG16)", True), ("DNN (VGG-16 fc6)", True),
                                             ("DNN (EfficientNet-Lite0)", False)])
def test_is_paper_dnn(label, expected):
    assert readme.is_paper_dnn(label) is expected


RUN = RunInfo(seed=7, git_commit="abc123", git_dirty=True, dataset_kind="synthetic_weather",
              matching={"ds": 10, "v_min": 0.8, "v_max": 1.1, "v_step": 0.1, "r_window": 10,
                        "enhance": True, "score": "ratio", "d_thresh": 20})


def render(selected, *, methods=("sad", "dnn", "bigan", "cmal", "cmal_untrained"),
           labels=LABELS, tables=(), figures=(), run=RUN):
    methods = list(methods)
    infos = {m: {"weights": f"w-{m}", "metric": "sqeuclidean"} for m in methods}
    return readme.render_readme(run=run, methods=methods, labels=labels, infos=infos,
                                selected=selected, paper_setting=selected, tables=tables,
                                figures=figures)


def with_control(nested, value=0.0):
    for pairs in nested.values():
        for methods in pairs.values():
            methods["cmal_untrained"] = {k: value for k in methods["cmal"]}
    return nested


def test_readme_states_run_config_and_pair_convention():
    text = render(with_control(as_paper()))
    assert "Seed: `7`; git commit: `abc123` (working tree differed" in text
    assert "`synthetic_weather`" in text
    assert "[config.yaml](config.yaml)" in text
    assert "`foggy-rainy` means the foggy drive is the reference" in text
    assert "ds=10, v=0.8..1.1 step 0.1" in text and "D_thresh=20" in text
    assert "weights `w-cmal`" in text


def test_readme_agrees_with_the_paper_when_the_numbers_are_the_papers():
    text = render(with_control(as_paper()))
    assert text.count("this run **agrees** with the paper") == 3
    assert "**disagrees**" not in text
    assert "the same best method in 6 of 6 pairs" in text
    assert "Kendall tau between our and the paper's order +1.00" in text


def test_readme_disagrees_when_the_order_is_reversed():
    text = render(with_control(reversed_paper()))
    assert text.count("**disagrees**") == 3
    assert "the same best method in 0 of 6 pairs" in text


def test_readme_reports_whether_training_beat_the_control():
    assert ("trained encoder is higher than its random-weight control"
            in render(with_control(as_paper(), value=0.0)))
    assert "random-weight control scores as high" in render(with_control(as_paper(), value=1.0))


def test_readme_dnn_paragraph_only_for_a_non_vgg_network():
    assert "is not the paper's VGG16" in render(with_control(as_paper()))
    vgg = {**LABELS, "dnn": "DNN (VGG16)"}
    assert "is not the paper's VGG16" not in render(with_control(as_paper()), labels=vgg)


def test_readme_for_a_dataset_without_paper_pairs_says_so():
    nested = nested_from({"nordland": {"summer-winter": {"sad": 0.3, "cmal": 0.2}}})
    text = render(nested, methods=["sad", "cmal"])
    assert "No route and pair of this dataset is one of the paper's" in text
    assert "nordland summer-winter: SAD" in text


def test_readme_lists_tables_and_figures_and_says_why_one_is_missing():
    tables = [Entry(title="Table II", description="Recall.", files=["tables/t2.md"],
                    markdown="| a |\n|--:|\n| 1 |\n")]
    figures = [Entry(title="Fig. 11: reconstructions", description="",
                     missing="`models/cmal/model.pt` does not exist.")]
    text = render(with_control(as_paper()), tables=tables, figures=figures)
    assert "### Table II\n\nRecall.\nFiles: [tables/t2.md](tables/t2.md).\n\n| a |" in text
    assert ("### Fig. 11: reconstructions\n\nNot produced in this run: "
            "`models/cmal/model.pt` does not exist.") in text


def test_readme_states_a_file_ground_truth_instead_of_d_thresh():
    import dataclasses

    from cmal_lcd.reports.provenance import ground_truth_sentence

    meta = {"ground_truth_source": {
        "source": "VPR-Bench ground_truth_new.npy: ../data/gt.npy", "sha256": "ab" * 32,
        "tolerance": "as listed in the file (3-5, median 5 right reference frames per query)",
        "n_ignored_pairs": 0, "n_query_without_reference": 2}}
    sentence = ground_truth_sentence(meta)
    assert sentence.startswith("VPR-Bench ground_truth_new.npy: ../data/gt.npy (sha256 abab")
    assert "queries with no right reference: 2" in sentence
    assert ground_truth_sentence({"ground_truth": "index"}) == ""
    run = dataclasses.replace(RUN, ground_truth=sentence)
    text = readme.render_readme(run=run, methods=["sad"], labels=LABELS,
                                infos={"sad": {"weights": "w", "metric": "sad"}}, selected={},
                                paper_setting={}, tables=(), figures=())
    assert f"- Ground truth: {sentence}" in text and "D_thresh=20" not in text


def test_all_protocols_fell_back_only_when_every_method_did():
    fell = {"fallback": "the dataset has no validation drives"}
    assert readme.all_protocols_fell_back({"sad": fell, "dnn": fell}) == fell["fallback"]
    assert readme.all_protocols_fell_back({"sad": fell, "dnn": {"fallback": None}}) == ""
    assert readme.all_protocols_fell_back({}) == ""


def test_without_validation_drives_the_readme_says_no_protocol_was_chosen():
    import dataclasses

    run = dataclasses.replace(RUN, protocol_fallback="the dataset has no validation drives")
    methods = ["sad", "dnn", "bigan", "cmal", "cmal_untrained"]
    selected = with_control(as_paper())
    text = readme.render_readme(run=run, methods=methods, labels=LABELS,
                                infos={m: {"weights": "w", "metric": "sad"} for m in methods},
                                selected=selected, paper_setting=selected, tables=(),
                                figures=())
    assert ("Matching protocol: the paper's (raw codes, eq. 14 with Table I's window) for "
            "every method, none chosen: the dataset has no validation drives.") in text
    assert "Under the paper's protocol" not in text
    assert "chosen on the validation drives, never on a test route" not in text
    assert "Under the paper's protocol" in render(selected)  # with chosen protocols


def test_without_chosen_protocols_there_is_no_ablation_table(tmp_path):
    from cmal_lcd.reports.sections.results import result_entries

    selected = with_control(as_paper())
    methods = ["sad", "cmal"]
    infos = {m: {"label": m, "metric": "sad", "dim": 4, "dtype": "float32",
                 "bytes_per_frame": 16, "weights": "w"} for m in methods}
    fell = {m: {"selected": {"label": "raw"}, "paper": {"label": "raw"}, "candidates": [],
                "fallback": "the dataset has no validation drives"} for m in methods}
    titles = [e.title for e in result_entries(tmp_path, selected=selected,
                                              paper_setting=selected, protocols=fell,
                                              infos=infos, methods=methods, labels=LABELS,
                                              d_thresh=20)]
    assert "Ablation: the paper's protocol" not in titles and len(titles) == 5


def test_the_readme_says_when_the_cmal_row_is_not_the_papers_objective():
    from cmal_lcd.reports.readme import objective_lines

    extended = objective_lines(["sad", "cmal"], {"cmal": "CMAL (+ eq. 7 prior, eq. 8 adversary)"})
    assert extended[0] == "## The cmal row is not the paper's objective alone"
    assert "**CMAL (+ eq. 7 prior, eq. 8 adversary)**" in extended[2]
    assert "objective=paper" in extended[2]
    # issue 36 item 6: where the paper's objective, left out of the default run, is reported
    assert extended[4].startswith("This run does not train the paper's objective")
    assert "`reports/seeds/README.md`" in extended[4]
    assert objective_lines(["cmal"], {"cmal": "CMAL (paper objective, eqs. 9-12)"}) == []
    assert objective_lines(["sad"], {"sad": "SAD"}) == []


def test_a_preset_run_says_so_first_and_a_toy_run_checks_no_claim():
    """A debug run's page opens with what it is and makes no claim about the paper; an
    experiment run says which experiment and still checks the claims; the default says
    neither."""
    import dataclasses

    nested = with_control(as_paper())
    toy = render(nested, run=dataclasses.replace(
        RUN, presets=("experiment=nordland", "debug=tiny"), paper_claims=False))
    lines = toy.splitlines()
    assert lines[2].startswith("**Preset `experiment=nordland` `debug=tiny`: not the default")
    assert "nothing on this page says anything about the paper" in lines[2]
    assert "agrees" not in toy and "Not checked: this run's config" in toy
    experiment = render(nested, run=dataclasses.replace(RUN, presets=("experiment=seeds",)))
    assert experiment.splitlines()[2].startswith("**Preset `experiment=seeds`")
    assert experiment.count("this run **agrees** with the paper") == 3
    default = render(nested)
    assert "not the default configuration" not in default and default.splitlines()[2].startswith(
        "Open this page first")


def test_the_run_info_reads_the_presets_of_the_config():
    from omegaconf import OmegaConf

    from cmal_lcd.reports.provenance import preset_fields

    tiny = OmegaConf.create({"preset": {"experiment": None, "debug": "debug=tiny",
                                        "paper_claims": False}})
    assert preset_fields(tiny) == {"presets": ("debug=tiny",), "paper_claims": False}
    assert preset_fields(OmegaConf.create({})) == {"presets": (), "paper_claims": True}


def test_a_metric_undefined_for_a_method_is_never_counted_as_0_of_0_pairs():
    """Issue 37: the Nordland report said "higher than SAD in 0 of 0 pairs ... It beats on most
    pairs: none" where CMAL's AUC-ROC was undefined (every match correct)."""
    selected = with_control(nested_from({"r1": {"a-b": {"sad": 0.5, "dnn": 0.6, "bigan": 0.7,
                                                        "cmal": 1.0}}}))
    selected["r1"]["a-b"]["cmal"]["auc_roc"] = math.nan
    selected["r1"]["a-b"]["dnn"]["auc_pr"] = math.nan
    text = render(selected)
    assert "0 of 0" not in text
    assert ("- **CMAL vs the others, AUC-ROC**: not compared: undefined for CMAL (or for every "
            "other method) on every pair") in text
    line = next(line for line in text.splitlines() if "vs the others, AUC-PR" in line)
    assert "SAD in 1 of 1 pairs" in line and "DNN (EfficientNet-Lite0) in" not in line.split(
        ". It beats")[0]
    assert line.endswith("Undefined for one of the two on every pair: DNN (EfficientNet-Lite0).")
