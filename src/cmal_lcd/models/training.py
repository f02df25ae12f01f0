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
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np
import torch

from cmal_lcd.io import atomic_path, atomic_write_bytes, atomic_write_json, atomic_write_text
from cmal_lcd.kernels import kernel_path
from cmal_lcd.models.base import GANModel, TrainingBatch
from cmal_lcd.models.bigan import BIGAN_KEYS, BIGAN_OPTIONAL_KEYS
from cmal_lcd.models.cmal import CMAL_KEYS, CMAL_OPTIONAL_KEYS
from cmal_lcd.models.device import pick_device
from cmal_lcd.models.images import preprocess, to_uint8
from cmal_lcd.models.live import write_live_log
from cmal_lcd.models.samples import image_grid, png_bytes

logger = logging.getLogger(__name__)

#: Training keys every ``conf/model/<name>.yaml`` provides.
TRAINING_KEYS = ("image_size", "iterations", "batch_size", "checkpoint_every", "log_every",
                 "sample_every", "sample_count", "heldout_fraction")
#: Optional training key: score the validation drives every this many iterations (0 = never;
#: needs a ``monitor``, see :mod:`cmal_lcd.evaluation.monitor`).
VALIDATE_KEY = "validate_every"
#: Optional key: which weights ``model.pt`` keeps (:data:`SELECTIONS`; absent = ``last``).
SELECT_KEY = "select"
#: ``best_validation``: the validated iteration (``validate_every`` multiples and the last; never
#: the untrained iteration 0) with the highest :data:`SELECTION_CRITERION`, the earliest on a
#: tie, chosen on the validation drives only; ``last``: the weights after ``iterations``.
SELECTIONS = ("best_validation", "last")
#: The ``train_log.csv`` column that ``best_validation`` maximises.
SELECTION_CRITERION = "val/recall_at_100p"
#: Keys that do not change what is computed, left out of the resume fingerprint.
CADENCE_KEYS = ("iterations", "checkpoint_every", "log_every", "sample_every", VALIDATE_KEY,
                SELECT_KEY)
#: Held-out frames scored at each logged iteration (a fixed subset, to bound the cost).
HELDOUT_EVAL_FRAMES = 512
CHECKPOINT_FORMAT = 1

# Independent random streams derived from the seed: numpy.random.default_rng([seed, stream, ...]).
_STREAM_BATCH, _STREAM_HELDOUT, _STREAM_SAMPLES, _STREAM_EVAL = 0, 1, 2, 3


class TrainingDivergedError(RuntimeError):
    """A loss became NaN or infinite; the last good checkpoint is kept."""


@dataclass(frozen=True)
class TrainingSettings:
    """The loop's settings, read from a model config node."""

    image_size: int
    iterations: int
    batch_size: int
    checkpoint_every: int
    log_every: int
    sample_every: int
    sample_count: int
    heldout_fraction: float
    validate_every: int = 0
    select: str = "last"


#: Every key a model config node may hold, per model (``conf/model/<name>.yaml``).
MODEL_CONFIG_KEYS = {
    "cmal": frozenset({*TRAINING_KEYS, VALIDATE_KEY, SELECT_KEY, *CMAL_KEYS,
                       *CMAL_OPTIONAL_KEYS}),
    "bigan": frozenset({*TRAINING_KEYS, VALIDATE_KEY, SELECT_KEY, *BIGAN_KEYS,
                        *BIGAN_OPTIONAL_KEYS})}


def check_model_keys(cfg: Mapping[str, Any], *, name: str | None = None) -> None:
    """Refuse keys that no model reads (typos such as ``iteration``).

    Parameters
    ----------
    name : str, optional
        Check against this model's keys; default: against the keys of any model.

    Raises
    ------
    ValueError
        Naming the unknown keys and the known ones.
    """
    known = MODEL_CONFIG_KEYS.get(name) if name else frozenset().union(*MODEL_CONFIG_KEYS.values())
    if known is None:
        return
    unknown = sorted(str(k) for k in cfg if k not in known)
    if unknown:
        raise ValueError(f"models.{name or '<name>'}: unknown keys {unknown}; "
                         f"known: {sorted(known)}")


