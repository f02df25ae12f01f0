"""``reports/README.md``: what was run, every table and figure, and what the numbers say.

The findings are computed here from the same nested metrics the tables show (no prose is
hard-coded about who wins): the best method per pair (:func:`best_methods`), head-to-head
counts (:func:`head_to_head`), the paper's qualitative claims checked on our pairs
(:func:`paper_claims`), the per-pair agreement of method orderings with the paper's Table II
(:func:`ordering_agreement`) and the effect of contrast enhancement (:func:`ablation_effect`).
:func:`render_readme` assembles the page; it does no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from scipy.stats import kendalltau

from cmal_lcd.reports import paper
from cmal_lcd.reports.render import format_percent
from cmal_lcd.reports.tables import METRIC_LABELS, metric_value, route_pairs

#: Two values closer than this count as a tie.
TIE_TOLERANCE = 1e-9
#: The paper's qualitative claims about Table II, as (winner, loser) pairs (Section IV-B:
#: "CMAL ... better than the DNN and BiGAN based method, but is worse than the SAD features").
PAPER_CLAIMS = (("cmal", "dnn"), ("cmal", "bigan"), ("sad", "cmal"))


@dataclass(frozen=True)
class Tally:
    """Outcome of comparing two methods over the pairs where both have a value."""

    wins: int
    losses: int
    ties: int

    @property
    def n(self) -> int:
        """Pairs compared."""
        return self.wins + self.losses + self.ties


@dataclass(frozen=True)
class RunInfo:
    """What produced the numbers.

    Attributes
    ----------
    seed : int or None
    git_commit : str
        Commit hash, or a sentence saying why there is none.
    git_dirty : bool or None
        Whether tracked files differed from the commit (None: unknown).
    dataset_kind : str
        ``kind`` from ``dataset.json`` (e.g. ``synthetic_weather``, ``nordland``).
    matching : mapping
        The ``matching`` node of the config (SeqSLAM parameters, ``d_thresh``).
    ground_truth : str
        What counts as a correct match, in one sentence (:func:`cmal_lcd.reports.provenance.
        ground_truth_sentence`); empty: Table I's ``D_thresh`` frames.
    protocol_fallback : str
        Why no method's protocol was chosen (every ``data/protocol/<method>.json`` fell back to
        the paper's, :func:`all_protocols_fell_back`); empty when they were chosen.
    presets : tuple of str
        The presets the config came from (``experiment=nordland``, ``debug=tiny``; config
        ``preset``); empty: the default configuration.
    paper_claims : bool
        Whether the page checks the paper's claims (false for toy-sized runs).
    """

    seed: object
    git_commit: str
    git_dirty: bool | None
    dataset_kind: str
    matching: Mapping = field(default_factory=dict)
    ground_truth: str = ""
    protocol_fallback: str = ""
    presets: tuple[str, ...] = ()
    paper_claims: bool = True


def all_protocols_fell_back(protocols: Mapping[str, Mapping]) -> str:
    """The shared reason when every method's protocol record fell back to the paper's (no
    validation drives), else ``""``."""
    reasons = {str(record.get("fallback") or "") for record in protocols.values()}
    return reasons.pop() if protocols and len(reasons) == 1 and "" not in reasons else ""


@dataclass(frozen=True)
class Entry:
    """A table or a figure of the report.

    Attributes
    ----------
    title : str
    description : str
        One sentence on what it shows.
    files : sequence of str
        Paths relative to ``reports/`` (empty when not produced).
    markdown : str or None
        Table content to inline in the README.
    missing : str or None
        Why it was not produced in this run (None when it was).
    """

    title: str
    description: str
    files: Sequence[str] = ()
    markdown: str | None = None
    missing: str | None = None


# ---------------------------------------------------------------------------------------------
# Computed findings
# ---------------------------------------------------------------------------------------------

def best_methods(nested: Mapping, *, methods: Sequence[str], metric: str) -> dict:
    """The method(s) with the highest ``metric`` on every route and pair.

    Returns
    -------
    dict
        ``{(route, pair): [method, ...]}`` (several on a tie, none when no value is finite).
    """
    best = {}
    for route, pair in route_pairs(nested):
        values = {m: metric_value(nested, route, pair, m, metric) for m in methods}
        finite = {m: v for m, v in values.items() if math.isfinite(v)}
        if not finite:
            best[(route, pair)] = []
            continue
        top = max(finite.values())
        best[(route, pair)] = [m for m, v in finite.items() if top - v <= TIE_TOLERANCE]
    return best


def head_to_head(nested: Mapping, *, method: str, other: str, metric: str) -> Tally:
    """How often ``method`` scores higher than ``other`` on ``metric`` across routes and pairs
    (pairs where either value is missing are skipped)."""
    wins = losses = ties = 0
    for route, pair in route_pairs(nested):
        a = metric_value(nested, route, pair, method, metric)
        b = metric_value(nested, route, pair, other, metric)
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        if abs(a - b) <= TIE_TOLERANCE:
            ties += 1
        elif a > b:
            wins += 1
        else:
            losses += 1
    return Tally(wins, losses, ties)


def paper_table2_nested() -> dict:
    """The paper's Table II in the report's nesting ``{route: {pair: {method: {metric}}}}``."""
    return {route: {pair: {m: {"recall_at_100p": v} for m, v in methods.items()}
                    for pair, methods in pairs.items()}
            for route, pairs in paper.PAPER_TABLE2_RECALL_AT_100P.items()}


def paper_claims(nested: Mapping, *, methods: Sequence[str],
                 metric: str = "recall_at_100p") -> list[dict]:
    """The paper's claims (:data:`PAPER_CLAIMS`) counted on our pairs and on the paper's.

    Returns
    -------
    list of dict
        ``{"winner", "loser", "ours": Tally, "paper": Tally}`` for every claim whose two
        methods we ran. The paper's tally always uses its own Table II (recall at 100%
        precision), whichever ``metric`` ours uses.
    """
    reference = paper_table2_nested()
    return [{"winner": w, "loser": l,
             "ours": head_to_head(nested, method=w, other=l, metric=metric),
             "paper": head_to_head(reference, method=w, other=l, metric="recall_at_100p")}
            for w, l in PAPER_CLAIMS if w in methods and l in methods]


def _ranking(values: Mapping[str, float]) -> list[str]:
    return sorted(values, key=lambda m: (-values[m], m))


def ordering_agreement(nested: Mapping, *, methods: Sequence[str]) -> list[dict]:
    """Per route and pair that the paper also reports: our order of the paper's methods by
    recall at 100% precision against the paper's order.

    Returns
    -------
    list of dict
        ``{"route", "pair", "ours": [methods best first], "paper": [...], "same_best": bool,
        "kendall_tau": float}`` (tau is NaN when either ordering is all ties).
    """
    common = [m for m in methods if m in paper.PAPER_METHOD_LABELS]
    rows = []
    for route, pair in route_pairs(nested):
        theirs = {m: paper.paper_recall_at_100p(route, pair, m) for m in common}
        ours = {m: metric_value(nested, route, pair, m, "recall_at_100p") for m in common}
        keep = [m for m in common if math.isfinite(theirs[m]) and math.isfinite(ours[m])]
        if len(keep) < 2:
            continue
        a = np.array([ours[m] for m in keep])
        b = np.array([theirs[m] for m in keep])
        tau = (float(kendalltau(a, b).statistic)
               if np.ptp(a) > 0 and np.ptp(b) > 0 else math.nan)
        ours_rank = _ranking({m: ours[m] for m in keep})
        paper_rank = _ranking({m: theirs[m] for m in keep})
        rows.append({"route": route, "pair": pair, "ours": ours_rank, "paper": paper_rank,
                     "same_best": ours_rank[0] == paper_rank[0], "kendall_tau": tau})
    return rows


def ablation_effect(selected: Mapping, paper_setting: Mapping, *, methods: Sequence[str],
                    metric: str = "recall_at_100p") -> dict:
    """Mean ``metric`` under the selected protocol and under the paper's, per method.

    Returns
    -------
    dict
        ``{method: {"selected": mean, "paper": mean, "paper_better": count, "n": pairs}}``
        over the pairs where both variants have a value.
    """
    effect = {}
    for method in methods:
        pairs = [(metric_value(selected, r, p, method, metric),
                  metric_value(paper_setting, r, p, method, metric))
                 for r, p in route_pairs(selected)]
        pairs = [(e, q) for e, q in pairs if math.isfinite(e) and math.isfinite(q)]
        effect[method] = {
            "selected": float(np.mean([e for e, _ in pairs])) if pairs else math.nan,
            "paper": float(np.mean([q for _, q in pairs])) if pairs else math.nan,
            "paper_better": sum(q - e > TIE_TOLERANCE for e, q in pairs),
            "n": len(pairs),
        }
    return effect


def is_paper_dnn(label: str) -> bool:
    """Whether a DNN label names the paper's network (VGG16)."""
    return "VGG16" in label.upper().replace("-", "").replace(" ", "")


