"""``cmal-lcd compose-params [OVERRIDES...]``: write ``params.yaml`` from ``conf/`` (what DVC
reads), e.g. ``cmal-lcd compose-params experiment=paper``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

def add_compose_params_parser(subparsers) -> argparse.ArgumentParser:
    """``cmal-lcd compose-params [OVERRIDES...] [--output params.yaml]``."""
    p = subparsers.add_parser(
        "compose-params", help="write params.yaml from conf/ (plus Hydra overrides)",
        description="Compose conf/config.yaml with Hydra overrides and write it where DVC "
                    "reads it. Same output as `dvc exp run` with hydra.enabled.")
    p.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. experiment=paper")
    p.add_argument("--output", default=None, type=Path,
                   help="default: params.yaml of the checkout (--repo)")
    p.add_argument("--repo", default=None, type=Path,
                   help="the checkout whose conf/ is composed (default: $CMAL_LCD_REPO, else the "
                        "nearest folder at or above the working directory holding "
                        "conf/config.yaml)")
    p.set_defaults(func=run_compose_params)
    return p


def run_compose_params(args: argparse.Namespace) -> int:
    from cmal_lcd.config import checkout_root, compose_params_yaml

    root = checkout_root(args.repo)
    tracked = root / "params.yaml"
    output = compose_params_yaml(args.overrides, output=args.output or tracked,
                                 config_dir=root / "conf")
    print(f"wrote {output}")
    if Path(output).resolve() == tracked.resolve():
        warning = preset_warning(output)
        if warning:
            print(f"cmal-lcd compose-params: warning: {warning}", file=sys.stderr)
    return 0


def preset_warning(params_file: Path) -> str:
    """One line when ``params_file`` (the checkout's tracked ``params.yaml``) holds a preset:
    ``dvc repro`` would replace the committed results with that run's; empty otherwise."""
    import yaml

    preset = (yaml.safe_load(Path(params_file).read_text()) or {}).get("preset") or {}
    names = [str(preset[k]) for k in ("experiment", "debug") if preset.get(k)]
    if not names:
        return ""
    return (f"params.yaml now holds a {' '.join(names)} config: `dvc repro` will replace the "
            f"committed data/, models/ and reports/ with that run's results (undo: `git checkout "
            f"params.yaml dvc.lock reports && dvc checkout`). A try that touches nothing "
            f"tracked: `cmal-lcd-run {' '.join(names)}` (writes under outputs/).")