def _positive_int(value: Any, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) \
            or int(value) != value or value < 1:
        raise ValueError(f"{key}: expected a positive integer, got {value!r}")
    return int(value)


def training_settings(cfg: Mapping[str, Any]) -> TrainingSettings:
    """Read and validate the loop's settings from a model config.

    Raises
    ------
    ValueError
        Naming the missing, unknown, mistyped or out-of-range key.
    """
    check_model_keys(cfg)
    values = {}
    for key in TRAINING_KEYS:
        if key not in cfg:
            raise ValueError(f"{key}: missing from the model config")
        values[key] = cfg[key]
    for key in TRAINING_KEYS[:-1]:
        values[key] = _positive_int(values[key], key)
    try:
        fraction = float(values["heldout_fraction"])
    except (TypeError, ValueError):
        raise ValueError(f"heldout_fraction: expected a number in [0, 1), got "
                         f"{values['heldout_fraction']!r}") from None
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"heldout_fraction: expected 0 <= fraction < 1, got {fraction}")
    values["heldout_fraction"] = fraction
    validate_every = cfg.get(VALIDATE_KEY, 0)
    values[VALIDATE_KEY] = 0 if validate_every == 0 else _positive_int(validate_every,
                                                                        VALIDATE_KEY)
    if values[VALIDATE_KEY] % values["log_every"]:
        raise ValueError(f"{VALIDATE_KEY}: expected a multiple of log_every "
                         f"({values['log_every']}), got {values[VALIDATE_KEY]}")
    values[SELECT_KEY] = cfg.get(SELECT_KEY, "last")
    if values[SELECT_KEY] not in SELECTIONS:
        raise ValueError(f"{SELECT_KEY}: expected one of {list(SELECTIONS)}, got "
                         f"{values[SELECT_KEY]!r}")
    return TrainingSettings(**values)


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


