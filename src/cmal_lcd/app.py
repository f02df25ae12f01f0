"""The whole chain as one Hydra app: ``cmal-lcd-run [overrides]`` or ``cmal-lcd-run -m ...``.

Runs the stages of the checkout's ``dvc.yaml`` (:mod:`cmal_lcd.chain`: the one declaration of
the chain), in its order, each as its ``cmd`` (the stage's ``cli`` on the same arguments,
in-process, plus ``--root <job folder>``), on one composed config (``conf/app.yaml`` =
``conf/config.yaml`` + an ``app`` node, written to the job's ``params.yaml`` without ``app``).
``dvc.yaml``'s relative paths lie under the Hydra job folder (``outputs/...`` or
``multirun/...``, both git- and dvc-ignored), never in the repository's tracked paths; the
working directory stays the launch folder, so the config's own relative paths mean what they
mean there. The job folder gets what ``dvc repro`` writes into the repository:

- ``data/dataset``, ``data/manifest.csv`` (step ``dataset``)
- ``reports/world`` (``calibrate_world``; for a folder dataset only the reason it is skipped)
- ``models/<model>``, ``checkpoints/<model>`` (``train``, per model :func:`models_to_train`)
- ``data/features/<method>``, ``data/timing/<method>.json``, ``data/protocol/<method>.json``,
  ``data/evaluation/<method>``, ``data/evaluation_loops/<method>`` (``extract_features``,
  ``select_protocol``, ``evaluate``, ``evaluate_loops``, per method)
- ``data/evaluation/invariance.json`` (``analyse_codes``)
- ``reports/`` (tables, figures, ``metrics.json``; step ``report``)
- ``metrics.json``: the job's flat summary ``{"route/pair/method/metric": value}`` of the
  ``selected`` variant (each method's protocol chosen on the validation drives), collected
  by ``cmal-lcd aggregate``.

Which learned models a job trains follows ``methods`` (:func:`models_to_train`; ``dvc repro``
trains every entry of ``model_names``): ``methods=[sad,cmal],[sad,bigan]`` sweeps the learned
model (``model`` itself is a config group used twice, for ``models.cmal`` and
``models.bigan``, so ``model=cmal,bigan`` does not select anything).

Launchers are Hydra config: ``hydra/launcher=joblib`` (local, parallel) or
``hydra/launcher=submitit_slurm`` (a SLURM cluster), ``submitit_local`` (here, for testing).
See docs/sweeps.md.

The app composes ``conf/`` of the checkout it is run in (:func:`cmal_lcd.config.checkout_root`:
``$CMAL_LCD_REPO``, else the nearest folder at or above the working directory holding
``conf/config.yaml``), never the one the package was installed from. Names are checked before
any step runs (:func:`cmal_lcd.config.check_config`); a failure is one line and exit code 2
(``CMAL_LCD_TRACEBACK=1`` or ``HYDRA_FULL_ERROR=1`` adds the traceback).
"""

from __future__ import annotations

import importlib
import json
import logging
import os
import sys
from pathlib import Path
from typing import Mapping, Sequence

import hydra
from omegaconf import DictConfig, OmegaConf

from cmal_lcd.config import check_config
from cmal_lcd.io import atomic_write_json
from cmal_lcd.paths import REPO

# named, not __name__: that is "__main__" under `python -m cmal_lcd.app`
logger = logging.getLogger("cmal_lcd.app")

#: The evaluation variant summarised in ``metrics.json`` (the protocol chosen on validation).
SUMMARY_VARIANT = "selected"


# ------------------------------------------------------------------------- the chain
#
# The chain is ``dvc.yaml`` (:mod:`cmal_lcd.chain`): the app runs its stages' commands
# in-process, in the job folder, for the job's matrix items. :func:`reused_folders` says which
# folders an ``app.reuse`` key stands for (a stage writing into one of them is skipped).


def reused_folders() -> dict[str, dict[Path, str]]:
    """``app.reuse`` key -> the folders of the job it replaces, and where each lies in the
    reused folder's checkout (``features`` brings its ``data/timing`` beside it, as ``dvc
    repro`` lays them out)."""
    return {"dataset": {REPO.dataset: "."},
            "models": {REPO.models: "."},
            "features": {REPO.features: ".",
                         REPO.timings: os.path.relpath(REPO.timings, REPO.features)}}


