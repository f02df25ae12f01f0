"""Training logs through DVC's own logger, ``dvclive``: ``<model dir>/dvclive``.

The folder holds what any dvclive project has: ``params.yaml`` (the model's config, the seed),
``plots/metrics/<group>/<name>.tsv`` (``step`` + value, one file per logged key, e.g.
``plots/metrics/val/recall_at_100p.tsv``) and ``metrics.json`` (the last value of each key and
its ``step``); ``dvc.yaml`` declares the training charts on those files.

It is rewritten from the loop's own rows (``train_log.csv``'s, restored with the checkpoint on
resume) into a fresh folder at every checkpoint and at the end, without timestamps, so a run
resumed after a kill writes the same files as an uninterrupted one.

Only inside a DVC repository (a ``.dvc`` folder at or above the working directory, as under
``dvc repro``/``dvc exp run`` or ``cmal-lcd-run`` in this checkout): dvclive opens the
repository, and in a git work tree without DVC it would run ``dvc init`` there. Elsewhere the
folder is not written and one INFO line says so; ``train_log.csv`` holds the same rows.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from cmal_lcd.io import staged_folder

logger = logging.getLogger(__name__)

#: The folder's name inside the model's output folder.
LIVE_DIR = "dvclive"


def dvc_repo_root(start: str | Path | None = None) -> Path | None:
    """The nearest folder at or above ``start`` (default: the working directory) that holds a
    ``.dvc`` folder, or None."""
    here = Path(start or Path.cwd()).resolve()
    return next((d for d in (here, *here.parents) if (d / ".dvc").is_dir()), None)


def write_live_log(out_dir: str | Path, rows: Sequence[Mapping[str, float]],
                   params: Mapping[str, Any]) -> Path | None:
    """Write ``rows`` (``{"iteration": k, key: value, ...}``, in order) and ``params`` as a
    dvclive folder ``out_dir / "dvclive"``, replacing any previous one atomically; return it,
    or None outside a DVC repository (:func:`dvc_repo_root`), where nothing is written.

    Missing and non-finite values are left out of their key's series (a key is logged only at
    some iterations, e.g. ``val/...`` every ``validate_every``).
    """
    live_dir = Path(out_dir) / LIVE_DIR
    if dvc_repo_root() is None:
        logger.info("no DVC repository at or above %s: %s not written (train_log.csv has the "
                    "same rows)", Path.cwd(), live_dir)
        return None
    from dvclive import Live

    with staged_folder(live_dir) as staging:
        with Live(dir=str(staging), save_dvc_exp=False, dvcyaml=False, report=None) as live:
            live.log_params(dict(params))
            for row in rows:
                live.step = int(row["iteration"])
                for key, value in row.items():
                    if key != "iteration" and isinstance(value, (int, float)) \
                            and math.isfinite(value):
                        live.log_metric(key, float(value))
                live.next_step()
    return live_dir