def selection_record(settings: TrainingSettings, best: BestWeights,
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
    if name == "cmal" and len(conditions) < 2:
        raise ValueError(f"conditions: CMAL needs at least 2 conditions (it learns by "
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
    if name == "cmal":
        counts = np.bincount(labels, minlength=len(conditions))
        empty = [c for c, n in zip(conditions, counts) if n == 0]
        if empty:
            raise ValueError(f"conditions: {empty} have no training frame; CMAL learns every "
                             f"listed condition (drop it from the list or add frames)")


def _format_eta(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60}m{seconds % 60:02d}s"


def train_model(name: str, cfg: Mapping[str, Any], images: np.ndarray, labels: np.ndarray, *,
                conditions: Sequence[str], out_dir: str | Path, seed: int, threads: int = 1,
                device: str | None = None, checkpoint_dir: str | Path | None = None,
                callback: Callable[[int, dict[str, float]], None] | None = None,
                monitor: Callable[[GANModel], dict[str, float]] | None = None) -> Path:
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
    from cmal_lcd.models import build_model

    images = images if isinstance(images, np.ndarray) else np.asarray(images)
    labels = np.asarray(labels).astype(np.int64)
    _validate_inputs(images, labels, conditions, name=name)
    check_model_keys(_plain(cfg), name=name)
    plain_cfg = _plain(cfg)
    settings = training_settings(plain_cfg)
    out_dir = Path(out_dir)
    checkpoint_path = Path(checkpoint_dir or out_dir / "checkpoints") / "last.pt"
    samples_dir = out_dir / "samples"
    device = device or pick_device()
    n_conditions = len(conditions)

    train_idx, heldout_idx = heldout_split(len(images), fraction=settings.heldout_fraction,
                                           seed=seed)
    train_labels = labels[train_idx]
    eval_pool = heldout_idx if len(heldout_idx) else train_idx
    eval_rng = np.random.default_rng([seed, _STREAM_EVAL])
    eval_idx = np.sort(eval_rng.choice(eval_pool, size=min(HELDOUT_EVAL_FRAMES, len(eval_pool)),
                                       replace=False))
    sample_idx = eval_pool[fixed_sample_positions(labels[eval_pool], count=settings.sample_count,
                                                  seed=seed)]
    fingerprint = config_fingerprint(name, plain_cfg, seed=seed, conditions=conditions,
                                     data=data_fingerprint(images, labels))

    # fork_rng: the caller's global torch RNG state is left as it was
    with torch_runtime(threads=threads, deterministic=device == "cpu"), \
            torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model: GANModel = build_model(name, plain_cfg, image_size=settings.image_size,
                                      n_conditions=n_conditions).to(device)
        model.train()
        optimizers = model.make_optimizers()
        rows: list[dict[str, float]] = []
        samples: dict[str, bytes] = {}
        start = 0
        best = BestWeights()
        state = load_checkpoint(checkpoint_path, fingerprint=fingerprint)
        if state is not None and state["iteration"] > settings.iterations:
            logger.warning("checkpoint %s is at iteration %d, beyond iterations=%d; starting"
                           " afresh", checkpoint_path, state["iteration"], settings.iterations)
            state = None
        for stale in samples_dir.glob("iter_*.png"):
            stale.unlink()
        if state is not None:
            model.load_state_dict(state["model"])
            for key, opt in optimizers.items():
                opt.load_state_dict(state["optimizers"][key])
            torch.set_rng_state(state["torch_rng"])
            start, rows, samples = state["iteration"], list(state["rows"]), dict(state["samples"])
            best = BestWeights.from_checkpoint(state.get("best"))
            logger.info("%s: resuming from %s at iteration %d", name, checkpoint_path, start)
            for filename, data in samples.items():
                atomic_write_bytes(samples_dir / filename, data)
        else:
            logger.info("%s: training from scratch (seed %d, %d frames, %d held out, device %s,"
                        " %d thread(s))", name, seed, len(train_idx), len(heldout_idx), device,
                        threads)

        eval_x = preprocess(images[eval_idx], image_size=settings.image_size).to(device)
        eval_c = torch.from_numpy(labels[eval_idx]).to(device)
        sample_x = preprocess(images[sample_idx], image_size=settings.image_size).to(device)
        sample_c = torch.from_numpy(labels[sample_idx]).to(device)
        sample_noise_seed = int(np.random.default_rng([seed, _STREAM_SAMPLES]).integers(2**62))
        sample_noise = seeded_noise(len(sample_idx), model.code_dim, seed=sample_noise_seed,
                                    std=model.prior_std).to(device)

        def write_samples(iteration: int) -> None:
            rows_ = [to_uint8(r) for r in model.sample_rows(sample_x, sample_c, sample_noise)]
            filename = f"iter_{iteration:06d}.png"
            samples[filename] = png_bytes(image_grid(rows_))
            atomic_write_bytes(samples_dir / filename, samples[filename])

        last_saved = [start if state is not None else None]
        live_params = {"model": name, "seed": int(seed), **plain_cfg}

        def save_state(iteration: int) -> None:
            check_parameters_finite(model, iteration=iteration, checkpoint=checkpoint_path,
                                    last_saved=last_saved[0])
            save_torch(checkpoint_path, {
                "format": CHECKPOINT_FORMAT, "fingerprint": fingerprint, "iteration": iteration,
                "model": model.state_dict(),
                "optimizers": {k: opt.state_dict() for k, opt in optimizers.items()},
                "torch_rng": torch.get_rng_state(), "rows": rows, "samples": samples,
                "best": best.as_checkpoint()})
            last_saved[0] = iteration
            write_live_log(out_dir, rows, live_params)

        validating = monitor is not None and settings.validate_every > 0
        if start == 0:
            write_samples(0)
            if validating:
                rows.append({"iteration": 0, **monitor(model)})
                write_train_log(out_dir / "train_log.csv", rows)
        progress = _progress_bar(total=settings.iterations, initial=start, name=name)
        t0, done_here = time.perf_counter(), 0
        try:
            for iteration in range(start + 1, settings.iterations + 1):
                positions, target, noise_seed = iteration_draws(
                    iteration, seed=seed, labels=train_labels, batch_size=settings.batch_size,
                    n_conditions=n_conditions)
                frames = images[train_idx[positions]]
                batch = TrainingBatch(
                    x=preprocess(frames, image_size=settings.image_size).to(device),
                    condition=torch.from_numpy(train_labels[positions]).to(device),
                    target=torch.from_numpy(target).to(device),
                    noise=seeded_noise(len(positions), model.code_dim, seed=noise_seed,
                                       std=model.prior_std).to(device))
                last = iteration == settings.iterations
                is_log = iteration % settings.log_every == 0 or last
                is_validation = validating and (iteration % settings.validate_every == 0
                                                or last)
                logs = model.training_step(batch, optimizers, diagnostics=is_log)
                check_finite(logs, iteration=iteration, checkpoint=checkpoint_path,
                             last_saved=last_saved[0])
                done_here += 1
                progress.update(1)
                if is_log:
                    logs.update(model.heldout_metrics(eval_x, eval_c))
                    if is_validation:
                        logs.update(monitor(model))
                        best.offer(iteration, logs, model)
                    rows.append({"iteration": iteration, **logs})
                    write_train_log(out_dir / "train_log.csv", rows)
                    elapsed = time.perf_counter() - t0
                    per_it = elapsed / done_here
                    eta = per_it * (settings.iterations - iteration)
                    progress.set_postfix({k: f"{logs[k]:.3g}" for k in _headline(logs)})
                    logger.info("%s %d/%d (%.2f s/it, ETA %s): %s", name, iteration,
                                settings.iterations, per_it, _format_eta(eta),
                                " ".join(f"{k}={logs[k]:.4g}" for k in _headline(logs)))
                if iteration % settings.sample_every == 0 or last:
                    write_samples(iteration)
                if iteration % settings.checkpoint_every == 0 or last:
                    save_state(iteration)
                if callback is not None:
                    callback(iteration, logs)
        finally:
            progress.close()

        if start == settings.iterations:  # a finished run: rewrite its logs from the checkpoint
            write_train_log(out_dir / "train_log.csv", rows)
            write_live_log(out_dir, rows, live_params)
        selection = selection_record(settings, best, rows)
        if settings.select == "best_validation" and selection["iteration"] != best.iteration:
            logger.warning("%s: %s", name, selection["note"])
        kept = best.state if selection["iteration"] == best.iteration else model.state_dict()
        model_path = out_dir / "model.pt"
        save_torch(model_path, {
            "name": name, "config": plain_cfg, "conditions": list(conditions),
            "image_size": settings.image_size, "state_dict": kept,
            "iteration": selection["iteration"], "trained_iterations": settings.iterations,
            "selection": selection, "seed": int(seed),
            # the CPU kernel path that trained it (cmal_lcd.kernels): same path, same weights
            "kernels": kernel_path()})
        atomic_write_json(out_dir / "selection.json", selection)
    logger.info("%s: wrote %s (weights of iteration %d of %d: %s)", name, model_path,
                selection["iteration"], settings.iterations, selection["note"])
    return model_path


_HEADLINE_KEYS = ("D/loss", "G/adv", "E/recon", "E/recon_heldout", "C/acc_heldout",
                  "val/recall_at_100p", "val/single_frame_recall_at_1")


def _headline(logs: Mapping[str, float]) -> list[str]:
    return [k for k in _HEADLINE_KEYS if k in logs]


def _progress_bar(*, total: int, initial: int, name: str):
    """A tqdm bar with ETA on stderr (hidden when stderr is not a terminal)."""
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=f"train {name}", unit="it", file=sys.stderr,
                disable=not sys.stderr.isatty(), dynamic_ncols=True)