def chain_runs(cfg: DictConfig, dvc_yaml: Path, names: Sequence[str] | None = None):
    """The :class:`cmal_lcd.chain.StageRun` of ``dvc_yaml``'s stages (those in ``names``) for
    the job's items: one per method of ``methods``, one per model :func:`models_to_train`."""
    from cmal_lcd.chain import stage_runs

    items = {"method": list(cfg.methods),
             "model": models_to_train(cfg.methods, cfg.model_names, cfg.get("extractors"))}
    feature_inputs = OmegaConf.to_container(cfg.feature_inputs, resolve=True) \
        if "feature_inputs" in cfg else None
    return stage_runs(dvc_yaml, items, feature_inputs=feature_inputs, names=names)


def run_stage(run, job_dir: Path) -> None:
    """Run one stage's ``cli`` on its ``dvc.yaml`` arguments with ``--root job_dir``: its
    relative paths and ``--params params.yaml`` are the job's (as ``dvc repro``'s are the
    checkout's), while the working directory stays the launch folder, where the config's own
    relative paths (``data.root``, a descriptor file) were given."""
    module = importlib.import_module(run.module)
    module.cli([*run.argv, "--root", str(job_dir)])


def resolve_reused(path: str | None, *, key: str) -> Path | None:
    """Absolute path of an ``app.reuse.<key>`` folder (relative to the launch directory).

    Raises
    ------
    FileNotFoundError
        When the folder does not exist (the message names ``app.reuse.<key>``).
    """
    if path is None:
        return None
    resolved = Path(hydra.utils.to_absolute_path(str(path)))
    if not resolved.exists():
        raise FileNotFoundError(f"app.reuse.{key}: {resolved} does not exist")
    return resolved


def models_to_train(methods, model_names, extractors=None) -> list[str]:
    """Names of ``model_names`` (in that order) whose trained weights some method reads.

    ``dvc.yaml`` trains every entry of ``model_names`` (``train`` is a matrix over it; a DVC
    matrix cannot be filtered by another list); the app trains only the models its
    ``methods`` read (``Method.model`` of their ``extractors`` nodes, default the built-in
    ones: :func:`cmal_lcd.features.method_model`), so that
    ``methods=[sad,bigan]`` spends no time on CMAL. The two agree whenever every model in
    ``model_names`` is read by some method, which holds for the default config and every
    shipped experiment (tests/test_chain.py). A model
    that a method reads but ``model_names`` lacks is trained by neither: its features step
    fails the same way in both.
    """
    from cmal_lcd.features import method_model

    needed = {method_model(str(method), extractors) for method in methods}
    return [name for name in model_names if name in needed]


def flat_summary(evaluations: Mapping[str, Mapping], *,
                 variant: str = SUMMARY_VARIANT) -> dict[str, float | None]:
    """Flatten per-method evaluation metrics into ``{"route/pair/method/metric": value}``.

    Parameters
    ----------
    evaluations : mapping
        ``{method: {route: {pair: {variant: {metric: value}}}}}`` (each method's
        ``data/evaluation/<method>/metrics.json``).
    variant : str
        Which variant to keep (``selected``: the protocol chosen on validation drives;
        ``paper``: the paper's protocol, an ablation).

    Raises
    ------
    ValueError
        When a method has no entry for ``variant``.
    """
    flat: dict[str, float | None] = {}
    for method, routes in evaluations.items():
        for route, pairs in routes.items():
            for pair, variants in pairs.items():
                if variant not in variants:
                    raise ValueError(f"variant: {method} {route} {pair} has no {variant!r} "
                                     f"entry (has {sorted(variants)})")
                for key, value in variants[variant].items():
                    flat[f"{route}/{pair}/{method}/{key}"] = value
    return dict(sorted(flat.items()))


def world_note(cfg: DictConfig) -> str | None:
    """Why ``calibrate_world`` has no world to measure (None for the rendered world)."""
    from cmal_lcd.data.world.config import KIND

    kind = OmegaConf.select(cfg, "data.kind", default=KIND)
    if kind == KIND:
        return None
    return (f"data.kind is {kind!r}, not {KIND!r}: there is no world to calibrate; the stage "
            f"writes only the reason to reports/world/difficulty.json, as under dvc repro")


def check_outside_tracked_paths(job_dir: Path, runs, chain) -> None:
    """Refuse a job whose outputs would land in the checkout's DVC-tracked paths (``data/``,
    ``models/``, ``checkpoints/``, ``reports/``): ``cmal-lcd-run hydra.run.dir=.`` wrote
    ``data/dataset`` and ``data/manifest.csv`` over ``dvc repro``'s (issue 38 item 7).
    ``runs`` are the runs the job makes (not those of reused folders: those are only read);
    ``chain`` all of the chain's, whose top-level folders are the tracked ones.

    Raises
    ------
    ValueError
        Naming ``hydra.run.dir`` (or ``hydra.sweep.dir``), the output and the tracked path.
    """
    from cmal_lcd.checkout import CheckoutNotFoundError, checkout_root

    try:
        root = checkout_root().resolve()
    except CheckoutNotFoundError:
        return
    tracked = {root / Path(out).parts[0] for run in chain for out in run.outs}
    for run in runs:
        for out in run.outs:
            path = (Path(job_dir) / out).resolve()
            inside = next((t for t in tracked if path == t or t in path.parents), None)
            if inside is not None:
                raise ValueError(f"hydra.run.dir (or hydra.sweep.dir) {job_dir}: the job would "
                                 f"write {path} inside the checkout's DVC-tracked {inside}; "
                                 f"choose a folder outside data/, models/, checkpoints/ and "
                                 f"reports/ (default: outputs/<date>/<time>)")


