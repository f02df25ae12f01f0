"""The CPU kernel pin (cmal_lcd.kernels): one kernel path, so one seed gives one set of weights."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from cmal_lcd.kernels import (NATIVE_ENV, OPENBLAS_ENV, PINNED_KERNELS, cpu_model_name,
                              kernel_path, numpy_simd, pin_cpu_kernels)
from cmal_lcd.models.training import train_model

sys.path.insert(0, str(Path(__file__).parent / "models"))
from model_helpers import CONDITIONS, tiny_config, weather_frames  # noqa: E402

#: sha256 (first 16 hex digits) of every tensor of a 4-step tiny run's model.pt, trained on the
#: pinned path (AVX2 ATen, oneDNN capped at AVX2, MKL_CBWR=AVX2) with torch 2.13.0 CPU, per
#: processor (``/proc/cpuinfo`` model name). The pin does NOT make two processor families agree:
#: the AMD EPYC record (2026-11-30) and the Intel Xeon one (2026-12-02) differ, under the same
#: pin, torch and code (docs/reliability.md). Each record catches a change of training's numerics
#: on its own processor. When the numerics change on purpose, record the new digest of every
#: processor you can run on and drop the others (their test then skips, saying so).
WEIGHT_FINGERPRINTS = {
    "AMD EPYC": {"cmal": "46e2f775828028eb", "bigan": "f18e88d621ee037a"},
    "Intel(R) Xeon(R) Processor": {"cmal": "b0d3bdc89a59531b", "bigan": "6f5eb7c83a45a889"},
}


def test_the_pin_fills_in_every_variable_of_an_empty_environment():
    environ: dict[str, str] = {}
    assert pin_cpu_kernels(environ, flags=set()) == PINNED_KERNELS
    assert environ == PINNED_KERNELS


def test_openblas_is_pinned_to_its_haswell_kernels_only_where_the_processor_has_them():
    with_avx2: dict[str, str] = {}
    pinned = pin_cpu_kernels(with_avx2, flags={"sse4_2", "avx", "avx2", "fma", "avx512f"})
    assert pinned[OPENBLAS_ENV] == with_avx2[OPENBLAS_ENV] == "Haswell"
    without: dict[str, str] = {}
    assert OPENBLAS_ENV not in pin_cpu_kernels(without, flags={"sse4_2", "avx"})
    assert OPENBLAS_ENV not in without


def test_a_variable_the_user_set_is_kept():
    environ = {"MKL_CBWR": "COMPATIBLE", OPENBLAS_ENV: "Zen"}
    pinned = pin_cpu_kernels(environ, flags={"avx2", "fma"})
    assert environ[OPENBLAS_ENV] == pinned[OPENBLAS_ENV] == "Zen"
    assert environ["MKL_CBWR"] == "COMPATIBLE" and pinned["MKL_CBWR"] == "COMPATIBLE"
    assert environ["ATEN_CPU_CAPABILITY"] == PINNED_KERNELS["ATEN_CPU_CAPABILITY"]


def test_native_kernels_switch_the_pin_off():
    environ = {NATIVE_ENV: "1"}
    assert pin_cpu_kernels(environ) == {}
    assert environ == {NATIVE_ENV: "1"}


def test_importing_the_package_pins_this_process_and_the_record_says_so():
    path = kernel_path()
    for key, value in PINNED_KERNELS.items():
        assert path[key] == value, f"{key} was set before cmal_lcd was imported"
    assert path["aten_capability"] == "AVX2"
    assert path["cpu"] == cpu_model_name() != ""


def _avx512(targets: list[str]) -> list[str]:
    """The AVX-512 targets among NumPy's active SIMD targets."""
    return [t for t in targets if t == "X86_V4" or t.startswith("AVX512")]


def test_numpy_runs_no_avx512_loop_in_a_process_that_imports_the_package_first():
    """NumPy reads its switch once, when imported: pytest loads ``cmal_lcd`` before any plugin
    imports NumPy (``-p cmal_lcd`` in pyproject.toml), as every stage (``python -m
    cmal_lcd.stages...``) does."""
    targets = numpy_simd().split()
    assert targets and "unknown" not in targets
    assert not _avx512(targets), targets


def _simd_of_a_fresh_process(code: str) -> list[str]:
    """``numpy_simd()`` printed by a new interpreter running ``code`` first, without the
    NumPy switch in its inherited environment."""
    code = ("import os; os.environ.pop('NPY_DISABLE_CPU_FEATURES', None); " + code +
            "; from cmal_lcd.kernels import numpy_simd; print(numpy_simd())")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.split()


def test_the_numpy_pin_holds_when_the_package_comes_first_and_the_record_tells_otherwise():
    imported_first = _simd_of_a_fresh_process("import numpy, cmal_lcd")
    if not _avx512(imported_first):
        pytest.skip("this processor has no AVX-512: NumPy runs the same loops either way")
    assert not _avx512(_simd_of_a_fresh_process("import cmal_lcd, numpy"))


def _weights_digest(model_file: Path) -> str:
    state = torch.load(model_file, weights_only=True)["state_dict"]
    digest = hashlib.sha256()
    for key in sorted(state):
        digest.update(key.encode())
        digest.update(state[key].detach().contiguous().numpy().tobytes())
    return digest.hexdigest()[:16]


@pytest.mark.parametrize("name", ["cmal", "bigan"])
def test_a_tiny_run_trains_the_recorded_weights(tmp_path, name):
    """Same seed, same data, same processor: the weights of that processor's fingerprint.

    Fails when training's numerics change (then record the new digests in the same commit,
    and re-run the pipeline) or when this processor takes another kernel path than when its
    digest was recorded.
    """
    if torch.backends.cpu.get_cpu_capability() not in ("AVX2", "AVX512"):
        pytest.skip("this processor has no AVX2; it cannot take the pinned kernel path")
    cpu = cpu_model_name()
    if cpu not in WEIGHT_FINGERPRINTS:
        pytest.skip(f"no weight fingerprint recorded for the processor {cpu!r} (recorded: "
                    f"{', '.join(WEIGHT_FINGERPRINTS)}); weights differ across processor families")
    images, labels = weather_frames(32, size=32)
    cfg = tiny_config(name, image_size=32, width=8, iterations=4, batch_size=16)
    model_file = train_model(name, cfg, images, labels, conditions=CONDITIONS,
                             out_dir=tmp_path / "model", checkpoint_dir=tmp_path / "ckpt", seed=0)
    assert _weights_digest(model_file) == WEIGHT_FINGERPRINTS[cpu][name]