# ---------------------------------------------------------------------------------------------
# Writing the page
# ---------------------------------------------------------------------------------------------

def _names(methods: Sequence[str], labels: Mapping[str, str]) -> str:
    return ", ".join(labels.get(m, m) for m in methods) or "none"


def _tally_text(t: Tally) -> str:
    ties = f", {t.ties} tied" if t.ties else ""
    return f"{t.wins} of {t.n}{ties}"


def _versus_line(focus: str, metric: str, tallies: Mapping[str, Tally],
                 labels: Mapping[str, str]) -> str:
    """``focus`` against each other method on ``metric``: the pairs where both are defined
    (a metric is undefined where, e.g., every match was correct: an ROC curve needs both
    kinds); methods with no such pair are named apart, never counted as "0 of 0"."""
    head = f"- **{labels[focus]} vs the others, {METRIC_LABELS[metric]}**: "
    compared = {m: t for m, t in tallies.items() if t.n}
    apart = [m for m, t in tallies.items() if not t.n]
    if not compared:
        return (head + f"not compared: undefined for {labels[focus]} (or for every other "
                       f"method) on every pair, e.g. when every match it made was correct, "
                       f"which leaves the ROC curve no false matches.")
    beaten = [m for m, t in compared.items() if t.wins > t.losses]
    text = "; ".join(f"{labels.get(m, m)} in {_tally_text(t)} pairs" for m, t in compared.items())
    line = head + f"higher than {text}. It beats on most pairs: {_names(beaten, labels)}."
    if apart:
        line += f" Undefined for one of the two on every pair: {_names(apart, labels)}."
    return line