def link_reused(job_dir: Path, reused: Mapping[Path, Path]) -> None:
    """Make each reused folder appear at its place in the job (a symbolic link), so that the
    stages read it on their ``dvc.yaml`` paths."""
    for relative, target in reused.items():
        link = Path(job_dir) / relative
        link.parent.mkdir(parents=True, exist_ok=True)
        if link.is_symlink():
            link.unlink()
        link.symlink_to(target, target_is_directory=True)


def write_job_params(cfg: DictConfig, job_dir: Path) -> Path:
    """The job's ``params.yaml`` (its config without the ``app`` node): what each stage reads
    through ``--params params.yaml``, as under ``dvc repro``."""
    from cmal_lcd.io import atomic_write_text

    params = OmegaConf.to_container(cfg, resolve=True)
    params.pop("app", None)
    path = Path(job_dir) / "params.yaml"
    atomic_write_text(path, OmegaConf.to_yaml(OmegaConf.create(params)))
    return path


def run_chain(cfg: DictConfig, job_dir: Path) -> dict[str, float | None]:
    """Run the configured stages of ``dvc.yaml`` in ``job_dir``; return the flat summary.

    The stages named in ``app.steps`` (null: all) run in ``dvc.yaml``'s order, each as its
    ``cmd`` on the job's relative paths and the job's ``params.yaml``.
    ``app.reuse.{dataset,models,features}`` stand for the job's own folder (linked into it) and
    skip the stages that write there. ``calibrate_world`` runs for every dataset kind, as in
    ``dvc.yaml``; for a dataset that is not the rendered world the stage records why there is
    nothing to measure, and the reason is logged here. The summary is also written to
    ``job_dir/metrics.json``.

    Raises
    ------
    ValueError
        When ``app.steps`` names an unknown stage, or a name of the config is unsafe
        (:func:`cmal_lcd.config.check_config`).
    """
    from cmal_lcd.chain import stage_names, under
    from cmal_lcd.checkout import checkout_dvc_yaml

    check_config(cfg)
    dvc_yaml = checkout_dvc_yaml()
    every = stage_names(dvc_yaml)
    steps = every if cfg.app.steps is None else list(cfg.app.steps)
    unknown = sorted(set(steps) - set(every))
    if unknown:
        raise ValueError(f"app.steps: unknown steps {unknown}; choose from {every} (the "
                         f"stages of {dvc_yaml})")
    job_dir = Path(job_dir)
    layout = reused_folders()
    reused = {relative: (folder / inside).resolve()
              for key, folder in ((k, resolve_reused(cfg.app.reuse[k], key=k)) for k in layout)
              if folder is not None for relative, inside in layout[key].items()}
    runs = chain_runs(cfg, dvc_yaml, steps)
    skipped = {run.address: folder for run in runs for folder in reused
               if any(under(out, folder) for out in run.outs)}
    check_outside_tracked_paths(job_dir, [r for r in runs if r.address not in skipped],
                                chain_runs(cfg, dvc_yaml))
    methods = list(cfg.methods)
    logger.info("job %s: steps %s, methods %s", job_dir, steps, methods)
    job_dir.mkdir(parents=True, exist_ok=True)
    link_reused(job_dir, reused)
    write_job_params(cfg, job_dir)
    for run in runs:
        if run.address in skipped:
            folder = skipped[run.address]
            logger.info("%s: skipped, %s is reused (%s)", run.address, folder, reused[folder])
            continue
        if run.name == "calibrate_world" and (note := world_note(cfg)) is not None:
            logger.info("calibrate_world: %s", note)
        run_stage(run, job_dir)

    evaluations = {m: json.loads(path.read_text()) for m in methods
                   if (path := job_dir / REPO.method_evaluation(m) / "metrics.json").is_file()}
    summary = flat_summary(evaluations)
    atomic_write_json(job_dir / "metrics.json", summary)
    report = job_dir / REPO.reports / "README.md"
    logger.info("job %s done%s", job_dir, f": open {report}" if "report" in steps and
                report.is_file() else "")
    return summary


