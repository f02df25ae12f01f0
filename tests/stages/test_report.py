"""The report stage: from the pipeline's files to tables, figures, DVC files and README."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from cmal_lcd.matching import matching_defaults
from cmal_lcd.reports.tables import METRIC_KEYS
from cmal_lcd.stages import report

sys.path.insert(0, str(Path(__file__).parents[1] / "models"))
from model_helpers import write_model_file  # noqa: E402

METHODS = ["sad", "dnn", "bigan", "cmal", "cmal_untrained"]
LABELS = {"sad": "SAD", "dnn": "DNN (EfficientNet-Lite0)", "bigan": "BiGAN", "cmal": "CMAL",
          "cmal_untrained": "CMAL (untrained control)"}
PAIRS = [("route1", "foggy-rainy"), ("route2", "rainy-sunny")]


def fake_metrics(rng: np.random.Generator) -> dict:
    values = {key: float(rng.uniform(0.05, 0.95)) for key in METRIC_KEYS}
    return {**values, "n_query": 50, "n_scored": 41, "n_positive": 40}


def write_fake_run(root: Path, *, methods=METHODS, pairs=PAIRS, seed=0, matrices=True,
                   invariance=True, reconstructions=True, train_logs=True) -> dict:
    """Files in the formats of docs/architecture.md, with random but valid contents."""
    rng = np.random.default_rng(seed)
    dirs = {name: root / sub for name, sub in (("evaluation", "data/evaluation"),
                                               ("features", "data/features"),
                                               ("protocol", "data/protocol"),
                                               ("timing", "data/timing"),
                                               ("models", "models"), ("dataset", "data/dataset"))}
    for method in methods:
        metrics: dict = {}
        for route, pair in pairs:
            metrics.setdefault(route, {})[pair] = {"selected": fake_metrics(rng),
                                                   "paper": fake_metrics(rng)}
            n = int(rng.integers(5, 30))
            recall = np.sort(rng.uniform(0, 1, n))
            pr = pd.DataFrame({"recall": recall, "precision": np.sort(rng.uniform(0.3, 1, n))[::-1],
                               "threshold": np.sort(rng.uniform(0, 1, n))})
            out = dirs["evaluation"] / method / "pr" / route / f"{pair}.csv"
            out.parent.mkdir(parents=True, exist_ok=True)
            pr.to_csv(out, index=False)
            if matrices:
                D = rng.uniform(0, 1, (20, 18)).astype(np.float32)
                npz = dirs["evaluation"] / method / "matrices" / route / f"{pair}.npz"
                npz.parent.mkdir(parents=True, exist_ok=True)
                np.savez(npz, D=D, D_hat=(D - D.mean()) / D.std(),
                         match=rng.integers(-1, 20, 18), truth=np.arange(18) - 1)
        (dirs["evaluation"] / method / "metrics.json").write_text(json.dumps(metrics))
        info = {"method": method, "label": LABELS.get(method, method.upper()),
                "metric": "sad" if method == "sad" else "sqeuclidean", "dim": 1024,
                "dtype": "float32", "bytes_per_frame": 4096, "weights": f"{method}-weights"}
        (dirs["features"] / method).mkdir(parents=True, exist_ok=True)
        (dirs["features"] / method / "info.json").write_text(json.dumps(info))
        dirs["timing"].mkdir(parents=True, exist_ok=True)
        (dirs["timing"] / f"{method}.json").write_text(json.dumps(
            {"device": "cpu (test)", "batch1_ms": 1.5, "batched_ms": 0.25, "batch_size": 16,
             "repeats": 5}))
        chosen = {"centre": "reference", "l2": True, "enhance": False, "r_window": 10,
                  "label": "centre(reference)+L2, no enhancement"}
        paper = {"centre": "none", "l2": False, "enhance": True, "r_window": 10,
                 "label": "raw, eq. 14 (r_window 10)"}
        dirs["protocol"].mkdir(parents=True, exist_ok=True)
        (dirs["protocol"] / f"{method}.json").write_text(json.dumps({
            "method": method, "selected": chosen, "paper": paper, "fallback": None,
            "candidates": [{**chosen, "mean_recall_at_100p": 0.75, "mean_auc_pr": 0.9},
                           {**paper, "mean_recall_at_100p": 0.25, "mean_auc_pr": 0.5}]}))
    if invariance:
        inv = {route: {m: {"normalisation": "centre(reference)+L2", "same_place": 1.0,
                           "other_place": 2.0, "ratio": 0.5, "single_frame_recall_at_1": 0.6,
                           "raw_ratio": 0.9, "raw_single_frame_recall_at_1": 0.3}
                       for m in methods} for route, _ in pairs}
        (dirs["evaluation"] / "invariance.json").write_text(json.dumps(inv))
    if reconstructions:  # an untrained CMAL; Fig. 11 also needs write_tiny_dataset
        write_model_file(dirs["models"], "cmal", conditions=["sunny", "foggy", "rainy"],
                         image_size=8)
    if train_logs:
        for name in ("cmal", "bigan"):
            (dirs["models"] / name).mkdir(parents=True, exist_ok=True)
            pd.DataFrame({"iteration": [0, 10, 20], "D/loss": [1.0, 0.8, 0.7],
                          "G/adv": [2.0, 1.5, 1.2]}).to_csv(dirs["models"] / name / "train_log.csv",
                                                           index=False)
    return dirs


def config(methods=METHODS):
    return OmegaConf.create({"seed": 3, "methods": list(methods), "model_names": ["cmal", "bigan"],
                             "models": {"cmal": {"heldout_fraction": 0.25}},
                             "runtime": {"threads": 1},
                             "matching": {**matching_defaults(), "d_thresh": 20}})


def run_report(tmp_path: Path, dirs: dict, cfg=None) -> Path:
    return report.main(cfg or config(), evaluation_dir=dirs["evaluation"],
                       features_dir=dirs["features"], models_dir=dirs["models"],
                       dataset_dir=dirs["dataset"], protocol_dir=dirs["protocol"],
                       timing_dir=dirs["timing"], out_dir=tmp_path / "reports",
                       repo_dir=tmp_path)



def link_targets(markdown: str) -> list[str]:
    return re.findall(r"\]\(([^)]+)\)", markdown)


def write_tiny_dataset(path: Path) -> None:
    """A real (tiny) dataset folder in the store format: 2 routes x 3 drives x 4 frames, and 4
    training frames per condition (Fig. 11)."""
    from cmal_lcd.data.store import FRAME_COLUMNS, save_dataset

    conditions = ["sunny", "foggy", "rainy"]
    rows = [{"split": "train", "route": "", "drive": "", "condition": condition,
             "x": float(i), "y": 0.0, "heading": 0.0, "time": 0.0, "s": np.nan}
            for condition in conditions for i in range(4)]
    for route in ("route1", "route2"):
        for condition in conditions:
            for i in range(4):
                rows.append({"split": "test", "route": route, "drive": f"{route}/{condition}",
                             "condition": condition, "x": float(i), "y": 0.0, "heading": 0.0,
                             "time": float(i), "s": float(i)})
    frames = pd.DataFrame(rows)
    frames.insert(0, "frame", np.arange(len(frames)))
    images = np.random.default_rng(0).integers(0, 256, (len(frames), 8, 8, 3), dtype=np.uint8)
    pairs = [[r, f"{r}/{p.split('-')[0]}", f"{r}/{p.split('-')[1]}", p] for r, p in PAIRS]
    save_dataset(path, images, frames[list(FRAME_COLUMNS)],
                 {"kind": "synthetic_weather", "conditions": conditions,
                  "routes": ["route1", "route2"], "pairs": pairs, "image_size": [8, 8]})


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """One report over every input, shared by the tests that only read it."""
    root = tmp_path_factory.mktemp("full")
    dirs = write_fake_run(root)
    write_tiny_dataset(dirs["dataset"])
    readme = run_report(root, dirs)
    return root, dirs, readme


def test_metrics_json_nests_route_pair_method_with_the_five_metrics(full_run):
    root, dirs, _ = full_run
    for name, variant in (("metrics.json", "selected"), ("metrics_paper.json", "paper")):
        written = json.loads((root / "reports" / name).read_text())
        for route, pair in PAIRS:
            for method in METHODS:
                source = json.loads((dirs["evaluation"] / method / "metrics.json").read_text())
                expected = {k: source[route][pair][variant][k] for k in METRIC_KEYS}
                assert written[route][pair][method] == expected


def test_pr_curves_of_every_method_are_one_dvc_plots_file_per_pair(full_run):
    root, dirs, _ = full_run
    for route, pair in PAIRS:
        overlay = pd.read_csv(root / "reports" / "plots" / "pr" / route / f"{pair}.csv")
        assert list(overlay["method"].unique()) == [LABELS[m] for m in METHODS]
        for method in METHODS:
            source = pd.read_csv(dirs["evaluation"] / method / "pr" / route / f"{pair}.csv")
            rows = overlay[overlay["method"] == LABELS[method]]
            np.testing.assert_array_equal(rows["recall"], source["recall"])
            np.testing.assert_array_equal(rows["precision"], source["precision"])
        assert (root / "reports" / "plots" / "roc" / route / f"{pair}.csv").is_file()
    assert not list((root / "reports" / "plots" / "pr").glob("*/*/*.csv"))  # no per-method files


def test_summary_is_one_file_per_method_with_six_means_and_the_dvc_metric_their_r100p(full_run):
    root, dirs, _ = full_run
    files = sorted(p.name for p in (root / "reports" / "summary").iterdir())
    assert files == sorted(f"{m}.json" for m in METHODS)
    sad = json.loads((root / "reports" / "summary" / "sad.json").read_text())
    assert list(sad) == sorted(["R@100P", "AUC-PR", "AUC-ROC", "R@1", "R@5", "SF-R@1"])
    source = json.loads((dirs["evaluation"] / "sad" / "metrics.json").read_text())
    values = [source[r][p]["selected"]["recall_at_100p"] for r, p in PAIRS]
    assert sad["R@100P"] == pytest.approx(np.mean(values), abs=5e-5)
    assert sad["R@5"] is None  # the fake evaluation predates recall@K
    headline = json.loads((root / "reports" / "summary.json").read_text())
    assert headline == {"R100P": {m: json.loads((root / "reports" / "summary" / f"{m}.json")
                                                .read_text())["R@100P"] for m in METHODS}}


@pytest.mark.parametrize("name", ["table2_recall_at_100p", "auc", "recall_at_k",
                                  "table3_inference",
                                  "ablation_paper_protocol", "invariance", "protocol"])
def test_every_table_is_written_as_markdown_csv_and_latex(full_run, name):
    root, _, _ = full_run
    for suffix in ("md", "csv", "tex"):
        text = (root / "reports" / "tables" / f"{name}.{suffix}").read_text()
        assert "DNN (EfficientNet-Lite0)" in text  # the label from info.json, never "dnn"


def test_table2_has_our_numbers_beside_the_papers(full_run):
    root, dirs, _ = full_run
    table = pd.read_csv(root / "reports" / "tables" / "table2_recall_at_100p.csv")
    assert list(table.columns) == ["method", "source", "route1/foggy-rainy", "route2/rainy-sunny"]
    cmal = json.loads((dirs["evaluation"] / "cmal" / "metrics.json").read_text())
    ours = table[(table.method == "CMAL") & (table.source == "this run")].iloc[0]
    assert ours["route1/foggy-rainy"] == cmal["route1"]["foggy-rainy"]["selected"]["recall_at_100p"]
    theirs = table[(table.method == "CMAL") & (table.source == "paper: CMAL")].iloc[0]
    assert theirs["route2/rainy-sunny"] == pytest.approx(0.224)
    md = (root / "reports" / "tables" / "table2_recall_at_100p.md").read_text()
    assert "| CMAL | this run |" in md


def test_table3_names_the_device(full_run):
    """Table III reads the features stage's timing files (data/timing/<method>.json)."""
    root, _, _ = full_run
    assert "cpu (test)" in (root / "reports" / "tables" / "table3_inference.md").read_text()