def findings_lines(selected: Mapping, paper_setting: Mapping, *, methods: Sequence[str],
                   labels: Mapping[str, str], focus: str = "cmal",
                   protocols_chosen: bool = True) -> list[str]:
    """Markdown bullet lines stating the computed findings."""
    lines = []
    for metric in ("recall_at_100p", "auc_roc"):
        best = best_methods(selected, methods=methods, metric=metric)
        parts = [f"{route} {pair}: {_names(winners, labels)}"
                 for (route, pair), winners in best.items()]
        lines.append(f"- **Best {METRIC_LABELS[metric]} per pair**: " + "; ".join(parts) + ".")
        counts = {m: sum(m in w for w in best.values()) for m in methods}
        top = max(counts.values(), default=0)
        leaders = [m for m in methods if counts[m] == top and top > 0]
        lines.append(f"  Most often best: {_names(leaders, labels)} "
                     f"({top} of {len(best)} pairs{' each' if len(leaders) > 1 else ''}).")
    if focus in methods:
        others = [m for m in methods if m != focus]
        for metric in ("recall_at_100p", "auc_roc", "auc_pr"):
            tallies = {m: head_to_head(selected, method=focus, other=m, metric=metric)
                       for m in others}
            lines.append(_versus_line(focus, metric, tallies, labels))
        control = f"{focus}_untrained"
        if control in methods:
            t = head_to_head(selected, method=focus, other=control, metric="recall_at_100p")
            verdict = ("in this run (one seed) the trained encoder is higher than its "
                       "random-weight control on most pairs" if t.wins > t.losses else
                       "in this run (one seed) the random-weight control scores as high or "
                       "higher on at least half of the pairs")
            verdict += ("; whether training helps is a claim over seeds: see "
                        "`reports/seeds/README.md` for intervals and paired tests")
            lines.append(f"- **Untrained control**: {verdict} ({labels[focus]} higher in "
                         f"{_tally_text(t)} pairs, recall@100%P).")
    if not protocols_chosen:  # every method ran under the paper's protocol: nothing to compare
        return lines
    effect = ablation_effect(selected, paper_setting, methods=methods)
    parts = [f"{labels.get(m, m)} {format_percent(e['selected'])} → {format_percent(e['paper'])}"
             f" (paper protocol better on {e['paper_better']} of {e['n']})"
             for m, e in effect.items()]
    lines.append("- **Under the paper's protocol** (raw codes, eq. 14; mean recall@100%P, "
                 "selected protocol → paper protocol): "
                 + "; ".join(parts) + ".")
    return lines


