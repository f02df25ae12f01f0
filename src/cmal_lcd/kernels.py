"""One CPU kernel path on every x86 machine, so that the same seed trains the same weights.

torch picks its CPU kernels by what the processor offers: ATen's vectorised loops (AVX2 or
AVX-512), oneDNN's convolutions (its highest instruction set) and MKL's BLAS (a code path per
processor family, and without conditional numerical reproducibility a threading- and
alignment-dependent summation order). Each choice changes the low bits of every step, and over
hundreds of training steps the weights part ways: two machines of the same kind trained
different CMAL weights from byte-identical data (issue 12). Measured on the development machine
(AMD EPYC, AVX2, no AVX-512), a 6-step tiny run changed its weights under each one of
``ATEN_CPU_CAPABILITY=default``, ``ONEDNN_MAX_CPU_ISA=SSE41`` and any ``MKL_CBWR``.

:func:`pin_cpu_kernels` caps all three at AVX2, the newest instruction set every machine of
this kind has. It sets environment variables, which torch reads when it first dispatches a
kernel, so it runs when ``cmal_lcd`` is imported, before any model code imports torch. A user
who sets a variable keeps it (``setdefault``); ``CMAL_LCD_NATIVE_KERNELS=1`` turns the pin off
(faster on AVX-512 machines, not reproducible across processor families).
Processors without AVX2 cannot take this path; they run their own kernels, and
:func:`kernel_path` records what was used beside every trained model.
"""

from __future__ import annotations

import os

#: The pinned kernel path: ATen, oneDNN and MKL (conditional numerical reproducibility) at AVX2.
PINNED_KERNELS = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "MKL_CBWR": "AVX2",
}

#: Set to 1 to let torch choose its kernels by processor (not reproducible across machines).
NATIVE_ENV = "CMAL_LCD_NATIVE_KERNELS"


def pin_cpu_kernels(environ: dict | None = None) -> dict[str, str]:
    """Set the variables of :data:`PINNED_KERNELS` unless the user set them; return the result.

    Parameters
    ----------
    environ : mapping, optional
        The environment to change (default ``os.environ``).
    """
    environ = os.environ if environ is None else environ
    if environ.get(NATIVE_ENV, "0") not in ("", "0"):
        return {}
    return {key: environ.setdefault(key, value) for key, value in PINNED_KERNELS.items()}


def kernel_path() -> dict[str, str]:
    """What torch actually uses: ATen's capability and the three variables, for a model's record."""
    import torch

    return {"aten_capability": torch.backends.cpu.get_cpu_capability(),
            **{key: os.environ.get(key, "") for key in PINNED_KERNELS}}