def test_a_missing_timing_file_is_named_with_the_stage_that_writes_it(tmp_path):
    dirs = write_fake_run(tmp_path)
    (dirs["timing"] / "cmal.json").unlink()
    with pytest.raises(FileNotFoundError, match=r"timing/cmal\.json.*extract_features@cmal"):
        run_report(tmp_path, dirs)


@pytest.mark.parametrize("stem", ["fig06_matrices_route1_foggy-rainy",
                                  "fig06_matrices_route2_rainy-sunny", "fig08-09_pr_route1",
                                  "fig08-09_pr_route2", "fig10_auc", "fig11_reconstructions",
                                  "training_cmal", "training_bigan"])
def test_figures_are_written_as_png_and_pdf(full_run, stem):
    root, _, _ = full_run
    for suffix in (".png", ".pdf"):
        assert (root / "reports" / "figures" / f"{stem}{suffix}").stat().st_size > 1000


def test_config_is_recorded_with_commit_and_dataset_kind(full_run):
    root, _, _ = full_run
    text = (root / "reports" / "config.yaml").read_text()
    assert "# git commit: unknown (not a git repository" in text
    assert "# dataset kind: synthetic_weather" in text
    assert OmegaConf.to_container(OmegaConf.load(root / "reports" / "config.yaml")) == \
        OmegaConf.to_container(config())