def paper_comparison_lines(selected: Mapping, *, methods: Sequence[str],
                           labels: Mapping[str, str]) -> list[str]:
    """Markdown lines comparing our results with the paper's Table II (computed)."""
    lines = []
    claims = paper_claims(selected, methods=methods)
    for claim in claims:
        w, l = claim["winner"], claim["loser"]
        ours, theirs = claim["ours"], claim["paper"]
        holds_ours = ours.n > 0 and ours.wins > ours.losses
        holds_paper = theirs.wins > theirs.losses
        verdict = "agrees" if holds_ours == holds_paper else "disagrees"
        lines.append(f"- Paper: {paper.PAPER_METHOD_LABELS[w]} above "
                     f"{paper.PAPER_METHOD_LABELS[l]} in {_tally_text(theirs)} of its pairs; "
                     f"here {labels.get(w, w)} above {labels.get(l, l)} in "
                     f"{_tally_text(ours)} pairs → this run **{verdict}** with the paper.")
    rows = ordering_agreement(selected, methods=methods)
    if rows:
        same = sum(r["same_best"] for r in rows)
        taus = [r["kendall_tau"] for r in rows if math.isfinite(r["kendall_tau"])]
        lines.append(f"- Per-pair ordering of the paper's methods by recall@100%P (routes and "
                     f"pairs the paper also reports): the same best method in {same} of "
                     f"{len(rows)} pairs; mean Kendall tau between our and the paper's order "
                     + (f"{np.mean(taus):+.2f}" if taus else "undefined (ties)")
                     + " (+1 = same order, -1 = reversed).")
        for r in rows:
            lines.append(f"  - {r['route']} {r['pair']}: here "
                         f"{' > '.join(labels.get(m, m) for m in r['ours'])}; paper "
                         f"{' > '.join(paper.PAPER_METHOD_LABELS[m] for m in r['paper'])}.")
    else:
        lines.append("- No route and pair of this dataset is one of the paper's (route1/route2 x "
                     "foggy-rainy, foggy-sunny, rainy-sunny), so Table II shows no paper rows; "
                     "only the qualitative claims above are compared.")
    return lines


def _pair_convention(selected: Mapping) -> str:
    """How pairs are written, with this run's first pair as the example."""
    pair = next((p for pairs in selected.values() for p in pairs), None)
    parts = str(pair).split("-") if pair is not None else []
    example = (f": `{pair}` means the {parts[0]} drive is the reference (the map) and the "
               f"{parts[1]} drive is the query" if len(parts) == 2 else
               ": the first drive is the reference (the map), the second the query")
    return f"- Pairs are written `reference-query`{example}."


