"""Difference matrices between reference and query features.

``D[r, q]``: rows = reference frames, columns = query frames; lower = more alike.

- ``metric="sad"`` (SeqSLAM thumbnails): the mean absolute difference
  ``mean_k |reference[r, k] - query[q, k]|``, computed exactly (no matrix-product trick: that is
  exact only for small integers) by a numba kernel that keeps a block of reference rows in cache
  while the queries stream past, with float32 accumulation (relative error about 1e-6 against a
  float64 loop). Measured on the 2-core development machine: about 21e9 absolute differences
  per second per core, i.e. 1.3 CPU-seconds for 3,600 x 3,600 thumbnails of 2,048 values (about
  0.7 s on two free cores). Alternatives measured and rejected: ``int16``/``uint8`` kernels
  compiled by numba (3-5x slower), the identity ``|a-b| = a + b - 2 min(a, b)`` (no faster, and
  not exact), AVX-512 code generation (slower), a 1 x 4 micro-kernel (1.5x slower).
- ``metric="sad_u8"`` (an option, ``matching.sad.quantise``): the same mean absolute difference
  on z-scores first rounded to steps of 1/16 and stored as bytes, summed exactly in integers by
  packed-byte instructions (``cmal_lcd.matching._sad_bytes``): about 4x faster than ``sad`` on
  AVX2 CPUs, and the same integers on every CPU. Meant for patch-normalised thumbnails (values
  beyond +-7.94 are clipped).
- ``metric="sqeuclidean"`` (codes, paper eq. 13): ``|a|^2 + |b|^2 - 2 a.b`` as one matrix
  product per chunk of queries, **accumulated in float64** and clamped at 0 (rounding can give
  tiny negatives), then stored as float32: near-duplicate codes keep their small distances
  (float32 products would leave an error of about 1e-6 |a|^2 on every cell).
- ``metric="sqeuclidean_f32"`` (an option for large maps, ``cmal-lcd match --float32-codes``):
  the same formula with the product, norms and sums in float32, about twice as fast (the
  product is most of the matching time at 20,000 x 20,000). Cells carry that 1e-6 |a|^2 error
  and can differ in the last bits between BLAS builds; ``benchmarks/README.md`` gives its effect
  on recall and AUC-PR.

Every cell is computed independently of how the queries are chunked for ``sad``; for
``sqeuclidean`` the BLAS product of a chunk may differ from the whole matrix in the last bit of
float64, which the float32 result hides.
"""

from __future__ import annotations

import numpy as np

from cmal_lcd.matching import _kernels, _sad_bytes

#: Accepted values of ``metric``.
METRICS = ("sad", "sad_u8", "sqeuclidean", "sqeuclidean_f32")
#: The metrics of codes (squared Euclidean, eq. 13) by the precision of their product.
CODE_METRICS = {"float64": "sqeuclidean", "float32": "sqeuclidean_f32"}

#: Target size of one chunk's float64 ``(Qc, R)`` working array, bytes. Small enough that the
#: streamed matching stays far below 1 GB at 20,000 x 20,000 and the chunk buffers are recycled.
CHUNK_BYTES = 32 * 2**20


def difference_matrix(reference: np.ndarray, query: np.ndarray, *, metric: str) -> np.ndarray:
    """Difference between every reference and every query feature vector.

    Parameters
    ----------
    reference : numpy.ndarray
        ``(R, F)`` reference features (any real dtype; SAD thumbnails may be ``uint8``).
    query : numpy.ndarray
        ``(Q, F)`` query features.
    metric : {"sad", "sad_u8", "sqeuclidean", "sqeuclidean_f32"}
        Mean absolute difference (thumbnails; ``sad_u8`` on byte-quantised z-scores) or squared
        Euclidean distance (codes, eq. 13; ``sqeuclidean_f32`` computed in float32).

    Returns
    -------
    numpy.ndarray
        ``float32 (R, Q)``, ``D[r, q] >= 0``.

    Raises
    ------
    ValueError
        For an unknown ``metric``, non-2-D inputs, a feature-size mismatch, empty inputs or
        non-finite values.
    """
    op = DifferenceRows(reference, metric=metric)
    query = op.check_query(query)
    out = np.empty((query.shape[0], op.n_reference), dtype=np.float32)
    step = op.chunk_rows()
    for start in range(0, query.shape[0], step):
        out[start:start + step] = op(query[start:start + step])
    return np.ascontiguousarray(out.T)