def test_readme_links_only_to_files_that_exist_and_mentions_every_table(full_run):
    root, _, readme = full_run
    text = readme.read_text()
    targets = link_targets(text)
    assert targets and all((root / "reports" / t).is_file() for t in targets)
    for name in ("table2_recall_at_100p", "auc", "table3_inference", "ablation_paper_protocol",
                 "invariance"):
        assert f"tables/{name}.md" in targets
    assert "Not produced in this run" in text  # Fig. 1: no world plotting code or images here
    assert "`synthetic_weather`" in text


def test_missing_optional_inputs_are_explained_not_fatal(tmp_path):
    dirs = write_fake_run(tmp_path, methods=["sad", "cmal"], pairs=[("route1", "foggy-rainy")],
                          matrices=False, invariance=False, reconstructions=False,
                          train_logs=False)
    text = run_report(tmp_path, dirs, config(["sad", "cmal"])).read_text()
    reasons = re.findall(r"Not produced in this run: (.+)", text)
    joined = "\n".join(reasons)
    assert "invariance.json" in joined
    assert "model.pt" in joined  # Fig. 11: no trained CMAL model
    assert "train_log.csv" in joined
    assert "dataset.json" in joined
    assert "matrices" in joined
    assert not (tmp_path / "reports" / "tables" / "invariance.md").exists()
    assert (tmp_path / "reports" / "metrics.json").is_file()