def _run_lines(run: RunInfo, selected: Mapping) -> list[str]:
    m = run.matching
    dirty = {True: " (working tree differed from this commit: uncommitted changes were used)",
             False: "", None: " (clean state unknown)"}[run.git_dirty]
    seqslam = (f"ds={m.get('ds')}, v={m.get('v_min')}..{m.get('v_max')} step {m.get('v_step')}, "
               f"r_window={m.get('r_window')}, contrast enhancement (eq. 14) "
               f"{'on' if m.get('enhance', True) else 'off'}, PR threshold on `{m.get('score')}`"
               + ("" if run.ground_truth else
                  f", a match is correct within D_thresh={m.get('d_thresh')} frames"))
    return [f"- Dataset: `{run.dataset_kind}`.",
            f"- Seed: `{run.seed}`; git commit: `{run.git_commit}`{dirty}.",
            "- Configuration: [config.yaml](config.yaml) is the composed config that produced "
            "every number here (a copy of `params.yaml`).",
            "- Frames: `data/manifest.csv` (written by the pipeline's dataset stage) lists every "
            "frame used for training, validation, reference and query with its sha256; check a "
            "copy with `cmal-lcd verify-manifest data/manifest.csv data/dataset` (docs/loops.md).",
            f"- SeqSLAM (paper Table I): {seqslam}.",
            *([f"- Ground truth: {run.ground_truth}"] if run.ground_truth else []),
            *([f"- Matching protocol: the paper's (raw codes, eq. 14 with Table I's window) "
               f"for every method, none chosen: {run.protocol_fallback}."]
              if run.protocol_fallback else []),
            _pair_convention(selected)]


def _entry_lines(entry: Entry, *, level: str) -> list[str]:
    lines = [f"{level} {entry.title}", ""]
    if entry.missing:
        return lines + [f"Not produced in this run: {entry.missing}", ""]
    lines.append(entry.description)
    if entry.files:
        lines.append("Files: " + ", ".join(f"[{f}]({f})" for f in entry.files) + ".")
    lines.append("")
    lines += [f"![{entry.title}]({f})\n" for f in entry.files if f.endswith(".png")]
    if entry.markdown:
        lines += [entry.markdown.rstrip("\n"), ""]
    return lines


def dnn_lines(methods: Sequence[str], labels: Mapping[str, str],
              infos: Mapping[str, Mapping]) -> list[str]:
    """A paragraph on the DNN baseline when it is not the paper's VGG16 (else empty)."""
    if "dnn" not in methods or is_paper_dnn(labels.get("dnn", "")):
        return []
    weights = infos.get("dnn", {}).get("weights", "unknown")
    return ["## The DNN baseline is not the paper's VGG16", "",
            f"The paper's DNN row uses fully connected VGG16 features pretrained on ImageNet. "
            f"This run used **{labels['dnn']}** instead (weights: `{weights}`; the pipeline "
            f"downloads nothing from model hubs). Both are ImageNet classifiers used as frozen "
            f"global descriptors, but the network, its depth and its code size differ, so the "
            f"DNN rows compare the idea (generic pretrained features), not the exact network.",
            ""]


#: The label of a CMAL row trained with the paper's objective alone (``CMAL.label``).
PAPER_OBJECTIVE = "paper objective, eqs. 9-12"


