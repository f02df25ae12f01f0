"""The training loop shared by every model: batches, logs, samples, checkpoints, resume.

:func:`train_model` takes plain arrays (frames and their weather labels) and writes, under
``out_dir``:

- ``model.pt``: ``{"name", "config", "conditions", "image_size", "state_dict", "iteration",
  "trained_iterations", "selection", "seed", "kernels"}`` (read back by
  :func:`cmal_lcd.models.load_trained`). ``state_dict`` holds the weights of ``iteration``:
  with ``select: best_validation`` the validated iteration that scored best on the validation
  drives (:class:`BestWeights`; the run still trains all ``trained_iterations``), with
  ``select: last`` the last one. ``kernels``: the CPU kernel path,
  :func:`cmal_lcd.kernels.kernel_path`;
- ``selection.json``: the ``selection`` record (:func:`selection_record`): which iteration was
  kept, its validation score, the last iteration's, and why;
- ``train_log.csv``: ``iteration`` + one column per logged key (``D/...``, ``G/...``,
  ``E/...``, ``C/...``), rewritten atomically at every logged iteration;
- ``dvclive/``: the same rows and the config through DVC's logger (:mod:`cmal_lcd.models.live`),
  rewritten at every checkpoint;
- ``samples/iter_XXXXXX.png``: sample grids of a fixed batch (``iter_000000`` = untrained);
- ``checkpoints/last.pt`` (or ``checkpoint_dir/last.pt``): the resume state.

Reproducibility and robustness
------------------------------
- Everything random in iteration ``k`` (which frames, the other condition of each frame, the
  noise, drawn from the model's prior ``N(0, prior_std^2 I)``) is drawn from generators seeded
  by ``(seed, k)``; the networks' initial weights come from ``torch.manual_seed(seed)``. With
  the model and optimiser states (and the global torch RNG, used by dropout and CMAL's extra
  critic steps) restored, a resumed run therefore computes exactly what an uninterrupted one
  does (CPU, same threads).
- A checkpoint is written atomically every ``checkpoint_every`` iterations and at the end. It
  carries a fingerprint of the config (without ``iterations`` and the logging cadence), the
  seed, the conditions and the training data; a run resumes only when the fingerprint
  matches, and otherwise starts afresh and says so. Raising ``iterations`` continues a
  finished run (no learning-rate schedule depends on it).
- A NaN or infinite loss raises :class:`TrainingDivergedError` naming the loss and the
  iteration; nothing is written after the last good checkpoint.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import logging
import math
import os
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np
import torch

from cmal_lcd.io import atomic_path, atomic_write_bytes, atomic_write_json, atomic_write_text
from cmal_lcd.kernels import kernel_path
from cmal_lcd.models.base import GANModel, TrainingBatch
from cmal_lcd.models.config import PRECISIONS, TrainingConfig, model_config
from cmal_lcd.kernels import PINNED_KERNELS
from cmal_lcd.models.device import pick_device
from cmal_lcd.models.images import preprocess, to_uint8
from cmal_lcd.models.live import write_live_log
from cmal_lcd.models.places import draw_positives, place_positives
from cmal_lcd.models.samples import image_grid, png_bytes

logger = logging.getLogger(__name__)

#: oneDNN's instruction-set cap, which the kernel pin sets (:mod:`cmal_lcd.kernels`).
ONEDNN_ISA_ENV = "ONEDNN_MAX_CPU_ISA"
#: The ``train_log.csv`` column that ``best_validation`` maximises.
SELECTION_CRITERION = "val/recall_at_100p"
#: Keys that do not change what is computed, left out of the resume fingerprint.
CADENCE_KEYS = ("iterations", "checkpoint_every", "log_every", "sample_every", "validate_every",
                "select")
#: Held-out frames scored at each logged iteration (a fixed subset, to bound the cost).
HELDOUT_EVAL_FRAMES = 512
CHECKPOINT_FORMAT = 1

# Independent random streams derived from the seed: numpy.random.default_rng([seed, stream, ...]).
_STREAM_BATCH, _STREAM_HELDOUT, _STREAM_SAMPLES, _STREAM_EVAL, _STREAM_PLACE = 0, 1, 2, 3, 4


class TrainingDivergedError(RuntimeError):
    """A loss became NaN or infinite; the last good checkpoint is kept."""


def compile_modules(model: torch.nn.Module, backend: str | None) -> list[str]:
    """Compile each of ``model``'s child modules in place (``nn.Module.compile``, so the
    ``state_dict`` keys and ``model.pt`` stay those of eager) with ``backend``; returns the
    names compiled. A child holding a parametrised module (spectral norm, whose power iteration
    updates its vectors in place during the forward, which a compiled backward refuses) stays
    eager. ``backend`` None: nothing is compiled."""
    from torch.nn.utils import parametrize

    if backend is None:
        return []
    compiled = []
    for name, child in model.named_children():
        if any(parametrize.is_parametrized(m) for m in child.modules()):
            continue
        child.compile(backend=backend)
        compiled.append(name)
    return compiled


def step_precision(precision: str, device: str) -> contextlib.AbstractContextManager:
    """The context a training step runs in: nothing for ``float32``, ``torch.autocast`` in
    bfloat16 on ``device``'s type for ``bfloat16`` (:data:`PRECISIONS`)."""
    if precision == "float32":
        return contextlib.nullcontext()
    if precision == "bfloat16":
        return torch.autocast(device_type=torch.device(device).type, dtype=torch.bfloat16)
    raise ValueError(f"precision: expected one of {list(PRECISIONS)}, got {precision!r}")