def test_loop_closure_within_one_drive_is_a_table_of_every_method(tmp_path):
    dirs, cfg = small_run(tmp_path)
    loops_dir = tmp_path / "data" / "evaluation_loops"
    for k, method in enumerate(["sad", "cmal"]):
        (loops_dir / method).mkdir(parents=True)
        (loops_dir / method / "metrics.json").write_text(json.dumps(
            {"route1": {"sunny-rainy": {"recall_at_100p": 0.25 + k / 2, "auc_pr": 0.5},
                        "sunny-sunny": {"recall_at_100p": 0.75, "auc_pr": 0.875}}}))
    text = report.main(cfg, evaluation_dir=dirs["evaluation"], features_dir=dirs["features"],
                       models_dir=dirs["models"], dataset_dir=dirs["dataset"],
                       protocol_dir=dirs["protocol"], loops_dir=loops_dir,
                       out_dir=tmp_path / "reports", repo_dir=tmp_path).read_text()
    assert "Loop closure within one drive" in text
    assert "| route1 | sunny then rainy (weather change) | 25.0% | 50.0% | 75.0% | 50.0% |" in text
    assert (tmp_path / "reports" / "tables" / "loops.csv").is_file()


def test_a_dataset_without_looping_routes_says_so_in_the_report(tmp_path):
    dirs, cfg = small_run(tmp_path)
    loops_dir = tmp_path / "data" / "evaluation_loops"
    for method in ("sad", "cmal"):
        (loops_dir / method).mkdir(parents=True)
        (loops_dir / method / "metrics.json").write_text(json.dumps(
            {"skipped": "no looping route in this dataset (kind 'folders')"}))
    text = report.main(cfg, evaluation_dir=dirs["evaluation"], features_dir=dirs["features"],
                       models_dir=dirs["models"], dataset_dir=dirs["dataset"],
                       protocol_dir=dirs["protocol"], loops_dir=loops_dir,
                       out_dir=tmp_path / "reports", repo_dir=tmp_path).read_text()
    assert "Not produced in this run: no looping route in this dataset" in text


def small_run(tmp_path, **kw):
    dirs = write_fake_run(tmp_path, methods=["sad", "cmal"], pairs=[("route1", "foggy-rainy")],
                          matrices=False, invariance=False, reconstructions=False,
                          train_logs=False, **kw)
    return dirs, config(["sad", "cmal"])


