"""Validation runs of CMAL's paper-scale recipe candidates (issue 36 item 3).

Not a timing: trains CMAL once per candidate (its Hydra overrides on top of the common ones) on
a built dataset with the validation monitor on, then prints one Markdown row per candidate:
validation R@100P at every validated iteration, the iteration ``select: best_validation`` keeps
(never 0) and whether it is at or above the untrained encoder (iteration 0, the same weights for
every candidate of one seed). Candidates are chosen on the validation drives only::

    python benchmarks/recipe_candidates.py run --dataset data/dataset --out runs/w64 \\
        --common models.cmal.width=64 models.cmal.classifier_width=32 \\
                 models.cmal.iterations=150 models.cmal.validate_every=50 \\
        --candidate base= --candidate mmd=models.cmal.prior_divergence=mmd \\
        --candidate lr_en=models.cmal.optimizer.lr_en=5e-5
    python benchmarks/recipe_candidates.py table runs/w64

``run`` writes ``OUT/<candidate>/`` (``train_log.csv``, ``model.pt``, ``overrides.txt``: the
common overrides, then the candidate's) and prints the table at the end; ``table`` prints it
again from those files. A candidate's overrides are comma-separated (``a=1,b=2``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

CRITERION = "val/recall_at_100p"


def candidate_overrides(spec: str) -> tuple[str, list[str]]:
    """``"name=a=1,b=2"`` -> ``("name", ["a=1", "b=2"])``; ``"base="`` -> ``("base", [])``."""
    name, _, overrides = spec.partition("=")
    if not name.isidentifier():
        raise SystemExit(f"--candidate {spec!r}: expected NAME=OVERRIDE[,OVERRIDE...]")
    return name, [o for o in overrides.split(",") if o]


def train_candidate(name: str, overrides: list[str], *, dataset: Path, out: Path) -> Path:
    """Compose ``overrides``, train CMAL into ``out/name`` (resuming a killed run)."""
    from cmal_lcd.config import compose
    from cmal_lcd.stages.train import main as train

    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "overrides.txt").write_text("\n".join(overrides) + "\n")
    cfg = compose(overrides)
    return train(cfg, model_name="cmal", dataset_dir=dataset, out_dir=folder,
                 checkpoints_dir=folder / "checkpoints")


def validation_table(out: Path) -> pd.DataFrame:
    """One row per ``out/<candidate>/train_log.csv``: its own overrides (those not shared by
    every candidate), R@100P (%) at each validated iteration, the kept iteration and its score,
    and ``kept >= untrained``."""
    rows = []
    for log in sorted(out.glob("*/train_log.csv")):
        frame = pd.read_csv(log)
        scores = frame.dropna(subset=[CRITERION]).set_index("iteration")[CRITERION]
        trained = scores.drop(index=0, errors="ignore")
        overrides = log.parent / "overrides.txt"
        own = overrides.read_text().split() if overrides.is_file() else []
        row = {"candidate": log.parent.name, "overrides": own}
        row.update({f"it {int(i)}": round(100 * float(v), 1) for i, v in scores.items()})
        if len(trained) and 0 in scores.index:
            kept = int(trained.idxmax())  # the earliest of equal maxima, as select does
            row.update(kept=kept, kept_score=round(100 * float(trained.max()), 1),
                       at_least_untrained=bool(trained.max() >= scores[0]))
        rows.append(row)
    # the overrides every candidate shares are said once, by the caller; a row shows its own
    shared = set.intersection(*(set(r["overrides"]) for r in rows)) if rows else set()
    for row in rows:
        row["overrides"] = " ".join(o for o in row["overrides"] if o not in shared) or "-"
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="train every candidate, then print the table")
    run.add_argument("--dataset", type=Path, required=True)
    run.add_argument("--out", type=Path, required=True)
    run.add_argument("--common", nargs="*", default=[], help="overrides of every candidate")
    run.add_argument("--candidate", action="append", required=True,
                     help="NAME=OVERRIDE[,OVERRIDE...] (NAME= : the common overrides alone)")
    table = commands.add_parser("table", help="print the table of an earlier run")
    table.add_argument("out", type=Path)
    args = parser.parse_args(argv)
    if args.command == "run":
        for spec in args.candidate:
            name, overrides = candidate_overrides(spec)
            train_candidate(name, [*args.common, *overrides], dataset=args.dataset, out=args.out)
    print(validation_table(args.out).to_markdown(index=False))


if __name__ == "__main__":
    main()
