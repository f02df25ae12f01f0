"""The matching protocol of a method, and choosing it on validation drives.

A protocol is what happens to a method's codes between extraction and the sequence search:
the code normalisation (:class:`~cmal_lcd.matching.normalise.CodeNormalisation`) and the local
contrast enhancement of eq. 14 with its window. The paper applies one protocol to every method
(raw codes, eq. 14 with ``r_window`` 10); smooth learned codes and hand-made thumbnails do not
need the same one, so each method gets the protocol that scores best on the *validation* route,
and the paper's protocol stays as an ablation (``paper`` variant).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from cmal_lcd.matching import SeqSLAMParams
from cmal_lcd.matching.normalise import CENTRES, CodeNormalisation
from cmal_lcd.schema import CRITERIA  # metrics a selection may maximise (over validation pairs)


@dataclass(frozen=True)
class MatchingProtocol:
    """Normalisation plus enhancement.

    Attributes
    ----------
    normalisation : CodeNormalisation
    enhance : bool
        Apply eq. 14.
    r_window : int
        Enhancement window when ``enhance``; always the uniqueness exclusion window.
    """

    normalisation: CodeNormalisation
    enhance: bool
    r_window: int

    @property
    def label(self) -> str:
        """``centre(reference)+L2, eq. 14 (r_window 20)`` or ``raw, no enhancement``."""
        enh = f"eq. 14 (r_window {self.r_window})" if self.enhance else "no enhancement"
        return f"{self.normalisation.label}, {enh}"

    def seqslam(self, params: SeqSLAMParams) -> SeqSLAMParams:
        """``params`` with this protocol's ``enhance`` and ``r_window``."""
        return dataclasses.replace(params, enhance=self.enhance, r_window=self.r_window)

    def as_dict(self) -> dict[str, Any]:
        """Plain values: ``centre, l2, enhance, r_window, label``."""
        return {"centre": self.normalisation.centre, "l2": self.normalisation.l2,
                "enhance": self.enhance, "r_window": self.r_window, "label": self.label}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MatchingProtocol":
        """Inverse of :meth:`as_dict` (``label`` ignored)."""
        return cls(CodeNormalisation(centre=d["centre"], l2=bool(d["l2"])),
                   enhance=bool(d["enhance"]), r_window=int(d["r_window"]))


def paper_protocol(params: SeqSLAMParams) -> MatchingProtocol:
    """The paper's protocol: raw codes, eq. 14 with the configured (Table I) ``r_window``."""
    return MatchingProtocol(CodeNormalisation("none", False), enhance=True,
                            r_window=params.r_window)


def candidate_protocols(params: SeqSLAMParams, *, centres: Sequence[str], l2: Sequence[bool],
                        enhance_windows: Sequence[int]) -> list[MatchingProtocol]:
    """Every combination of centring, L2 and enhancement (off, or on with each window).

    With the enhancement off, the uniqueness window stays ``params.r_window`` (Table I).
    The paper's protocol is always among the candidates.
    """
    for centre in centres:
        if centre not in CENTRES:
            raise ValueError(f"matching.protocol.centre: expected items of {CENTRES}, got "
                             f"{centre!r}")
    windows = [(False, params.r_window)] + [(True, int(w)) for w in enhance_windows]
    out = [MatchingProtocol(CodeNormalisation(c, bool(n)), enhance=e, r_window=w)
           for c, n, (e, w) in itertools.product(centres, l2, windows)]
    paper = paper_protocol(params)
    return out if paper in out else [paper] + out


def select_protocol(candidates: Sequence[MatchingProtocol],
                    evaluate: Callable[[MatchingProtocol], Sequence[Mapping[str, float]]], *,
                    criterion: str = "recall_at_100p") -> tuple[MatchingProtocol, list[dict]]:
    """The candidate with the best mean ``criterion`` over the validation pairs.

    Parameters
    ----------
    candidates : sequence of MatchingProtocol
    evaluate : callable
        ``evaluate(protocol) -> [metrics of each validation pair]`` (dicts with ``criterion``
        and ``auc_pr``).
    criterion : {"recall_at_100p", "auc_pr"}
        Maximised; ties are broken by the mean ``auc_pr``, then by the candidate order.

    Returns
    -------
    best : MatchingProtocol
    table : list of dict
        One row per candidate: the protocol's fields, ``mean_<metric>`` for both criteria, and
        the per-pair metrics.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"matching.protocol.criterion: expected one of {CRITERIA}, got "
                         f"{criterion!r}")
    if not candidates:
        raise ValueError("candidates: at least one protocol is needed")
    table, keys = [], []
    for protocol in candidates:
        per_pair = [dict(m) for m in evaluate(protocol)]
        if not per_pair:
            raise ValueError("evaluate: returned no validation pair")
        means = {f"mean_{k}": float(np.mean([m[k] for m in per_pair])) for k in CRITERIA}
        table.append({**protocol.as_dict(), **means, "pairs": per_pair})
        keys.append((means[f"mean_{criterion}"], means["mean_auc_pr"]))
    best = max(range(len(candidates)), key=lambda i: (keys[i][0], keys[i][1], -i))
    return candidates[best], table