def objective_lines(methods: Sequence[str], labels: Mapping[str, str], *,
                    focus: str = "cmal") -> list[str]:
    """A paragraph saying which row is the paper's method, when the ``focus`` row was trained
    with more than the paper's objective (its label says which terms; else empty)."""
    label = labels.get(focus, "")
    if focus not in methods or PAPER_OBJECTIVE in label:
        return []
    return [f"## The {focus} row is not the paper's objective alone", "",
            "The paper trains CMAL with eqs. 9-12 only (V_A + V_B + L_R). This run's "
            f"`{focus}` row is **{label}**: its objective (`objective` in `conf/config.yaml`) "
            "adds the terms its label lists, which `conf/objective/` and "
            "`conf/model/cmal.yaml` describe (why the default objective adds them, with its "
            "validation numbers: docs/decisions.md). So this row is an extension of the "
            "paper's method, not the method itself; `objective=paper` trains the paper's "
            "objective, labelled \"CMAL (" + PAPER_OBJECTIVE + ")\". Where the findings "
            "compare with the paper's CMAL, they compare this row.", "",
            "This run does not train the paper's objective (the default run leaves it out to "
            "stay within 15 minutes on 2 cores). Its rows beside this objective's, over 3 "
            "seeds on the rendered world's test routes with 95% intervals and paired "
            "differences, are in `reports/seeds/README.md` (`cmal-lcd seeds-report`; the "
            "sweeps' commands: `conf/experiment/seeds.yaml`).", ""]


def _intro_lines(run: RunInfo, methods: Sequence[str], labels: Mapping[str, str],
                 infos: Mapping[str, Mapping], selected: Mapping) -> list[str]:
    """The page's head: what it is, what was run, the methods and the metrics."""
    method_lines = [f"- **{labels.get(m, m)}** (`{m}`): weights "
                    f"`{infos.get(m, {}).get('weights', 'unknown')}`, compared with "
                    f"`{infos.get(m, {}).get('metric', '?')}`." for m in methods]
    return ["# Results: CMAL loop closure detection, reproduced", "", *_preset_lines(run),
            "Open this page first. Every number here was computed by the pipeline "
            "(`dvc repro`, or the Hydra app `cmal-lcd-run`) from its dataset and models; "
            "nothing is typed in by "
            "hand except the paper's own published numbers, which are labelled "
            f"\"paper\" and cited ({paper.PAPER_CITATION}; measured in the "
            f"{paper.PAPER_SETTING}).",
            "", "## What was run", "", *_run_lines(run, selected), "",
            "Methods (rows of every table):", "", *method_lines, "",
            "Metrics: *recall@100%P* is the highest recall reached by a threshold on the "
            "SeqSLAM confidence that admits no false positive (paper Table II); *AUC-ROC* and "
            "*AUC-PR* are the areas under the ROC and precision-recall curves; *recall@1* "
            "counts queries whose best match is correct; *single-frame recall@1* is the same "
            "without sequence matching. " + (
                "Every table uses the paper's protocol (raw codes, eq. 14 with Table I's "
                "window): this dataset has no validation drives to choose another on."
                if run.protocol_fallback else
                "Main tables use, for every method, the matching protocol (code centring, L2 "
                "normalisation, contrast enhancement and its window) chosen on the validation "
                "drives, never on a test route (see *Matching protocol per method*); the "
                "ablation repeats them under the paper's protocol (raw codes, eq. 14 with "
                "Table I's window)."), ""]


def _preset_lines(run: RunInfo) -> list[str]:
    """The page's first line when the config is not the default one: which presets, and
    whether the paper's claims are checked."""
    if not run.presets:
        return []
    names = " ".join(f"`{p}`" for p in run.presets)
    claims = ("" if run.paper_claims else " Its models are toy-sized (a few iterations on small "
              "frames): nothing on this page says anything about the paper, and its claims "
              "are not checked.")
    return [f"**Preset {names}: not the default configuration.**{claims}", ""]


def paper_claims_lines(run: RunInfo, selected: Mapping, *, methods: Sequence[str],
                       labels: Mapping[str, str]) -> list[str]:
    """The section *Agreement with the paper*, or one line saying why it is left out."""
    if not run.paper_claims:
        return ["Not checked: this run's config (`preset.paper_claims: false`) is too small "
                "for its numbers to say anything about the paper's claims."]
    return paper_comparison_lines(selected, methods=methods, labels=labels)


