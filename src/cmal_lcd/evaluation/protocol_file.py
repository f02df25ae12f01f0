"""Reading a method's chosen protocol (``data/protocol/<method>.json``) and its statistics.

One place for what every consumer of ``select_protocol``'s output does the same way: the
``evaluate`` and ``analyse_codes`` stages and ``cmal-lcd match`` read the ``selected`` protocol
with :func:`load_selected_protocol` and the training-set centring means with
:func:`centring_means` (only ``centre="condition"`` needs them; they come from the features
folder's *training* codes, never from a query drive).

Not a dependency of the ``train`` stage (``dvc.yaml``): editing it re-runs only the cheap
stages that read protocols.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from cmal_lcd.evaluation.protocol import MatchingProtocol


def read_protocol_record(path: str | Path) -> dict[str, Any]:
    """The whole record ``select_protocol`` wrote to ``path`` (``method``, ``selected``, ...).

    Raises
    ------
    FileNotFoundError, ValueError
        Naming ``path`` when it is missing or not a protocol record.
    """
    from cmal_lcd.io import check_regular_file

    path = Path(path)
    if not path.is_dir():  # a folder gets its own message below
        check_regular_file(path, what="a protocol record")
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        MatchingProtocol.from_dict(record["selected"])
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: missing; run the select_protocol stage") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: a folder, not a protocol record (data/protocol/<method>"
                         f".json)") from None
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path}: not a protocol record ({err}); re-run select_protocol") from err
    return record


def load_selected_protocol(path: str | Path) -> MatchingProtocol:
    """The protocol ``select_protocol`` wrote to ``path`` (``selected`` entry)."""
    return MatchingProtocol.from_dict(read_protocol_record(path)["selected"])


def centring_means(protocol: MatchingProtocol, features_dir: str | Path,
                   n_conditions: int | None = None) -> np.ndarray | None:
    """Training-set mean code per condition when ``protocol`` centres on the condition.

    Parameters
    ----------
    protocol : MatchingProtocol
    features_dir : path-like
        ``data/features/<method>/`` holding ``train_codes.npy`` and ``train_labels.npy``.
    n_conditions : int, optional
        Number of conditions (the dataset's); default: 1 + the largest training label (a
        user's frame folders have no dataset).

    Returns
    -------
    ndarray (n_conditions, F) or None
        ``None`` unless ``protocol.normalisation.centre == "condition"``
        (:func:`cmal_lcd.data.codes.load_centring_means`).

    Raises
    ------
    FileNotFoundError, ValueError
        Naming the file of ``features_dir`` that is missing or unreadable.
    """
    from cmal_lcd.data.codes import load_centring_means

    if protocol.normalisation.centre != "condition":
        return None
    if n_conditions is None:
        n_conditions = training_condition_count(features_dir)
    return load_centring_means(features_dir, n_conditions)


def training_condition_count(features_dir: str | Path) -> int:
    """1 + the largest condition label of ``train_labels.npy`` (0 when there is none)."""
    from cmal_lcd.data.codes import load_training_codes

    _, labels = load_training_codes(features_dir)
    return int(labels.max()) + 1 if len(labels) else 0