def heldout_split(n_frames: int, *, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Split frame indices into training and held-out sets, reproducibly.

    Parameters
    ----------
    n_frames : int
    fraction : float
        Share of frames held out, rounded; at least one frame when ``fraction > 0``, and at
        least one frame is always left for training.
    seed : int

    Returns
    -------
    train, heldout : ndarray, int64
        Sorted, disjoint, together ``range(n_frames)``.
    """
    if n_frames < 2 and fraction > 0:
        raise ValueError(f"n_frames: need at least 2 frames to hold some out, got {n_frames}")
    n_heldout = 0 if fraction <= 0 else min(max(1, round(fraction * n_frames)), n_frames - 1)
    perm = np.random.default_rng([seed, _STREAM_HELDOUT]).permutation(n_frames)
    return np.sort(perm[n_heldout:]).astype(np.int64), np.sort(perm[:n_heldout]).astype(np.int64)


def iteration_draws(iteration: int, *, seed: int, labels: np.ndarray, batch_size: int,
                    n_conditions: int) -> tuple[np.ndarray, np.ndarray, int]:
    """What iteration ``iteration`` trains on, from ``(seed, iteration)`` alone.

    Parameters
    ----------
    labels : ndarray, int64, shape (M,)
        Labels of the training frames.

    Returns
    -------
    positions : ndarray, int64, shape (B,)
        Sorted positions into the training frames, ``B = min(batch_size, M)``, no repeats.
    target : ndarray, int64, shape (B,)
        For each frame, another condition drawn uniformly (its own when only one exists).
    noise_seed : int
        Seed of the torch generator for this iteration's noise.
    """
    rng = np.random.default_rng([seed, _STREAM_BATCH, iteration])
    positions = np.sort(rng.choice(len(labels), size=min(batch_size, len(labels)),
                                   replace=False)).astype(np.int64)
    condition = labels[positions]
    if n_conditions > 1:
        target = (condition + rng.integers(1, n_conditions, size=len(positions))) % n_conditions
    else:
        target = condition.copy()
    return positions, target.astype(np.int64), int(rng.integers(2**62))


def seeded_noise(n: int, code_dim: int, *, seed: int, std: float = 1.0) -> torch.Tensor:
    """Prior codes ``(n, code_dim)`` float32, ``N(0, std^2)`` per entry, from a CPU generator
    seeded ``seed`` (``std`` is the model's ``prior_std``; 1.0 leaves the draws untouched)."""
    generator = torch.Generator(device="cpu").manual_seed(seed)
    noise = torch.randn(n, code_dim, generator=generator)
    return noise if std == 1.0 else noise * float(std)


def fixed_sample_positions(labels: np.ndarray, *, count: int, seed: int) -> np.ndarray:
    """A fixed set of ``count`` frames for sample grids, spread over the conditions.

    Conditions are visited round-robin, a random frame of each; the result is sorted by
    condition so that grids read left to right by weather.

    Returns
    -------
    ndarray, int64, shape (min(count, len(labels)),)
        Positions into ``labels``.
    """
    rng = np.random.default_rng([seed, _STREAM_SAMPLES])
    pools = [list(rng.permutation(np.flatnonzero(labels == k))) for k in np.unique(labels)]
    chosen: list[int] = []
    while len(chosen) < min(count, len(labels)):
        for pool in pools:
            if pool and len(chosen) < count:
                chosen.append(int(pool.pop()))
    chosen_arr = np.asarray(chosen, dtype=np.int64)
    return chosen_arr[np.argsort(labels[chosen_arr], kind="stable")]


def _plain(cfg: Any) -> Any:
    """A config node (OmegaConf or mapping) as plain Python containers."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(cfg, (DictConfig, ListConfig)):
            return OmegaConf.to_container(cfg, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        pass
    if isinstance(cfg, Mapping):
        return {str(k): _plain(v) for k, v in cfg.items()}
    if isinstance(cfg, (list, tuple)):
        return [_plain(v) for v in cfg]
    return cfg


def data_fingerprint(images: np.ndarray, labels: np.ndarray) -> str:
    """SHA-256 of the frames (shape, dtype, bytes) and labels, read in chunks."""
    digest = hashlib.sha256()
    digest.update(repr((images.shape, str(images.dtype))).encode())
    for start in range(0, len(images), 1024):
        digest.update(np.ascontiguousarray(images[start:start + 1024]).tobytes())
    digest.update(np.ascontiguousarray(labels, dtype=np.int64).tobytes())
    return digest.hexdigest()


def config_fingerprint(name: str, cfg: Mapping[str, Any], *, seed: int,
                       conditions: Sequence[str], data: str) -> str:
    """Fingerprint of what determines the trained weights (not the cadence keys)."""
    relevant = {k: v for k, v in _plain(cfg).items() if k not in CADENCE_KEYS}
    text = json.dumps({"name": name, "config": relevant, "seed": int(seed),
                       "conditions": list(conditions), "data": data,
                       "format": CHECKPOINT_FORMAT}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


@contextlib.contextmanager
def torch_runtime(*, threads: int, deterministic: bool) -> Iterator[None]:
    """Set torch's intra-op threads and deterministic mode; restore both afterwards."""
    if int(threads) < 1:
        raise ValueError(f"threads: expected >= 1, got {threads}")
    old_threads = torch.get_num_threads()
    old_det = torch.are_deterministic_algorithms_enabled()
    torch.set_num_threads(int(threads))
    torch.use_deterministic_algorithms(deterministic)
    try:
        yield
    finally:
        torch.set_num_threads(old_threads)
        torch.use_deterministic_algorithms(old_det)


@dataclass
class BestWeights:
    """The validated weights with the highest :data:`SELECTION_CRITERION` so far (on the CPU)."""

    iteration: int | None = None
    score: float = -math.inf
    state: dict[str, torch.Tensor] | None = None

    def offer(self, iteration: int, logs: Mapping[str, float], model: torch.nn.Module) -> bool:
        """Keep ``model``'s weights if ``logs`` beats the best score (iteration 0 never does)."""
        score = logs.get(SELECTION_CRITERION)
        if iteration == 0 or score is None or not math.isfinite(score) or score <= self.score:
            return False
        self.iteration, self.score = iteration, float(score)
        self.state = {k: v.detach().to("cpu", copy=True) for k, v in model.state_dict().items()}
        return True

    def as_checkpoint(self) -> dict[str, Any]:
        return {"iteration": self.iteration, "score": self.score, "state": self.state}

    @classmethod
    def from_checkpoint(cls, saved: Mapping[str, Any] | None) -> "BestWeights":
        return cls(**saved) if saved else cls()


def selection_record(settings: TrainingConfig, best: BestWeights,
                     rows: Sequence[Mapping[str, float]]) -> dict[str, Any]:
    """What ``model.pt`` holds and why: ``select``, ``criterion``, ``iteration`` (of the kept
    weights), ``score`` (its criterion value, ``None`` if never validated), ``trained_iterations``,
    ``last_score`` and ``note``."""
    last = next((r for r in reversed(rows) if r.get("iteration") == settings.iterations), {})
    last_score = last.get(SELECTION_CRITERION)
    record = {"select": settings.select, "criterion": SELECTION_CRITERION,
              "trained_iterations": settings.iterations,
              "last_score": None if last_score is None else float(last_score)}
    if settings.select == "best_validation" and best.state is not None:
        return {**record, "iteration": best.iteration, "score": best.score,
                "note": "the validated iteration with the highest criterion (earliest on a tie)"}
    validated = any(r.get(SELECTION_CRITERION) is not None and r.get("iteration", 0) > 0
                    for r in rows)
    note = ("the last iteration" if settings.select == "last" else
            "the last iteration: select=best_validation, but the checkpoint this run resumed "
            "from kept no best weights (written before select existed; delete it to retrain)"
            if validated else
            "the last iteration: select=best_validation, but nothing was validated (no "
            "validation drives, or validate_every 0)")
    return {**record, "iteration": settings.iterations, "score": record["last_score"],
            "note": note}


def _kept(checkpoint: Path, last_saved: int | None) -> str:
    if last_saved is None:
        return f"no checkpoint was written yet ({checkpoint})"
    return f"the last good checkpoint is kept: {checkpoint} (iteration {last_saved})"


def check_finite(logs: Mapping[str, float], *, iteration: int, checkpoint: Path,
                 last_saved: int | None) -> None:
    """Raise :class:`TrainingDivergedError` when a logged value is NaN or infinite.

    Parameters
    ----------
    logs : mapping of str to float
        The values of one iteration.
    iteration : int
    checkpoint : Path
        The resume file, named in the message.
    last_saved : int or None
        Iteration of the last checkpoint written (``None``: none yet).
    """
    for key, value in logs.items():
        if not math.isfinite(value):
            raise TrainingDivergedError(
                f"training diverged: loss {key} = {value} at iteration {iteration}; stopped"
                f" without writing model.pt; {_kept(checkpoint, last_saved)}. Lower the"
                " learning rates or change the seed before running again.")


def check_parameters_finite(model: torch.nn.Module, *, iteration: int, checkpoint: Path,
                            last_saved: int | None) -> None:
    """Raise :class:`TrainingDivergedError` when a parameter or buffer is not finite."""
    for key, tensor in model.state_dict().items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise TrainingDivergedError(
                f"training diverged: weights {key} are not finite after iteration {iteration};"
                f" {_kept(checkpoint, last_saved)}.")


def write_train_log(path: Path, rows: Sequence[Mapping[str, float]]) -> Path:
    """Write ``iteration`` + one column per key (sorted) as CSV, atomically."""
    keys = sorted({k for row in rows for k in row if k != "iteration"})
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["iteration", *keys])
    for row in rows:
        writer.writerow([int(row["iteration"]), *[repr(float(row[k])) if k in row else ""
                                                   for k in keys]])
    return atomic_write_text(path, buffer.getvalue())


def save_torch(path: Path, obj: Any) -> Path:
    """``torch.save`` to a temporary file, then rename over ``path``.

    Saved through an open file, not a file name: given a name, ``torch.save`` names the zip
    archive's root folder after it (here the random temporary name), so the same weights gave
    different bytes, and a different DVC hash, on every run.
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        torch.save(obj, fh)
    return Path(path)


def load_checkpoint(path: Path, *, fingerprint: str) -> dict | None:
    """The resume state at ``path`` if it exists and matches ``fingerprint``, else ``None``."""
    if not path.is_file():
        return None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a corrupt file is not fatal: start afresh
        logger.warning("checkpoint %s is unreadable (%s); starting afresh", path, exc)
        return None
    if state.get("fingerprint") != fingerprint:
        logger.warning("checkpoint %s was written for another config, seed or dataset;"
                       " starting afresh", path)
        return None
    return state


def _validate_inputs(images: np.ndarray, labels: np.ndarray, conditions: Sequence[str], *,
                    name: str) -> None:
    from cmal_lcd.models import MODEL_CONFIGS

    conditional = name in MODEL_CONFIGS and MODEL_CONFIGS[name].conditional
    if conditional and len(conditions) < 2:
        raise ValueError(f"conditions: {name} needs at least 2 conditions (it learns by "
                         f"translating between them), got {list(conditions)}")
    if images.dtype != np.uint8 or images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images: expected uint8 (N, H, W, 3), got {images.dtype} {images.shape}")
    if labels.shape != (len(images),):
        raise ValueError(f"labels: expected shape ({len(images)},), got {labels.shape}")
    if len(conditions) < 1:
        raise ValueError("conditions: expected at least one condition name")
    if len(labels) and (labels.min() < 0 or labels.max() >= len(conditions)):
        raise ValueError(f"labels: expected values in [0, {len(conditions)}) (positions in"
                         f" conditions), got [{labels.min()}, {labels.max()}]")
    if conditional:
        counts = np.bincount(labels, minlength=len(conditions))
        empty = [c for c, n in zip(conditions, counts) if n == 0]
        if empty:
            raise ValueError(f"conditions: {empty} have no training frame; {name} learns every "
                             f"listed condition (drop it from the list or add frames)")


def _format_eta(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60}m{seconds % 60:02d}s"


def _checked_inputs(name: str, cfg: Mapping[str, Any], images: np.ndarray, labels: np.ndarray,
                    conditions: Sequence[str]) -> tuple[np.ndarray, np.ndarray, dict[str, Any],
                                                        TrainingConfig]:
    """Validate the arguments; return ``images`` (N, H, W, 3) uint8, ``labels`` (N,) int64, the
    config as plain containers (what ``model.pt`` records) and as the model's checked config
    dataclass (:func:`~cmal_lcd.models.config.model_config`)."""
    images = images if isinstance(images, np.ndarray) else np.asarray(images)
    labels = np.asarray(labels).astype(np.int64)
    _validate_inputs(images, labels, conditions, name=name)
    plain_cfg = _plain(cfg)
    return images, labels, plain_cfg, model_config(name, plain_cfg)


@dataclass(frozen=True)
class _Frames:
    """Which frames a run trains on, scores and draws sample grids from (int64 positions into
    ``images``): ``train_idx`` (M,) with ``train_labels`` (M,), ``heldout_idx`` (H,),
    ``eval_idx`` (E,) scored at logged iterations, ``sample_idx`` (K,) of the sample grids."""

    train_idx: np.ndarray
    train_labels: np.ndarray
    heldout_idx: np.ndarray
    eval_idx: np.ndarray
    sample_idx: np.ndarray


def _split_frames(n_frames: int, labels: np.ndarray, settings: TrainingConfig, *,
                  seed: int) -> _Frames:
    """Split ``range(n_frames)`` (``labels``: (N,) int64) and pick the eval and sample frames."""
    train_idx, heldout_idx = heldout_split(n_frames, fraction=settings.heldout_fraction,
                                           seed=seed)
    train_labels = labels[train_idx]
    eval_pool = heldout_idx if len(heldout_idx) else train_idx
    eval_rng = np.random.default_rng([seed, _STREAM_EVAL])
    eval_idx = np.sort(eval_rng.choice(eval_pool, size=min(HELDOUT_EVAL_FRAMES, len(eval_pool)),
                                       replace=False))
    sample_idx = eval_pool[fixed_sample_positions(labels[eval_pool], count=settings.sample_count,
                                                  seed=seed)]
    return _Frames(train_idx=train_idx, train_labels=train_labels, heldout_idx=heldout_idx,
                   eval_idx=eval_idx, sample_idx=sample_idx)


@dataclass
class _Run:
    """One run's fixed settings and model, and the state a checkpoint saves and restores."""

    name: str
    plain_cfg: dict[str, Any]
    settings: TrainingConfig
    seed: int
    device: str
    n_conditions: int
    out_dir: Path
    checkpoint_path: Path
    fingerprint: str
    model: GANModel
    optimizers: dict[str, torch.optim.Optimizer]
    live_params: dict[str, Any]
    rows: list[dict[str, float]] = field(default_factory=list)
    samples: dict[str, bytes] = field(default_factory=dict)
    start: int = 0
    best: BestWeights = field(default_factory=BestWeights)
    last_saved: int | None = None
    #: per training position, the positions of its place positives (models with a place rule)
    positives: list[np.ndarray] | None = None

    @property
    def samples_dir(self) -> Path:
        return self.out_dir / "samples"


@dataclass(frozen=True)
class _Probes:
    """Fixed inputs: ``eval_x`` (E, 3, S, S) with conditions ``eval_c`` (E,), scored at logged
    iterations; ``sample_x`` (K, 3, S, S), ``sample_c`` (K,), ``sample_noise`` (K, code_dim),
    drawn in every sample grid."""

    eval_x: torch.Tensor
    eval_c: torch.Tensor
    sample_x: torch.Tensor
    sample_c: torch.Tensor
    sample_noise: torch.Tensor


def _new_run(name: str, plain_cfg: dict[str, Any], settings: TrainingConfig, *, seed: int,
             device: str, n_conditions: int, out_dir: Path, checkpoint_path: Path,
             fingerprint: str) -> _Run:
    """Seed torch, build the untrained model on ``device`` and its optimisers."""
    from cmal_lcd.models import build_model

    torch.manual_seed(seed)
    model: GANModel = build_model(name, settings, image_size=settings.image_size,
                                  n_conditions=n_conditions).to(device)
    model.train()
    optimizers = model.make_optimizers()
    compiled = compile_modules(model, settings.compile)
    if compiled:
        logger.info("%s: torch.compile (%s) of %s; the others run eager", name, settings.compile,
                    ", ".join(compiled))
    return _Run(name=name, plain_cfg=plain_cfg, settings=settings, seed=seed, device=device,
                n_conditions=n_conditions, out_dir=out_dir, checkpoint_path=checkpoint_path,
                fingerprint=fingerprint, model=model, optimizers=optimizers,
                live_params={"model": name, "seed": int(seed), **plain_cfg})


def _resume_or_start(run: _Run, frames: _Frames, *, threads: int) -> None:
    """Restore a matching checkpoint (not beyond ``iterations``) or log a fresh start; stale
    sample grids are removed either way."""
    state = load_checkpoint(run.checkpoint_path, fingerprint=run.fingerprint)
    if state is not None and state["iteration"] > run.settings.iterations:
        logger.warning("checkpoint %s is at iteration %d, beyond iterations=%d; starting"
                       " afresh", run.checkpoint_path, state["iteration"],
                       run.settings.iterations)
        state = None
    for stale in run.samples_dir.glob("iter_*.png"):
        stale.unlink()
    if state is not None:
        _restore_checkpoint(run, state)
    else:
        logger.info("%s: training from scratch (seed %d, %d frames, %d held out, device %s,"
                    " %d thread(s), %s)", run.name, run.seed, len(frames.train_idx),
                    len(frames.heldout_idx), run.device, threads, run.settings.precision)
    if run.settings.precision == "bfloat16" and run.device == "cpu" and \
            os.environ.get(ONEDNN_ISA_ENV, "").upper() == PINNED_KERNELS[ONEDNN_ISA_ENV]:
        logger.warning("%s: precision bfloat16 on the CPU under the AVX2 kernel pin: oneDNN "
                       "emulates bfloat16 there, about 10x slower than float32; set "
                       "CMAL_LCD_NATIVE_KERNELS=1 (src/cmal_lcd/kernels.py)", run.name)


def _restore_checkpoint(run: _Run, state: Mapping[str, Any]) -> None:
    """Load weights, optimisers, the torch RNG, rows, samples and best weights from ``state``;
    rewrite its sample grids."""
    run.model.load_state_dict(state["model"])
    for key, opt in run.optimizers.items():
        opt.load_state_dict(state["optimizers"][key])
    torch.set_rng_state(state["torch_rng"])
    run.start, run.rows, run.samples = (state["iteration"], list(state["rows"]),
                                        dict(state["samples"]))
    run.best = BestWeights.from_checkpoint(state.get("best"))
    logger.info("%s: resuming from %s at iteration %d", run.name, run.checkpoint_path, run.start)
    for filename, data in run.samples.items():
        atomic_write_bytes(run.samples_dir / filename, data)
    run.last_saved = run.start


def _fixed_probes(run: _Run, images: np.ndarray, labels: np.ndarray,
                  frames: _Frames) -> _Probes:
    """The eval and sample inputs (``images`` (N, H, W, 3) uint8, ``labels`` (N,)) on the device,
    and the sample noise seeded from ``(seed, samples stream)``."""
    size, device = run.settings.image_size, run.device
    eval_x = preprocess(images[frames.eval_idx], image_size=size).to(device)
    eval_c = torch.from_numpy(labels[frames.eval_idx]).to(device)
    sample_x = preprocess(images[frames.sample_idx], image_size=size).to(device)
    sample_c = torch.from_numpy(labels[frames.sample_idx]).to(device)
    sample_noise_seed = int(np.random.default_rng([run.seed, _STREAM_SAMPLES]).integers(2**62))
    sample_noise = seeded_noise(len(frames.sample_idx), run.model.code_dim,
                                seed=sample_noise_seed, std=run.model.prior_std).to(device)
    return _Probes(eval_x=eval_x, eval_c=eval_c, sample_x=sample_x, sample_c=sample_c,
                   sample_noise=sample_noise)


def _write_samples(run: _Run, probes: _Probes, iteration: int) -> None:
    """Draw the sample grid of ``iteration`` into ``run.samples`` and ``samples/``."""
    rows_ = [to_uint8(r) for r in run.model.sample_rows(probes.sample_x, probes.sample_c,
                                                        probes.sample_noise)]
    filename = f"iter_{iteration:06d}.png"
    run.samples[filename] = png_bytes(image_grid(rows_))
    atomic_write_bytes(run.samples_dir / filename, run.samples[filename])


def _save_state(run: _Run, iteration: int) -> None:
    """Check the weights are finite, write the resume checkpoint and the DVC live log."""
    check_parameters_finite(run.model, iteration=iteration, checkpoint=run.checkpoint_path,
                            last_saved=run.last_saved)
    save_torch(run.checkpoint_path, {
        "format": CHECKPOINT_FORMAT, "fingerprint": run.fingerprint, "iteration": iteration,
        "model": run.model.state_dict(),
        "optimizers": {k: opt.state_dict() for k, opt in run.optimizers.items()},
        "torch_rng": torch.get_rng_state(), "rows": run.rows, "samples": run.samples,
        "best": run.best.as_checkpoint()})
    run.last_saved = iteration
    write_live_log(run.out_dir, run.rows, run.live_params)


def _write_samples_and_checkpoint(run: _Run, probes: _Probes, iteration: int, *,
                                  last: bool) -> None:
    """The sample grid and the checkpoint, when ``iteration`` is due for them (or the last)."""
    if iteration % run.settings.sample_every == 0 or last:
        _write_samples(run, probes, iteration)
    if iteration % run.settings.checkpoint_every == 0 or last:
        _save_state(run, iteration)


def _record_untrained(run: _Run, probes: _Probes,
                      validator: Callable[[GANModel], dict[str, float]] | None) -> None:
    """Iteration 0: the untrained sample grid and, when validating, its monitor row."""
    _write_samples(run, probes, 0)
    if validator is not None:
        run.rows.append({"iteration": 0, **validator(run.model)})
        write_train_log(run.out_dir / "train_log.csv", run.rows)


def _training_batch(run: _Run, iteration: int, images: np.ndarray,
                    frames: _Frames) -> TrainingBatch:
    """Iteration ``iteration``'s batch on the device: ``x`` (B, 3, S, S), ``condition`` and
    ``target`` (B,), prior ``noise`` (B, code_dim); all drawn from ``(seed, iteration)``."""
    positions, target, noise_seed = iteration_draws(
        iteration, seed=run.seed, labels=frames.train_labels,
        batch_size=run.settings.batch_size, n_conditions=run.n_conditions)
    batch_frames = images[frames.train_idx[positions]]
    batch = TrainingBatch(
        x=preprocess(batch_frames, image_size=run.settings.image_size).to(run.device),
        condition=torch.from_numpy(frames.train_labels[positions]).to(run.device),
        target=torch.from_numpy(target).to(run.device),
        noise=seeded_noise(len(positions), run.model.code_dim, seed=noise_seed,
                           std=run.model.prior_std).to(run.device))
    if run.positives is None:
        return batch
    rng = np.random.default_rng([run.seed, _STREAM_PLACE, iteration])
    partner, has = draw_positives(run.positives, positions, rng)
    return replace(batch, positive=preprocess(images[frames.train_idx[partner]],
                                              image_size=run.settings.image_size).to(run.device),
                   positive_condition=torch.from_numpy(frames.train_labels[partner]).to(run.device),
                   has_positive=torch.from_numpy(has).to(run.device))


def _place_positives(run: _Run, poses: np.ndarray | None, frames: _Frames) -> None:
    """For a model with a place rule: each training frame's place positives into
    ``run.positives``, and the poses into ``run.fingerprint`` (they shape the weights)."""
    rule = run.model.place_rule
    if rule is None:
        return
    where = f"models.{run.name}.place"
    if poses is None:
        raise ValueError(f"{where}: the place term needs the training frames' poses "
                         f"(frames.csv x, y, heading)")
    poses = np.asarray(poses, dtype=np.float64)
    n_frames = len(frames.train_idx) + len(frames.heldout_idx)
    if poses.shape != (n_frames, 3):
        raise ValueError(f"poses: expected shape ({n_frames}, 3) (x, y, heading per frame), "
                         f"got {poses.shape}")
    run.positives = place_positives(poses[frames.train_idx], frames.train_labels, rule)
    share = float(np.mean([len(p) > 0 for p in run.positives])) if run.positives else 0.0
    if share == 0.0:
        raise ValueError(f"{where}: no training frame has a frame of another condition within "
                         f"radius {rule.radius:g} and {rule.heading_deg:g} degrees (do the "
                         f"training frames have poses, frames.csv x, y?)")
    logger.info("%s: %.1f%% of the training frames have a place positive (radius %g, heading "
                "%g deg)", run.name, 100 * share, rule.radius, rule.heading_deg)
    run.fingerprint = hashlib.sha256(run.fingerprint.encode() + poses.tobytes()).hexdigest()


def _train_step(run: _Run, iteration: int, images: np.ndarray, frames: _Frames, *,
                diagnostics: bool) -> dict[str, float]:
    """One update of every player on iteration ``iteration``'s batch; its finite losses."""
    batch = _training_batch(run, iteration, images, frames)
    with step_precision(run.settings.precision, run.device):
        logs = run.model.training_step(batch, run.optimizers, diagnostics=diagnostics)
    check_finite(logs, iteration=iteration, checkpoint=run.checkpoint_path,
                 last_saved=run.last_saved)
    return logs


def _log_iteration(run: _Run, iteration: int, logs: dict[str, float], probes: _Probes,
                   validator: Callable[[GANModel], dict[str, float]] | None, *,
                   last: bool) -> None:
    """Add held-out metrics to ``logs`` (and, at a validated iteration, the monitor's, offering
    the weights to ``run.best``); append the row and rewrite ``train_log.csv``."""
    logs.update(run.model.heldout_metrics(probes.eval_x, probes.eval_c))
    if validator is not None and (iteration % run.settings.validate_every == 0 or last):
        logs.update(validator(run.model))
        run.best.offer(iteration, logs, run.model)
    run.rows.append({"iteration": iteration, **logs})
    write_train_log(run.out_dir / "train_log.csv", run.rows)


def _report_progress(run: _Run, iteration: int, logs: Mapping[str, float], progress: Any, *,
                     per_it: float) -> None:
    """Show the headline values on the progress bar and log them with s/it and the ETA."""
    eta = per_it * (run.settings.iterations - iteration)
    progress.set_postfix({k: f"{logs[k]:.3g}" for k in _headline(logs)})
    logger.info("%s %d/%d (%.2f s/it, ETA %s): %s", run.name, iteration,
                run.settings.iterations, per_it, _format_eta(eta),
                " ".join(f"{k}={logs[k]:.4g}" for k in _headline(logs)))


def _save_final_model(run: _Run, conditions: Sequence[str]) -> tuple[Path, dict[str, Any]]:
    """Write ``model.pt`` with the selected weights and ``selection.json``; return the path
    and the selection record."""
    settings = run.settings
    if run.start == settings.iterations:  # a finished run: rewrite its logs from the checkpoint
        write_train_log(run.out_dir / "train_log.csv", run.rows)
        write_live_log(run.out_dir, run.rows, run.live_params)
    selection = selection_record(settings, run.best, run.rows)
    if settings.select == "best_validation" and selection["iteration"] != run.best.iteration:
        logger.warning("%s: %s", run.name, selection["note"])
    kept = (run.best.state if selection["iteration"] == run.best.iteration
            else run.model.state_dict())
    model_path = run.out_dir / "model.pt"
    save_torch(model_path, {
        "name": run.name, "config": run.plain_cfg, "conditions": list(conditions),
        "image_size": settings.image_size, "state_dict": kept,
        "iteration": selection["iteration"], "trained_iterations": settings.iterations,
        "selection": selection, "seed": int(run.seed),
        # the processor and CPU kernel path that trained it (cmal_lcd.kernels): same processor,
        # same path, same weights
        "kernels": kernel_path()})
    atomic_write_json(run.out_dir / "selection.json", selection)
    return model_path, selection


def _train_iterations(run: _Run, images: np.ndarray, frames: _Frames, probes: _Probes,
                      validator: Callable[[GANModel], dict[str, float]] | None,
                      callback: Callable[[int, dict[str, float]], None] | None) -> None:
    """Iterations ``run.start + 1 .. iterations``: train each on ``images`` uint8
    (N, H, W, 3); at logged ones log and report; then samples, checkpoint and ``callback``."""
    settings = run.settings
    progress = _progress_bar(total=settings.iterations, initial=run.start, name=run.name)
    t0, done_here = time.perf_counter(), 0
    try:
        for iteration in range(run.start + 1, settings.iterations + 1):
            last = iteration == settings.iterations
            is_log = iteration % settings.log_every == 0 or last
            logs = _train_step(run, iteration, images, frames, diagnostics=is_log)
            done_here += 1
            progress.update(1)
            if is_log:
                _log_iteration(run, iteration, logs, probes, validator, last=last)
                _report_progress(run, iteration, logs, progress,
                                 per_it=(time.perf_counter() - t0) / done_here)
            _write_samples_and_checkpoint(run, probes, iteration, last=last)
            if callback is not None:
                callback(iteration, logs)
    finally:
        progress.close()


def train_model(name: str, cfg: Mapping[str, Any], images: np.ndarray, labels: np.ndarray, *,
                conditions: Sequence[str], out_dir: str | Path, seed: int, threads: int = 1,
                device: str | None = None, checkpoint_dir: str | Path | None = None,
                callback: Callable[[int, dict[str, float]], None] | None = None,
                monitor: Callable[[GANModel], dict[str, float]] | None = None,
                poses: np.ndarray | None = None) -> Path:
    """Train model ``name`` on frames labelled by weather; resume from a checkpoint if any.

    Parameters
    ----------
    name : str
        ``cmal`` or ``bigan``.
    cfg : mapping
        The model's config node (``models.<name>``, see ``conf/model/<name>.yaml``).
    images : ndarray, uint8, shape (N, H, W, 3)
        Training frames (may be memory-mapped); resized to ``cfg.image_size`` per batch.
    labels : ndarray, int, shape (N,)
        Condition index of each frame (its position in ``conditions``).
    conditions : sequence of str
        Condition names, in label order.
    out_dir : path
        Where ``model.pt``, ``train_log.csv`` and ``samples/`` go.
    seed : int
        Seeds the initial weights and every draw of the loop.
    threads : int
        torch intra-op threads (``runtime.threads``).
    device : str, optional
        ``cpu`` or ``cuda``; default :func:`pick_device`.
    checkpoint_dir : path, optional
        Resume state folder; default ``out_dir / "checkpoints"``.
    callback : callable, optional
        ``callback(iteration, logs)`` after each iteration (after its checkpoint, if any).
    monitor : callable, optional
        ``monitor(model) -> {"val/<metric>": value}``, called before the first iteration and
        every ``validate_every`` iterations (and at the last); its values join the logged row
        of ``train_log.csv``. It must not draw random numbers or change the weights (e.g.
        :class:`cmal_lcd.evaluation.monitor.ValidationMonitor`).
    poses : ndarray, float, shape (N, 3), optional
        ``x, y, heading`` of each frame (``frames.csv``): read only by a model with a place
        rule (``GANModel.place_rule``: ``cmal_place``, ``place_encoder``).

    Returns
    -------
    Path
        ``out_dir / "model.pt"``.

    Raises
    ------
    TrainingDivergedError
        When a loss becomes NaN or infinite.
    ValueError
        Naming a bad argument or config key.
    """
    images, labels, plain_cfg, settings = _checked_inputs(name, cfg, images, labels, conditions)
    out_dir = Path(out_dir)
    checkpoint_path = Path(checkpoint_dir or out_dir / "checkpoints") / "last.pt"
    device = device or pick_device()
    frames = _split_frames(len(images), labels, settings, seed=seed)
    fingerprint = config_fingerprint(name, plain_cfg, seed=seed, conditions=conditions,
                                     data=data_fingerprint(images, labels))
    validator = monitor if monitor is not None and settings.validate_every > 0 else None

    # fork_rng: the caller's global torch RNG state is left as it was
    with torch_runtime(threads=threads, deterministic=device == "cpu"), \
            torch.random.fork_rng(devices=[]):
        run = _new_run(name, plain_cfg, settings, seed=seed, device=device,
                       n_conditions=len(conditions), out_dir=out_dir,
                       checkpoint_path=checkpoint_path, fingerprint=fingerprint)
        _place_positives(run, poses, frames)
        _resume_or_start(run, frames, threads=threads)
        probes = _fixed_probes(run, images, labels, frames)
        if run.start == 0:
            _record_untrained(run, probes, validator)
        _train_iterations(run, images, frames, probes, validator, callback)
        model_path, selection = _save_final_model(run, conditions)
    logger.info("%s: wrote %s (weights of iteration %d of %d: %s)", name, model_path,
                selection["iteration"], settings.iterations, selection["note"])
    return model_path


_HEADLINE_KEYS = ("D/loss", "G/adv", "E/recon", "E/recon_heldout", "E/place", "C/acc_heldout",
                  "val/recall_at_100p", "val/single_frame_recall_at_1")


def _headline(logs: Mapping[str, float]) -> list[str]:
    return [k for k in _HEADLINE_KEYS if k in logs]


def _progress_bar(*, total: int, initial: int, name: str):
    """A tqdm bar with ETA on stderr (hidden when stderr is not a terminal)."""
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=f"train {name}", unit="it", file=sys.stderr,
                disable=not sys.stderr.isatty(), dynamic_ncols=True)