class DifferenceRows:
    """The difference of a fixed reference set against chunks of queries, query-major.

    ``DifferenceRows(reference, metric=...)(query_chunk)`` returns ``float32 (Qc, R)``: row ``q``
    is column ``q`` of ``D``. Used by :func:`difference_matrix` and by the streaming
    :func:`cmal_lcd.matching.match_sequences`.
    """

    def __init__(self, reference: np.ndarray, *, metric: str) -> None:
        if metric not in METRICS:
            raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
        self.metric = metric
        reference = _check_features(reference, name="reference")
        self.n_reference, self.n_features = reference.shape
        if metric == "sad":
            self._reference = np.ascontiguousarray(reference, dtype=np.float32)
            block = (1024 * 1024) // (4 * self.n_features)  # about half of a 2 MB L2 cache
            block = max(4, min(256, block - block % 4))
            self._block = block
        elif metric == "sad_u8":
            self._reference = _sad_bytes.quantise_z_scores(reference)
            block = (1024 * 1024) // self._reference.shape[1]
            self._block = max(2, min(256, block - block % 2))
            self._scale = 1.0 / (_sad_bytes.STEPS_PER_Z * self.n_features)
        else:
            self._dtype = np.float32 if metric == "sqeuclidean_f32" else np.float64
            self._reference = np.ascontiguousarray(reference, dtype=self._dtype)
            self._norms = np.einsum("ij,ij->i", self._reference, self._reference)

    def check_query(self, query: np.ndarray) -> np.ndarray:
        """Validate ``query (Q, F)`` against the reference; returns it as an array."""
        query = _check_features(query, name="query")
        if query.shape[1] != self.n_features:
            raise ValueError(f"query has {query.shape[1]} features per row but reference has "
                             f"{self.n_features}")
        return query

    def chunk_rows(self) -> int:
        """Queries per chunk so that one chunk's working arrays stay within :data:`CHUNK_BYTES`."""
        return max(1, CHUNK_BYTES // (8 * self.n_reference))

    def __call__(self, query: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
        """``float32 (Qc, R)`` differences of a query chunk (validated by :meth:`check_query`).

        ``out``, when given, is a C-contiguous ``float32 (Qc, R)`` array to write into (the
        streamed matching reuses one buffer for every chunk).
        """
        shape = (query.shape[0], self.n_reference)
        if out is None:
            out = np.empty(shape, dtype=np.float32)
        elif out.shape != shape or out.dtype != np.float32 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous float32 array of shape {shape}")
        if not shape[0]:
            return out
        if self.metric == "sad":
            q = np.ascontiguousarray(query, dtype=np.float32)
            _kernels.sad_rows(q, self._reference, out, self._block)
            return out
        if self.metric == "sad_u8":
            _sad_bytes.sad_byte_rows(_sad_bytes.quantise_z_scores(query), self._reference, out,
                                     self._block, self._scale)
            return out
        q = np.ascontiguousarray(query, dtype=self._dtype)
        # float32: the product is written straight into ``out``; float64: into a working array
        prod = np.matmul(q, self._reference.T, out=out if self._dtype == np.float32 else None)
        prod *= -2.0
        prod += np.einsum("ij,ij->i", q, q)[:, None]
        prod += self._norms[None, :]
        np.maximum(prod, 0.0, out=prod)
        if prod is not out:
            np.copyto(out, prod, casting="same_kind")
        return out


def _check_features(x: np.ndarray, *, name: str) -> np.ndarray:
    """``x`` as a 2-D, non-empty, finite real array, else ``ValueError`` naming ``name``."""
    x = np.asarray(x)
    if x.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (N, F) array, got shape {x.shape}")
    if x.shape[0] < 1 or x.shape[1] < 1:
        raise ValueError(f"{name} must have at least one row and one feature, got shape {x.shape}")
    if not (np.issubdtype(x.dtype, np.floating) or np.issubdtype(x.dtype, np.integer)):
        raise ValueError(f"{name} must be a real-valued array, got dtype {x.dtype}")
    if np.issubdtype(x.dtype, np.floating) and not np.isfinite(x).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return x
