"""``cmal-lcd verify-manifest MANIFEST FOLDER_OR_DATASET``: is this copy the one a run used?

Compares a split manifest (``data/manifest.csv``, written by the ``dataset`` stage, see
:mod:`cmal_lcd.data.manifest`) with a dataset folder (``data/dataset``: frame ids, labels and
pixels) or with a data root of frame folders (e.g. ``../shared/data/nordland_summer_winter``:
file bytes; a file of a listed sub-folder that the manifest does not know is extra). Prints the
counts and the first changed, missing and extra frames. Exit codes: 0 match, 1 mismatch, 2 bad
input (one line naming the file or folder).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_verify_manifest_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``verify-manifest``."""
    p = subparsers.add_parser(
        "verify-manifest", help="check a dataset folder or frame folders against a manifest",
        description="Report changed, missing and extra frames of FOLDER_OR_DATASET against "
                    "MANIFEST (data/manifest.csv). Exit 0: identical, 1: mismatch, 2: bad "
                    "input.")
    p.add_argument("manifest", type=Path, help="manifest CSV, e.g. data/manifest.csv")
    p.add_argument("target", type=Path,
                   help="a dataset folder (data/dataset) or the data root the manifest's paths "
                        "are relative to (the folder holding the condition sub-folders)")
    p.add_argument("--show", type=int, default=10, help="examples listed per kind")
    p.set_defaults(func=run_verify_manifest)
    return p


def run_verify_manifest(args: argparse.Namespace) -> int:
    """Print the verification; 0 when it matches, 1 on a mismatch, 2 on bad input."""
    from cmal_lcd.data.manifest import ManifestError, read_manifest, verify_manifest

    try:
        result = verify_manifest(read_manifest(args.manifest), args.target)
    except ManifestError as exc:
        print(f"cmal-lcd verify-manifest: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(result.summary(limit=max(0, args.show)))
    print("OK: matches the manifest" if result.ok else
          f"MISMATCH: {args.target} differs from {args.manifest}")
    return 0 if result.ok else 1