def _closing_lines(run: RunInfo) -> list[str]:
    """The page's end: the caveats and the other files of ``reports/``."""
    return ["## Caveats", "",
            f"- The paper's numbers come from GTA V footage on its own two routes; this run's "
            f"dataset is `{run.dataset_kind}`. When that is the procedural world, its weather "
            f"and scenes are synthetic, so absolute numbers are not comparable with the "
            f"paper's, only orderings and trends.",
            "- The default configuration is a small CPU budget (short training, small images); "
            "learned methods may be under-trained compared with the paper's GPU training. The "
            "training curves above show how far training went.",
            "- Inference times were measured on this machine (device named in Table III), "
            "possibly shared with other jobs; the paper's times are from a Titan X GPU.",
            "- Recall at 100% precision hinges on the single most confident false match, so it "
            "moves a lot between pairs and seeds; AUC-PR is the steadier summary.", "",
            "## Other files", "",
            "- [metrics.json](metrics.json): route → pair → method → every metric, "
            "recall@K included (selected protocols); [metrics_paper.json](metrics_paper.json):"
            " the same under the paper's protocol; [summary.json](summary.json): each "
            "method's mean R@100P over routes and pairs (the DVC metrics: what `dvc metrics "
            "show` and `dvc exp show` print); `summary/<method>.json`: per method, the "
            "mean over routes and pairs of R@100P, AUC-PR, AUC-ROC, R@1, R@5 and "
            "single-frame R@1 (selected protocols; `dvc metrics show -R reports/summary` "
            "prints one row per method, `dvc metrics diff -R --targets reports/summary` "
            "compares them).",
            "- `plots/pr/<route>/<pair>.csv` and `plots/roc/<route>/<pair>.csv`: PR and ROC "
            "curves of every method on one pair, as DVC plots files (`dvc plots show`: one "
            "chart per pair with the methods overlaid); `plots/training/<model>/`: each "
            "trained model's logged series (the training and validation charts of `dvc plots "
            "show`, here so that a fresh clone draws them).",
            "- Beside this page, when present, reports made by other commands, each with its "
            "own README and config (not linked: this page links only what this run wrote): "
            "`world/` (how hard each weather pair of the rendered world is for SAD: the "
            "`calibrate_world` stage), `seeds/README.md` (CMAL over seeds with 95% intervals: "
            "`cmal-lcd seeds-report`), `place/README.md` (the place-supervised extensions "
            "`cmal_place` and `place_encoder` over seeds: `experiment=place`, not the "
            "paper), `nordland/README.md` and `corridor/README.md` (real "
            "frames: `cmal-lcd-run experiment=nordland` / `experiment=corridor`).", ""]


def render_readme(*, run: RunInfo, methods: Sequence[str], labels: Mapping[str, str],
                  infos: Mapping[str, Mapping], selected: Mapping, paper_setting: Mapping,
                  tables: Sequence[Entry], figures: Sequence[Entry]) -> str:
    """The text of ``reports/README.md``.

    Parameters
    ----------
    run : RunInfo
    methods : sequence of str
        Methods in table order; ``labels[method]`` is how they are shown.
    infos : mapping
        ``{method: info.json contents}`` (weights).
    selected, paper_setting : mapping
        ``{route: {pair: {method: {metric: value}}}}`` under each method's selected protocol
        and under the paper's protocol.
    tables, figures : sequence of Entry
    """
    lines = [*_intro_lines(run, methods, labels, infos, selected),
             "## Findings (computed from the tables below)", "",
             *findings_lines(selected, paper_setting, methods=methods, labels=labels,
                             protocols_chosen=not run.protocol_fallback), "",
             "### Agreement with the paper", "",
             *paper_claims_lines(run, selected, methods=methods, labels=labels), "",
             *dnn_lines(methods, labels, infos),
             *objective_lines(methods, labels),
             "## Tables", ""]
    for entry in tables:
        lines += _entry_lines(entry, level="###")
    lines += ["## Figures", ""]
    for entry in figures:
        lines += _entry_lines(entry, level="###")
    lines += _closing_lines(run)
    return "\n".join(lines)
