"""Training logs through DVC's own logger, ``dvclive``: ``<model dir>/dvclive``.

The folder holds what any dvclive project has: ``params.yaml`` (the model's config, the seed),
``plots/metrics/<group>/<name>.tsv`` (``step`` + value, one file per logged key, e.g.
``plots/metrics/val/recall_at_100p.tsv``) and ``metrics.json`` (the last value of each key and
its ``step``); ``dvc.yaml`` declares the training charts on those files.

It is rewritten from the loop's own rows (``train_log.csv``'s, restored with the checkpoint on
resume) into a fresh folder at every checkpoint and at the end, without timestamps, so a run
resumed after a kill writes the same files as an uninterrupted one.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from cmal_lcd.io import staged_folder

#: The folder's name inside the model's output folder.
LIVE_DIR = "dvclive"


def write_live_log(out_dir: str | Path, rows: Sequence[Mapping[str, float]],
                   params: Mapping[str, Any]) -> Path:
    """Write ``rows`` (``{"iteration": k, key: value, ...}``, in order) and ``params`` as a
    dvclive folder ``out_dir / "dvclive"``, replacing any previous one atomically.

    Missing and non-finite values are left out of their key's series (a key is logged only at
    some iterations, e.g. ``val/...`` every ``validate_every``).
    """
    from dvclive import Live

    live_dir = Path(out_dir) / LIVE_DIR
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
