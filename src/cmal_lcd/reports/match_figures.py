"""The figures of ``cmal-lcd match``: ``pr_curve.png`` and ``difference_matrices.png``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported lazily at run time
    import numpy as np

    from cmal_lcd.evaluation.chosen_protocol import ChosenProtocol
    from cmal_lcd.matching import SeqSLAMParams



#: Largest side of the matrices drawn in ``difference_matrices.png`` (every k-th frame): each
#: panel is about 550 pixels wide at 150 dpi, so more rows only cost drawing time.
DISPLAY_SIDE = 600


def write_figures(folder: Path, evaluation, ref_features, query_features, *, metric: str,
                  params: SeqSLAMParams, chosen: ChosenProtocol, train_means, label: str,
                  reference_dir, query_dir, reference_sequences=None) -> None:
    """``pr_curve.png`` and ``difference_matrices.png`` (paper Fig. 6) into ``folder``.

    ``ref_features (R, F)`` and ``query_features (Q, F)`` as extracted; ``params`` the
    effective ones (the protocol's enhancement); ``reference_sequences (R,)`` when the
    reference holds several sequences. The matrices are those of every k-th frame
    (kept by the search, else :func:`figure_matrices`), the overlays every query's match and
    true place.
    """
    from cmal_lcd.reports import plots

    plots.plot_pr_curves({f"{label} + SeqSLAM": (evaluation.recall, evaluation.precision)},
                         path=folder / "pr_curve.png",
                         title=f"{Path(reference_dir).name} (reference) vs "
                               f"{Path(query_dir).name} (query)")
    n_ref, n_query = len(ref_features), len(query_features)
    result = evaluation.result
    if result.D is not None:
        k = max(1, -(-max(n_ref, n_query) // DISPLAY_SIDE))
        D, D_hat = result.D[::k, ::k], result.D_hat[::k, ::k]
    else:
        from cmal_lcd.matching.normalise import normalise_pair

        ref, qry = normalise_pair(ref_features, query_features, chosen.protocol.normalisation,
                                  train_means=train_means)
        D, D_hat, k = figure_matrices(ref, qry, metric=metric, params=params,
                                      reference_sequences=reference_sequences)
    truth = evaluation.truth
    if hasattr(truth, "nearest_right"):  # ReferenceSets: the right row nearest the match
        truth = truth.nearest_right(result.match)
    plots.plot_difference_matrices(
        D, D_hat, path=folder / "difference_matrices.png", frames=(n_ref, n_query),
        match=result.match, truth=truth,
        title=f"{label}: {n_ref} reference x {n_query} query frames"
              + (f" (one frame in {k} shown)" if k > 1 else ""),
        labels=("difference matrix D (eq. 13)",
                "enhanced matrix D_hat (eq. 14)" if params.enhance else
                "D as searched (no enhancement)"))


def figure_matrices(reference: np.ndarray, query: np.ndarray, *, metric: str,
                    params: SeqSLAMParams, side: int | None = None, reference_sequences=None
                    ) -> tuple[np.ndarray, np.ndarray, int]:
    """``D`` and ``D_hat`` of every k-th reference and query frame, for the figure.

    Parameters
    ----------
    reference : ndarray (R, F)
    query : ndarray (Q, F)
        Normalised features (as matched).
    metric : str
    params : SeqSLAMParams
        Effective parameters (``enhancement_window``).
    side : int, optional
        At most this many rows and columns (default :data:`DISPLAY_SIDE`).
    reference_sequences : ndarray (R,), optional
        Sequence numbers of the reference rows (enhancement windows stop at their bounds).

    Returns
    -------
    D, D_hat : ndarray, float32 (ceil(R / k), ceil(Q / k))
        ``D[::k, ::k]`` and ``D_hat[::k, ::k]`` of the full matrices (``D_hat`` up to one
        constant: eq. 14's shift to values >= 0 is the minimum over the kept columns). Eq. 14
        works down each query's column, so it runs on every reference row of the kept
        columns; the full ``R x Q`` matrices are never held.
    k : int
        ``ceil(max(R, Q) / side)``.
    """
    from cmal_lcd.matching import difference_matrix, enhance_contrast

    side = DISPLAY_SIDE if side is None else side
    k = max(1, -(-max(len(reference), len(query)) // side))
    columns = difference_matrix(reference, query[::k], metric=metric)
    enhanced = enhance_contrast(columns, r_window=params.enhancement_window,
                                reference_sequences=reference_sequences)
    return columns[::k], enhanced[::k], k