def test_missing_metrics_file_is_an_error_naming_it(tmp_path):
    dirs, cfg = small_run(tmp_path)
    (dirs["evaluation"] / "cmal" / "metrics.json").unlink()
    with pytest.raises(FileNotFoundError, match=r"cmal/metrics\.json.*evaluate@cmal"):
        run_report(tmp_path, dirs, cfg)


def test_missing_pr_curve_is_an_error_naming_it(tmp_path):
    dirs, cfg = small_run(tmp_path)
    (dirs["evaluation"] / "sad" / "pr" / "route1" / "foggy-rainy.csv").unlink()
    with pytest.raises(FileNotFoundError, match=r"sad/pr/route1/foggy-rainy\.csv"):
        run_report(tmp_path, dirs, cfg)


def test_info_without_label_is_an_error_naming_it(tmp_path):
    dirs, cfg = small_run(tmp_path)
    path = dirs["features"] / "sad" / "info.json"
    path.write_text(json.dumps({"method": "sad"}))
    with pytest.raises(ValueError, match=r"sad/info\.json.*label"):
        run_report(tmp_path, dirs, cfg)


def test_no_methods_is_an_error(tmp_path):
    dirs, _ = small_run(tmp_path)
    with pytest.raises(ValueError, match="methods"):
        run_report(tmp_path, dirs, config([]))


def test_same_inputs_give_byte_identical_reports(tmp_path):
    dirs, cfg = small_run(tmp_path)
    first = run_report(tmp_path, dirs, cfg).parent
    snapshot = {p.relative_to(first): p.read_bytes() for p in first.rglob("*") if p.is_file()}
    run_report(tmp_path, dirs, cfg)
    again = {p.relative_to(first): p.read_bytes() for p in first.rglob("*") if p.is_file()}
    assert snapshot.keys() == again.keys()
    assert [k for k in snapshot if snapshot[k] != again[k]] == []


def test_a_dataset_without_the_papers_routes_has_no_paper_rows(tmp_path):
    dirs = write_fake_run(tmp_path, methods=["sad", "cmal"], pairs=[("nordland", "summer-winter")],
                          matrices=False, invariance=False, reconstructions=False,
                          train_logs=False)
    text = run_report(tmp_path, dirs, config(["sad", "cmal"])).read_text()
    table = (tmp_path / "reports" / "tables" / "table2_recall_at_100p.md").read_text()
    assert "paper:" not in table and "nordland summer-winter" in table
    assert "No route and pair of this dataset is one of the paper's" in text
    metrics = json.loads((tmp_path / "reports" / "metrics.json").read_text())
    assert list(metrics) == ["nordland"] and list(metrics["nordland"]) == ["summer-winter"]


def test_table_columns_follow_the_datasets_pair_order(tmp_path):
    pairs = [("route1", "foggy-rainy"), ("route1", "rainy-sunny")]
    dirs = write_fake_run(tmp_path, methods=["sad"], pairs=pairs, matrices=False,
                          invariance=False, reconstructions=False, train_logs=False)
    dirs["dataset"].mkdir(parents=True)
    (dirs["dataset"] / "dataset.json").write_text(json.dumps(
        {"kind": "k", "pairs": [["route1", "rainy", "sunny", "rainy-sunny"],
                                ["route1", "foggy", "rainy", "foggy-rainy"]]}))
    run_report(tmp_path, dirs, config(["sad"]))
    header = (tmp_path / "reports" / "tables" / "auc.csv").read_text().split("\n")[0]
    assert header == "method,metric,route1/rainy-sunny,route1/foggy-rainy"


def git(repo, *args):
    subprocess.run(["git", "-C", str(repo), "-c", "user.email=t@t", "-c", "user.name=t", *args],
                   check=True, capture_output=True)


@pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")
def test_git_commit_and_dirty_state_are_recorded(tmp_path):
    dirs, cfg = small_run(tmp_path)
    git(tmp_path, "init", "-q")
    (tmp_path / "tracked.txt").write_text("a")
    git(tmp_path, "add", "tracked.txt")
    git(tmp_path, "commit", "-q", "-m", "c")
    commit = subprocess.run(["git", "-C", str(tmp_path), "rev-parse", "HEAD"], check=True,
                            capture_output=True, text=True).stdout.strip()
    text = run_report(tmp_path, dirs, cfg).read_text()
    assert f"git commit: `{commit}`." in text  # clean: untracked data files do not count
    (tmp_path / "tracked.txt").write_text("b")
    text = run_report(tmp_path, dirs, cfg).read_text()
    assert f"git commit: `{commit}` (working tree differed" in text
    assert f"# git commit: {commit} (dirty)" in (tmp_path / "reports" / "config.yaml").read_text()


def test_command_line_reads_params_yaml(tmp_path):
    dirs, cfg = small_run(tmp_path)
    params = tmp_path / "params.yaml"
    params.write_text(OmegaConf.to_yaml(cfg))
    out = tmp_path / "cli_reports"
    report.cli(["--params", str(params), "--evaluation", str(dirs["evaluation"]),
                "--features", str(dirs["features"]), "--models", str(dirs["models"]),
                "--dataset", str(dirs["dataset"]), "--protocol", str(dirs["protocol"]),
                "--timing", str(dirs["timing"]), "--out", str(out)])
    assert (out / "README.md").is_file()
    assert json.loads((out / "metrics.json").read_text())["route1"]["foggy-rainy"]["cmal"]


def report_files(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file()}


def test_a_report_replaces_only_its_own_entries_of_the_out_folder(tmp_path):
    dirs, cfg = small_run(tmp_path)
    out = tmp_path / "reports"
    for name, text in (("world/difficulty.json", "{}"), ("seeds/notes.md", "mine"),
                       ("figures/stale_from_an_older_run.png", "stale"),
                       ("tables/stale.md", "stale")):
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(text)
    run_report(tmp_path, dirs, cfg)
    files = report_files(out)
    assert files["world/difficulty.json"] == b"{}" and files["seeds/notes.md"] == b"mine"
    assert "figures/stale_from_an_older_run.png" not in files and "tables/stale.md" not in files
    assert sorted(p.name for p in out.iterdir()) == sorted([*report.REPORT_OUTPUTS, "world",
                                                            "seeds"])


def test_a_report_failing_mid_way_leaves_the_previous_report_whole(tmp_path, monkeypatch):
    dirs, cfg = small_run(tmp_path)
    out = run_report(tmp_path, dirs, cfg).parent
    before = report_files(out)

    def failing(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(report, "render_readme", failing)  # after every table and figure
    (dirs["evaluation"] / "cmal" / "metrics.json").write_text(
        (dirs["evaluation"] / "sad" / "metrics.json").read_text())  # new numbers
    with pytest.raises(OSError, match="No space left"):
        run_report(tmp_path, dirs, cfg)
    assert report_files(out) == before
    assert sorted(p.name for p in out.iterdir()) == sorted(report.REPORT_OUTPUTS)


def test_the_report_outputs_are_the_stages_persistent_uncached_outs_in_dvc_yaml(repo_root):
    """REPORT_OUTPUTS is what dvc.yaml declares (every entry swapped together), and the
    uncached outs of `report` and `calibrate_world` persist: DVC must not delete them before
    the stage runs, since `dvc checkout` cannot bring them back."""
    import yaml

    stages = yaml.safe_load((repo_root / "dvc.yaml").read_text())["stages"]
    outs = {}
    for stage in ("report", "calibrate_world"):
        for out in stages[stage].get("outs", []) + stages[stage].get("metrics", []):
            (path, flags), = out.items()
            outs[path] = (stage, flags)
    report_outs = sorted(p.removeprefix("reports/") for p, (s, _) in outs.items()
                         if s == "report")
    assert report_outs == sorted(report.REPORT_OUTPUTS)
    assert "reports/world" in outs
    for path, (stage, flags) in outs.items():
        assert flags == {"cache": False, "persist": True}, path
    assert "--out reports" in stages["report"]["cmd"]


def test_every_figure_is_shown_inline_in_the_readme(full_run):
    """Issue 37: the report page showed no figure, only links to them."""
    _, _, readme = full_run
    text = readme.read_text()
    pngs = set(re.findall(r"\]\((figures/[^)]+\.png)\)", text))
    shown = set(re.findall(r"!\[[^\]]*\]\((figures/[^)]+\.png)\)", text))
    assert pngs and shown == pngs
