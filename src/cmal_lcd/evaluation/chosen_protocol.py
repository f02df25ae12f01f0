"""The matching protocol a user's pair is matched under, and where it came from.

:func:`choose_protocol` decides, before any frame is read:

- ``protocol=FILE``: the ``selected`` protocol of a ``data/protocol/<method>.json`` written by
  the ``select_protocol`` stage (chosen on validation drives);
- ``protocol="raw"``: codes as extracted, enhancement as the SeqSLAM parameters say (by
  default eq. 14 with Table I's window: the paper's protocol);
- neither, ``sad`` or descriptor files: ``raw`` (SAD keeps the paper's matching);
- neither, a DNN or learned extractor: the file the pipeline writes,
  ``<checkout>/data/protocol/<method>.json`` with ``<checkout>`` the folder holding the model
  folder (else the checkout of the working directory); when it is absent, ``raw``, with a
  warning (raw learned codes with eq. 14 tend to match the weather, not the place).

Centring statistics (``centre=condition``) come from the *training* codes of the pipeline's
features folder (default ``<checkout>/data/features/<method>``), never from the queries: a
robot sees its queries one at a time.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cmal_lcd.data.pair_inputs import PRECOMPUTED

if TYPE_CHECKING:  # imported lazily at run time
    import numpy as np

    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.matching import SeqSLAMParams

#: ``--protocol`` value for codes as extracted, enhancement from ``--no-enhance``/``--r-window``.
RAW_PROTOCOL = "raw"


@dataclasses.dataclass(frozen=True)
class ChosenProtocol:
    """The protocol ``match`` applies and where it came from.

    Attributes
    ----------
    protocol : MatchingProtocol
    source : str
        Printed after the label: the file, or why ``raw`` was used.
    file : Path or None
        The protocol file read.
    train_features : Path or None
        Features folder of the centring means (``centre="condition"`` only).
    warning : str or None
        Printed as a warning (``raw`` learned codes because no file was found).
    """

    protocol: MatchingProtocol
    source: str
    file: Path | None = None
    train_features: Path | None = None
    warning: str | None = None

    def train_means(self) -> np.ndarray | None:
        """Training-set mean code per condition, ``(K, F)``, or None (no condition centring).

        Raises
        ------
        ValueError
            Naming the missing or unreadable file and ``--train-features``.
        """
        from cmal_lcd.evaluation.protocol_file import centring_means

        if self.protocol.normalisation.centre != "condition":
            return None
        try:
            return centring_means(self.protocol, self.train_features)
        except (FileNotFoundError, ValueError) as err:
            raise ValueError(f"--train-features: {err} (the centring means of "
                             f"{self.protocol.label})") from None

    def as_dict(self) -> dict[str, Any]:
        """``centre, l2, enhance, r_window, label, source, file, train_features, warning``."""
        return {**self.protocol.as_dict(), "source": self.source,
                "file": None if self.file is None else str(self.file),
                "train_features": (None if self.train_features is None
                                   or self.protocol.normalisation.centre != "condition"
                                   else str(self.train_features)),
                "warning": self.warning}


def raw_protocol(params: SeqSLAMParams) -> MatchingProtocol:
    """Codes as extracted; enhancement and window from ``params`` (Table I: the paper's)."""
    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.matching.normalise import CodeNormalisation

    return MatchingProtocol(CodeNormalisation("none", False), enhance=params.enhance,
                            r_window=params.r_window)


def pipeline_protocol_path(features: str, *,
                           model_dir: str | os.PathLike | None) -> Path | None:
    """Where the pipeline writes ``features``' protocol: ``<checkout>/data/protocol/<name>.json``
    with ``<checkout>`` the parent of ``model_dir`` (else the working directory's checkout;
    None outside one)."""
    from cmal_lcd.checkout import CheckoutNotFoundError, checkout_root
    from cmal_lcd.paths import REPO

    if model_dir is not None:
        root = Path(os.path.abspath(model_dir)).parent
    else:
        try:
            root = checkout_root()
        except CheckoutNotFoundError:
            return None
    return root / REPO.protocol(features)


def choose_protocol(features: str, protocol: str | os.PathLike | None, *,
                    model_dir: str | os.PathLike | None, params: SeqSLAMParams,
                    train_features: str | os.PathLike | None = None,
                    defaults: SeqSLAMParams | None = None) -> ChosenProtocol:
    """The protocol ``match`` applies (module docstring), before any frame is read.

    ``defaults``: the configured matching parameters (default: ``SeqSLAMParams.defaults()``); a
    protocol file refuses ``params`` whose enhancement differs from them.

    Raises
    ------
    ValueError
        ``--protocol FILE``: missing, not a protocol record, or chosen for another method;
        ``--no-enhance``/``--r-window`` changed while a file sets the enhancement.
    """
    if protocol is not None and str(protocol) == RAW_PROTOCOL:
        return ChosenProtocol(raw_protocol(params), source="--protocol raw")
    if protocol is not None:
        return _protocol_from_file(Path(protocol), features, params=params,
                                   train_features=train_features, found=False,
                                   defaults=defaults)
    if features == "sad":
        return ChosenProtocol(raw_protocol(params),
                              source="sad default; --protocol FILE applies a chosen one")
    if features == PRECOMPUTED:
        return ChosenProtocol(raw_protocol(params), source="descriptor files, as given")
    path = pipeline_protocol_path(features, model_dir=model_dir)
    if path is not None and path.is_file():
        return _protocol_from_file(path, features, params=params,
                                   train_features=train_features, found=True,
                                   defaults=defaults)
    where = str(path) if path is not None else "no checkout found (pass --model-dir)"
    return ChosenProtocol(
        raw_protocol(params), source=f"fallback: no protocol file ({where})",
        warning=f"no protocol chosen for {features} ({where}): using raw codes with "
                f"{'eq. 14' if params.enhance else 'no enhancement'}, which for learned codes "
                f"tends to match the weather rather than the place; pass --protocol "
                f"data/protocol/{features}.json (select_protocol stage) or --protocol raw")


def _protocol_from_file(path: Path, features: str, *, params: SeqSLAMParams,
                        train_features: str | os.PathLike | None,
                        found: bool, defaults: SeqSLAMParams | None = None
                        ) -> ChosenProtocol:
    from cmal_lcd.evaluation.protocol import MatchingProtocol
    from cmal_lcd.evaluation.protocol_file import read_protocol_record
    from cmal_lcd.matching import SeqSLAMParams
    from cmal_lcd.paths import REPO

    try:
        record = read_protocol_record(path)
    except (FileNotFoundError, ValueError) as err:
        raise ValueError(f"--protocol {err}") from None
    method = record.get("method")
    if method is not None and method != features:
        raise ValueError(f"--protocol {path}: chosen for {method!r}, not for --features "
                         f"{features!r}")
    chosen = MatchingProtocol.from_dict(record["selected"])
    default = SeqSLAMParams.defaults() if defaults is None else defaults
    if (params.enhance, params.r_window) != (default.enhance, default.r_window):
        raise ValueError(f"--no-enhance/--r-window: {path} sets the enhancement "
                         f"({chosen.label}); leave them at their defaults or pass --protocol "
                         f"{RAW_PROTOCOL}")
    if train_features is None:
        train_features = path.parent.parent.parent / REPO.method_features(features)
    if chosen.normalisation.centre == "condition":
        check_training_features(Path(train_features), features)
    source = f"{path}{' (found beside --model-dir)' if found else ''}"
    return ChosenProtocol(chosen, source=source, file=path,
                          train_features=Path(train_features))


def check_training_features(folder: Path, features: str) -> None:
    """Refuse a features folder whose ``info.json`` names another method than ``features``.

    Raises
    ------
    ValueError
        ``--train-features <folder>: codes of '<method>', not of '<features>'``.
    """
    import json

    try:
        method = json.loads((folder / "info.json").read_text(encoding="utf-8")).get("method")
    except (OSError, ValueError, AttributeError):
        return  # no readable info.json: the training codes' own checks speak later
    if method is not None and method != features:
        raise ValueError(f"--train-features {folder}: codes of {method!r}, not of "
                         f"{features!r}")
