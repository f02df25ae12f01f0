"""SAD on byte-quantised z-scores (``metric="sad_u8"``), summed exactly by packed-byte instructions.

SeqSLAM thumbnails are patch-normalised z-scores. :func:`quantise_z_scores` stores each as one
byte, ``128 + round(16 z)`` clipped to ``0..255``: steps of 1/16 of a standard deviation, and
``|z| <= 127/16 = 7.94`` kept unclipped (the largest z-score an 8 x 8 patch can hold is
``63 / 8 = 7.875``, so the default thumbnails are never clipped). OpenSeqSLAM stores
``127 + round(z)``, steps 16 times coarser.

:func:`sad_byte_rows` computes ``out[q, r] = sum_k |query[q, k] - reference[r, k]| / (16 F)``:
the mean absolute difference in z units. The sums are integers, so every cell is exact and
the same on every CPU, for any chunking or thread count. On x86 CPUs with AVX2 the sums use
``vpsadbw`` (32 byte differences summed per instruction), through an LLVM intrinsic: numba's
own code generation does not find that instruction (a plain numba byte loop is 3-5x slower than
the float32 kernel). Elsewhere a plain loop computes the same integers, slowly.
"""

from __future__ import annotations

import platform

import numpy as np
from llvmlite import binding as llvm_binding
from llvmlite import ir
from numba import config as numba_config
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

#: Quantisation steps per z unit: byte = 128 + round(STEPS_PER_Z * z), clipped to 0..255.
STEPS_PER_Z = 16

#: Rows are zero-padded to a multiple of this many bytes (one AVX2 register); padding adds 0.
ROW_ALIGN = 32

QUERY_ROWS, REFERENCE_ROWS = 4, 2  # micro-kernel: 4 queries x 2 references = 8 sums at once


def has_avx2() -> bool:
    """Whether numba compiles for this machine's CPU and that CPU has AVX2."""
    if platform.machine().lower() not in ("x86_64", "amd64") or numba_config.CPU_NAME:
        return False
    return bool(llvm_binding.get_host_cpu_features().get("avx2", False))


def quantise_z_scores(features: np.ndarray) -> np.ndarray:
    """``uint8 (N, F_pad)``: ``128 + round(16 z)`` clipped to 0..255, rows zero-padded.

    ``features`` is ``(N, F)`` real; ``F_pad`` is ``F`` rounded up to a multiple of
    :data:`ROW_ALIGN` (padding bytes are 0 in every row, so they add nothing to a sum).
    """
    features = np.asarray(features)
    n, f = features.shape
    dtype = features.dtype if features.dtype in (np.float32, np.float64) else np.float64
    scaled = np.multiply(features, STEPS_PER_Z, dtype=dtype)  # exact: a power of two
    np.rint(scaled, out=scaled)
    scaled += 128.0
    np.clip(scaled, 0, 255, out=scaled)
    padded = np.zeros((n, -(-f // ROW_ALIGN) * ROW_ALIGN), dtype=np.uint8)
    padded[:, :f] = scaled
    return padded


@intrinsic
def _vpsadbw_block(typingctx, a, b, i0, i1, i2, i3, j0, j1):  # pragma: no cover - compiled
    """``(s[0] .. s[7])``: ``sum |a[i_p] - b[j_r]|`` for ``p < 4``, ``r < 2`` (``8 int64``)."""
    index = types.intp
    sig = types.UniTuple(types.int64, 8)(a, b, index, index, index, index, index, index)

    def codegen(context, builder, signature, args):
        A = context.make_array(signature.args[0])(context, builder, args[0])
        B = context.make_array(signature.args[1])(context, builder, args[1])
        n_bytes = builder.extract_value(A.shape, 1)
        byte_vec, sum_vec = ir.VectorType(ir.IntType(8), 32), ir.VectorType(ir.IntType(64), 4)
        psadbw = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(sum_vec, [byte_vec, byte_vec]),
            "llvm.x86.avx2.psad.bw")
        queries = [builder.gep(A.data, [builder.mul(i, n_bytes)]) for i in args[2:6]]
        references = [builder.gep(B.data, [builder.mul(j, n_bytes)]) for j in args[6:8]]
        sums = [cgutils.alloca_once_value(builder, ir.Constant(sum_vec, None)) for _ in range(8)]
        step = ir.Constant(n_bytes.type, ROW_ALIGN)

        def load(row, offset):
            pointer = builder.bitcast(builder.gep(row, [offset]), byte_vec.as_pointer())
            return builder.load(pointer, align=1)

        with cgutils.for_range(builder, builder.udiv(n_bytes, step)) as loop:
            offset = builder.mul(loop.index, step)
            ref = [load(row, offset) for row in references]
            for p, row in enumerate(queries):
                q = load(row, offset)
                for r in range(2):
                    acc = sums[2 * p + r]
                    builder.store(builder.add(builder.load(acc), builder.call(psadbw,
                                                                             [q, ref[r]])), acc)
        totals = []
        for acc in sums:
            lanes = builder.load(acc)
            total = builder.extract_element(lanes, ir.Constant(ir.IntType(32), 0))
            for k in range(1, 4):
                total = builder.add(total, builder.extract_element(lanes,
                                                                   ir.Constant(ir.IntType(32), k)))
            totals.append(total)
        return context.make_tuple(builder, signature.return_type, totals)

    return sig, codegen


@njit(cache=True)
def _loop_block(a, b, i0, i1, i2, i3, j0, j1):  # pragma: no cover - compiled
    """The same 8 sums as :func:`_vpsadbw_block`, by a plain loop (CPUs without AVX2)."""
    sums = np.zeros(8, dtype=np.int64)
    for p, i in enumerate((i0, i1, i2, i3)):
        for r, j in enumerate((j0, j1)):
            s = 0
            for k in range(a.shape[1]):
                s += abs(np.int64(a[i, k]) - np.int64(b[j, k]))
            sums[2 * p + r] = s
    return (sums[0], sums[1], sums[2], sums[3], sums[4], sums[5], sums[6], sums[7])


_block_sums = _vpsadbw_block if has_avx2() else _loop_block


@njit(parallel=True, cache=True)
def sad_byte_rows(query, reference, out, block, scale):  # pragma: no cover - compiled
    """``out[q, r] = scale * sum_k |query[q, k] - reference[r, k]|``.

    ``query uint8 (Qc, F_pad)``, ``reference uint8 (R, F_pad)`` (both from
    :func:`quantise_z_scores`), ``out float32 (Qc, R)``, all C-contiguous. Threads take blocks of
    ``block`` reference rows; a 4-query x 2-reference micro-kernel computes 8 sums at once; a
    short last group repeats its last row (integer sums: a cell's value never depends on it).
    """
    n_query, n_ref = query.shape[0], reference.shape[0]
    for b in prange((n_ref + block - 1) // block):
        j_lo = b * block
        j_hi = min(n_ref, j_lo + block)
        for i in range(0, n_query, QUERY_ROWS):
            rows_i = (i, min(i + 1, n_query - 1), min(i + 2, n_query - 1),
                      min(i + 3, n_query - 1))
            for j in range(j_lo, j_hi, REFERENCE_ROWS):
                j1 = min(j + 1, j_hi - 1)
                s = _block_sums(query, reference, rows_i[0], rows_i[1], rows_i[2], rows_i[3],
                                j, j1)
                for p in range(QUERY_ROWS):
                    out[rows_i[p], j] = np.float32(s[2 * p] * scale)
                    out[rows_i[p], j1] = np.float32(s[2 * p + 1] * scale)
