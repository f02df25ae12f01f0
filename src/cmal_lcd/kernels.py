"""One CPU kernel path on every x86 machine, so that the same seed gives the same numbers.

torch picks its CPU kernels by what the processor offers: ATen's vectorised loops (AVX2 or
AVX-512), oneDNN's convolutions (its highest instruction set) and MKL's BLAS (a code path per
processor family, and without conditional numerical reproducibility a threading- and
alignment-dependent summation order). Each choice changes the low bits of every step, and over
hundreds of training steps the weights part ways: two machines of the same kind trained
different CMAL weights from byte-identical data (issue 12). Measured on the development machine
(AMD EPYC, AVX2, no AVX-512), a 6-step tiny run changed its weights under each one of
``ATEN_CPU_CAPABILITY=default``, ``ONEDNN_MAX_CPU_ISA=SSE41`` and any ``MKL_CBWR``.

:func:`pin_cpu_kernels` caps all three at AVX2, the newest instruction set every machine of
this kind has, and NumPy's too: its OpenBLAS at the Haswell (AVX2) kernels where the processor
has them (``OPENBLAS_CORETYPE``: on an Intel Xeon it runs AVX-512 "SkylakeX" kernels, on an
AMD EPYC the AVX2 "Haswell" ones, which sum in another order), and its
run-time SIMD dispatch (``NPY_DISABLE_CPU_FEATURES``: its AVX-512 ``arctan2`` and ``exp``
differ in the last bit from its AVX2 ones, ``sin``, ``cos`` and ``sqrt`` do not; that changed
693 headings (``arctan2``) and 6 positions of the world's ``frames.csv`` on an Intel Xeon, and
so the dataset's hash). It sets environment variables, which torch reads when it first
dispatches a kernel and NumPy when it is imported, so it runs when ``cmal_lcd`` is imported,
before the package imports either;
:func:`kernel_path` says whether NumPy was imported earlier and so escaped the pin. A user
who sets a variable keeps it (``setdefault``); ``CMAL_LCD_NATIVE_KERNELS=1`` turns the pin off
(faster on AVX-512 machines, not reproducible across processor families).
Processors without AVX2 cannot take this path; they run their own kernels, and
:func:`kernel_path` records what was used beside every trained model, the processor included.

The pin is not enough for torch across processor families: on 2026-12-02 an Intel Xeon
(AVX-512) trained other CMAL and BiGAN weights than the AMD EPYC (AVX2) that recorded the
fingerprints of ``tests/test_kernels.py``, under the same pin, torch and code, from
byte-identical frames. Twelve variants of the pin on the Intel machine (``MKL_CBWR`` set to
``AVX2,STRICT``, ``COMPATIBLE``, ``AVX`` or ``SSE4_2``; ``MKL_ENABLE_INSTRUCTIONS=AVX2``;
``ONEDNN_MAX_CPU_ISA`` ``AVX2_VNNI``, ``AVX`` or ``SSE41``; ``ATEN_CPU_CAPABILITY=default``;
oneDNN switched off, alone and with ``MKL_CBWR=COMPATIBLE`` or the default ATen loops) each
gave another digest, none the AMD one. Which kernel differs was not traced (a likely one:
oneDNN's convolutions, which size their blocks, and so their summation order, by the
processor's caches). Same processor, same seed: same weights.
"""

from __future__ import annotations

import os
import platform

#: The pinned kernel path: ATen, oneDNN and MKL (conditional numerical reproducibility) at AVX2.
PINNED_KERNELS = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "MKL_CBWR": "AVX2",
    # every AVX-512 target of NumPy's dispatch (names of NumPy >= 2.4, then of 2.0-2.3; a name
    # NumPy does not know is ignored): NumPy then runs its AVX2 (X86_V3) loops
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX "
                                "AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR",
}

#: NumPy's OpenBLAS kernels, pinned where the processor has :data:`HASWELL_FLAGS`.
OPENBLAS_ENV, OPENBLAS_CORE = "OPENBLAS_CORETYPE", "Haswell"

#: Set to 1 to let torch choose its kernels by processor (not reproducible across machines).
NATIVE_ENV = "CMAL_LCD_NATIVE_KERNELS"


#: Processor flags (``/proc/cpuinfo``) that OpenBLAS's Haswell kernels need.
HASWELL_FLAGS = ("avx2", "fma")


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS tells it, else all): the
    threads that decode frames (``cmal-lcd match``), score SAD in parallel and render the
    weather world."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _cpuinfo(field: str) -> str | None:
    """The value of the first ``field`` line of ``/proc/cpuinfo`` (Linux), else None."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                name, _, value = line.partition(":")
                if name.strip().lower() == field:
                    return value.strip()
    except OSError:
        pass
    return None


def cpu_flags() -> set[str]:
    """The processor's feature flags from ``/proc/cpuinfo`` (empty where there is none)."""
    return set((_cpuinfo("flags") or "").split())


def pin_cpu_kernels(environ: dict | None = None, *, flags: set[str] | None = None
                    ) -> dict[str, str]:
    """Set the variables of :data:`PINNED_KERNELS` unless the user set them; return the result.

    Parameters
    ----------
    environ : mapping, optional
        The environment to change (default ``os.environ``).
    """
    environ = os.environ if environ is None else environ
    if environ.get(NATIVE_ENV, "0") not in ("", "0"):
        return {}
    pinned = {key: environ.setdefault(key, value) for key, value in PINNED_KERNELS.items()}
    # NumPy's OpenBLAS picks its kernels by processor (AVX-512 "SkylakeX" ones on an Intel Xeon,
    # AVX2 "Haswell" ones on an AMD EPYC): pinned only where the Haswell kernels can run, since
    # a forced core type the processor lacks would stop on an illegal instruction.
    if set(HASWELL_FLAGS) <= (cpu_flags() if flags is None else flags):
        pinned[OPENBLAS_ENV] = environ.setdefault(OPENBLAS_ENV, OPENBLAS_CORE)
    return pinned


def cpu_model_name() -> str:
    """The CPU model name from ``/proc/cpuinfo`` (Linux), else :func:`platform.processor`."""
    return (_cpuinfo("model name") or platform.processor() or platform.machine()
            or "unknown cpu")


def numpy_simd() -> str:
    """NumPy's run-time SIMD targets that are on in this process, e.g. ``X86_V3``."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:  # NumPy moved its private module
        return "unknown"
    return " ".join(name for name in __cpu_dispatch__ if __cpu_features__.get(name)) or "none"


def kernel_path() -> dict[str, str]:
    """What this process actually uses, for a model's record: the processor (``cpu``), ATen's
    capability, NumPy's SIMD targets and the pinned variables."""
    import torch

    return {"cpu": cpu_model_name(), "aten_capability": torch.backends.cpu.get_cpu_capability(),
            "numpy_simd": numpy_simd(),
            **{key: os.environ.get(key, "") for key in (*PINNED_KERNELS, OPENBLAS_ENV)}}