def objective(summary: Mapping[str, float | None], extractors=None) -> float | None:
    """Mean recall at 100% precision of the methods whose codes come from trained weights
    (``Method.trained`` of their ``extractors`` nodes, default the built-in ones:
    :func:`cmal_lcd.features.trained_methods`; a sweeper objective), or None."""
    from cmal_lcd.features import trained_methods

    trained = trained_methods(extractors)
    values = [v for k, v in summary.items()
              if k.endswith("/recall_at_100p") and k.split("/")[2] in trained
              and v is not None]
    return float(sum(values) / len(values)) if values else None


def run_job(cfg: DictConfig) -> float | None:
    """One Hydra job: :func:`run_chain` in the job folder; returns :func:`objective`.

    A failure ends the process with one line naming the file or key and exit code 2; in a
    submitit job (a SLURM or submitit-local sweep) it raises
    :class:`cmal_lcd.slurm.JobFailed` with that line instead, so that submitit records the
    failure and the launcher reports it (an exit leaves no result to read: issue 39).
    """
    from hydra.core.hydra_config import HydraConfig

    from cmal_lcd.errors import one_line, report_failure

    job_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        return objective(run_chain(cfg, job_dir), cfg.get("extractors"))
    except Exception as exc:  # noqa: BLE001 - the user-facing boundary
        if os.environ.get("SUBMITIT_EXECUTOR"):
            from cmal_lcd.slurm import JobFailed

            raise JobFailed(one_line(exc)) from exc
        verbose = any(os.environ.get(k, "") not in ("", "0")
                      for k in ("CMAL_LCD_TRACEBACK", "HYDRA_FULL_ERROR"))
        sys.exit(report_failure("cmal-lcd-run", exc, verbose=verbose))


#: Hydra options after which the command line is Hydra's own business (help, config printing,
#: another config): the overrides are then left to Hydra.
HYDRA_OPTIONS = ("-h", "--help", "--hydra-help", "--version", "-c", "--cfg", "--resolve",
                 "-p", "--package", "-i", "--info", "-cp", "--config-path", "-cn",
                 "--config-name", "-cd", "--config-dir", "-sc", "--shell-completion",
                 "--experimental-rerun")


def check_command_line(argv: Sequence[str], conf_dir: Path) -> None:
    """Compose ``conf/app.yaml`` with the command line's overrides before Hydra does, so that
    a bad override (``matching.dss=3``, ``"matching.ds=[1,"``, ``debug=huge``) is one line
    and exit 2 (Hydra prints several lines and exits 1; issue 38 item 10). ``hydra.*``
    overrides are left out; a sweep (``-m seed=0,1``) is checked with its first value.

    Raises
    ------
    Exception
        Hydra's parse or composition error, or :class:`cmal_lcd.schema.SchemaError` naming the
        key (the message is cut before Hydra's config search path).
    """
    from hydra.core.override_parser.overrides_parser import OverridesParser

    from cmal_lcd.config import compose

    if any(arg.split("=")[0] in HYDRA_OPTIONS for arg in argv):
        return
    overrides = [arg for arg in argv if not arg.startswith("-")]
    kept = []
    for override in OverridesParser.create().parse_overrides(overrides):
        if override.is_hydra_override() or override.key_or_group == "hydra":
            continue
        if not override.is_sweep_override():
            kept.append(override.input_line)
        elif override.is_discrete_sweep():
            first = next(iter(override.sweep_string_iterator()), None)
            if first is not None:
                kept.append(f"{override.get_key_element()}={first}")
    try:
        compose(kept, config_dir=conf_dir, config_name="app")
    except Exception as exc:
        text = str(exc).split("Config search path:")[0]
        if text == str(exc):
            raise
        raise ValueError(text) from None


def main() -> float | None:
    """``cmal-lcd-run``: Hydra on ``conf/`` of the checkout it is run in (see the module doc)."""
    from cmal_lcd.checkout import CheckoutNotFoundError, checkout_root
    from cmal_lcd.errors import report_failure

    try:
        conf_dir = checkout_root() / "conf"
    except CheckoutNotFoundError as exc:
        sys.exit(report_failure("cmal-lcd-run", exc))
    from cmal_lcd.schema import register_configs

    register_configs()
    try:
        check_command_line(sys.argv[1:], conf_dir)
    except Exception as exc:  # noqa: BLE001 - the user-facing boundary: one line, exit 2
        sys.exit(report_failure("cmal-lcd-run", exc))
    hydra_main = hydra.main(config_path=str(conf_dir), config_name="app", version_base="1.3")
    return hydra_main(run_job)()


if __name__ == "__main__":
    main()
