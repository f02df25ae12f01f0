"""The whole chain as one Hydra app: ``cmal-lcd-run [overrides]`` or ``cmal-lcd-run -m ...``.

Runs the same stage functions as ``dvc repro`` (``cmal_lcd.stages.*.main``), in the same order
and on the same relative paths, on one composed config (``conf/app.yaml`` =
``conf/config.yaml`` + an ``app`` node), writing everything into the Hydra job folder
(``outputs/...`` or ``multirun/...``, both git- and dvc-ignored), never into the repository's
tracked paths. The chain is defined once, here: :data:`CHAIN` (the steps, in ``dvc.yaml``'s
order, each with its command-line paths and outputs) over :class:`ChainPaths` (the path
layout); tests/test_chain.py fails when ``dvc.yaml`` says otherwise. The job folder gets what
``dvc repro`` writes into the repository:

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
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import hydra
from omegaconf import DictConfig, OmegaConf

from cmal_lcd.config import check_config
from cmal_lcd.io import atomic_write_json
from cmal_lcd.paths import ChainPaths

# named, not __name__: that is "__main__" under `python -m cmal_lcd.app`
logger = logging.getLogger("cmal_lcd.app")

#: The evaluation variant summarised in ``metrics.json`` (the protocol chosen on validation).
SUMMARY_VARIANT = "selected"


# ------------------------------------------------------------------------- the chain, once
#
# ``ChainPaths`` (:mod:`cmal_lcd.paths`) is the chain's path layout and ``CHAIN`` its steps:
# the one definition that both the Hydra app (here) and ``dvc.yaml`` follow. ``dvc.yaml`` cannot import Python, so
# tests/test_chain.py reads it and fails when a stage's order, matrix, command-line paths,
# outputs or data dependencies differ from this table (docs/architecture.md, "The chain").




#: A step's command-line flags (as in its ``dvc.yaml`` cmd, ``--params`` aside) -> paths.
Flags = Callable[[ChainPaths, str], dict[str, Path]]


@dataclass(frozen=True)
class Step:
    """One step of the chain: a DVC stage and the stage function the app calls.

    Attributes
    ----------
    name : str
        The DVC stage name (also the ``app.steps`` name).
    module : str
        ``cmal_lcd.stages.<module>``: its ``main`` is called, as its ``cli`` does under DVC.
    matrix : str or None
        ``method`` (one run per entry of ``methods``), ``model`` (one per model to train) or
        None (one run): the key of the stage's ``matrix`` in ``dvc.yaml``.
    flags : callable
        ``(paths, item) -> {flag: path}``: the paths the stage's command line takes
        (``--dataset data/dataset`` ...); ``dvc.yaml`` names those not in ``item_flags``.
    outs : callable
        ``(paths, item) -> paths``: what the step writes (``dvc.yaml`` ``outs``, or folders
        holding them).
    kwargs : mapping
        The ``main`` keyword of each flag (the stage's ``cli`` does the same mapping).
    item_kwarg : str or None
        The ``main`` keyword taking the matrix item (``method``, ``model_name``).
    item_flags : frozenset of str
        Flags whose paths are the item's (``--out models/<model>``): ``dvc.yaml`` leaves them
        out, with the item itself, and the stage's ``cli`` derives them from the item it reads
        from ``$DVC_STAGE`` (:func:`cmal_lcd.stages.stage_item`), so no name reaches a shell.
    reuse : str or None
        The ``app.reuse`` key whose folder replaces this step's output (the step is skipped).
    extra : callable
        ``paths -> {keyword: path}``: paths ``main`` gets that are not flags in ``dvc.yaml``
        (the stage's ``cli`` derives them: the manifest beside ``--out``).
    after : callable
        ``paths -> paths``: outputs of earlier steps the stage depends on in ``dvc.yaml``
        without a flag (only to run after the step that writes them).
    """

    name: str
    module: str
    matrix: str | None
    flags: Flags
    outs: Callable[[ChainPaths, str], tuple[Path, ...]]
    kwargs: Mapping[str, str]
    item_kwarg: str | None = None
    item_flags: frozenset[str] = frozenset()
    reuse: str | None = None
    extra: Callable[[ChainPaths], dict[str, Path]] = lambda paths: {}
    after: Callable[[ChainPaths], tuple[Path, ...]] = lambda paths: ()

    def main_kwargs(self, paths: ChainPaths, item: str | None = None) -> dict[str, object]:
        """The keyword arguments of ``cmal_lcd.stages.<module>.main`` for one run."""
        kwargs: dict[str, object] = {self.kwargs[flag]: path
                                     for flag, path in self.flags(paths, item).items()}
        if self.item_kwarg is not None:
            kwargs[self.item_kwarg] = item
        return {**kwargs, **self.extra(paths)}

    def run(self, cfg, paths: ChainPaths, item: str | None = None) -> None:
        """Call ``cmal_lcd.stages.<module>.main(part, **main_kwargs(paths, item))`` on the part
        of ``cfg`` the stage reads (:func:`cmal_lcd.stages.config_slice`), as its ``cli``
        does under DVC."""
        from cmal_lcd.stages import config_slice, stage_keys

        module = importlib.import_module(f"cmal_lcd.stages.{self.module}")
        module.main(config_slice(cfg, stage_keys(module, item, cfg)),
                    **self.main_kwargs(paths, item))


_DATA = {"--dataset": "dataset_dir", "--models": "models_dir", "--features": "features_dir",
         "--evaluation": "evaluation_dir", "--checkpoints": "checkpoints_dir"}

#: The chain, in ``dvc.yaml``'s order (a topological order of its deps and outs).
CHAIN: tuple[Step, ...] = (
    Step("dataset", "make_dataset", None,
         flags=lambda p, _: {"--out": p.dataset},
         outs=lambda p, _: (p.dataset, p.manifest),
         kwargs={"--out": "out_dir"}, reuse="dataset",
         extra=lambda p: {"manifest": p.manifest}),
    Step("calibrate_world", "calibrate_world", None,
         flags=lambda p, _: {"--dataset": p.dataset, "--out": p.world},
         outs=lambda p, _: (p.world,),
         kwargs={**_DATA, "--out": "out_dir"}),
    Step("train", "train", "model",
         flags=lambda p, m: {"--dataset": p.dataset, "--out": p.model(m),
                             "--checkpoints": p.checkpoints(m)},
         outs=lambda p, m: (p.model(m), p.checkpoints(m)),
         kwargs={**_DATA, "--out": "out_dir"}, item_kwarg="model_name", reuse="models",
         item_flags=frozenset({"--out", "--checkpoints"})),
    Step("extract_features", "extract_features", "method",
         flags=lambda p, m: {"--dataset": p.dataset, "--models": p.models,
                             "--out": p.method_features(m), "--timing": p.timing(m)},
         outs=lambda p, m: (p.method_features(m), p.timing(m)),
         kwargs={**_DATA, "--out": "out_dir", "--timing": "timing_path"}, item_kwarg="method",
         reuse="features", item_flags=frozenset({"--out", "--timing"})),
    Step("select_protocol", "select_protocol", "method",
         flags=lambda p, m: {"--dataset": p.dataset, "--features": p.method_features(m),
                             "--out": p.protocol(m)},
         outs=lambda p, m: (p.protocol(m),),
         kwargs={**_DATA, "--out": "out_path"}, item_kwarg="method",
         item_flags=frozenset({"--features", "--out"})),
    Step("evaluate", "evaluate", "method",
         flags=lambda p, m: {"--dataset": p.dataset, "--features": p.method_features(m),
                             "--protocol": p.protocol(m), "--out": p.method_evaluation(m)},
         outs=lambda p, m: (p.method_evaluation(m),),
         kwargs={**_DATA, "--protocol": "protocol_path", "--out": "out_dir"},
         item_kwarg="method", item_flags=frozenset({"--features", "--protocol", "--out"})),
    Step("evaluate_loops", "evaluate_loops", "method",
         flags=lambda p, m: {"--dataset": p.dataset, "--features": p.method_features(m),
                             "--protocol": p.protocol(m), "--out": p.method_loops(m)},
         outs=lambda p, m: (p.method_loops(m),),
         kwargs={**_DATA, "--protocol": "protocol_path", "--out": "out_dir"},
         item_kwarg="method", item_flags=frozenset({"--features", "--protocol", "--out"})),
    Step("analyse_codes", "analyse_codes", None,
         flags=lambda p, _: {"--dataset": p.dataset, "--features": p.features,
                             "--protocol": p.protocols, "--models": p.models,
                             "--out": p.invariance},
         outs=lambda p, _: (p.invariance,),
         kwargs={**_DATA, "--protocol": "protocol_dir", "--out": "out_path"}),
    # reports/world is a dependency only so that the report comes after calibrate_world
    Step("report", "report", None,
         flags=lambda p, _: {"--evaluation": p.evaluation, "--loops": p.loops,
                             "--features": p.features, "--timing": p.timings,
                             "--protocol": p.protocols, "--models": p.models,
                             "--dataset": p.dataset, "--out": p.reports},
         outs=lambda p, _: (p.reports,),
         kwargs={**_DATA, "--protocol": "protocol_dir", "--loops": "loops_dir",
                 "--timing": "timing_dir", "--out": "out_dir"},
         after=lambda p: (p.world,)),
)
#: Step names in the order they run (``app.steps`` picks among them; the order is always this).
STEPS = tuple(step.name for step in CHAIN)


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


def step_items(step: Step, cfg: DictConfig) -> list[str | None]:
    """The runs of ``step``: one per method, one per model to train, or a single one."""
    if step.matrix == "method":
        return list(cfg.methods)
    if step.matrix == "model":
        return models_to_train(cfg.methods, cfg.model_names, cfg.get("extractors"))
    return [None]


def world_note(cfg: DictConfig) -> str | None:
    """Why ``calibrate_world`` has no world to measure (None for the rendered world)."""
    from cmal_lcd.data.world.config import KIND

    kind = OmegaConf.select(cfg, "data.kind", default=KIND)
    if kind == KIND:
        return None
    return (f"data.kind is {kind!r}, not {KIND!r}: there is no world to calibrate; the stage "
            f"writes only the reason to reports/world/difficulty.json, as under dvc repro")


def check_outside_tracked_paths(paths: ChainPaths) -> None:
    """Refuse a job whose outputs would land in the checkout's DVC-tracked paths (``data/``,
    ``models/``, ``checkpoints/``, ``reports/``): ``cmal-lcd-run hydra.run.dir=.`` wrote
    ``data/dataset`` and ``data/manifest.csv`` over ``dvc repro``'s (issue 38 item 7). Reused
    folders are only read, so they may be there.

    Raises
    ------
    ValueError
        Naming ``hydra.run.dir`` (or ``hydra.sweep.dir``), the output and the tracked path.
    """
    from cmal_lcd.config import CheckoutNotFoundError, checkout_root

    try:
        repo = ChainPaths(checkout_root())
    except CheckoutNotFoundError:
        return
    def outputs(layout: ChainPaths) -> set[Path]:
        """Every output of :data:`CHAIN` under ``layout`` (``item`` for any matrix item)."""
        return {p.resolve() for step in CHAIN for p in step.outs(layout, "item")}

    root = repo.root.resolve()
    tracked = {root / out.relative_to(root).parts[0] for out in outputs(repo)}
    reused = {p.resolve() for p in paths.reuse.values()}
    for out in sorted(outputs(paths)):
        if any(out == r or r in out.parents for r in reused):
            continue
        inside = next((t for t in tracked if out == t or t in out.parents), None)
        if inside is not None:
            raise ValueError(f"hydra.run.dir (or hydra.sweep.dir) {paths.root}: the job would "
                             f"write {out} inside the checkout's DVC-tracked {inside}; choose "
                             f"a folder outside data/, models/, checkpoints/ and reports/ "
                             f"(default: outputs/<date>/<time>)")


def run_chain(cfg: DictConfig, job_dir: Path) -> dict[str, float | None]:
    """Run the configured steps of the pipeline in ``job_dir``; return the flat summary.

    The steps of :data:`CHAIN` named in ``app.steps`` run in the chain's order (the order of
    ``dvc.yaml``), each on the paths of :class:`ChainPaths` rooted at ``job_dir``.
    ``app.reuse.{dataset,models,features}`` replace the job's own folder (and skip the step
    that makes it). ``calibrate_world`` runs for every dataset kind, as in ``dvc.yaml``; for
    a dataset that is not the rendered world the stage records why there is nothing to
    measure, and the reason is logged here. The summary is also written to
    ``job_dir/metrics.json``.

    Raises
    ------
    ValueError
        When ``app.steps`` names an unknown step, or a name of the config is unsafe
        (:func:`cmal_lcd.config.check_config`).
    """
    check_config(cfg)
    steps = list(cfg.app.steps)
    unknown = sorted(set(steps) - set(STEPS))
    if unknown:
        raise ValueError(f"app.steps: unknown steps {unknown}; choose from {list(STEPS)}")
    reuse = cfg.app.reuse
    reused = {key: resolve_reused(reuse[key], key=key) for key in ("dataset", "models",
                                                                   "features")}
    paths = ChainPaths(Path(job_dir), reuse={k: v for k, v in reused.items() if v is not None})
    check_outside_tracked_paths(paths)
    methods = list(cfg.methods)
    logger.info("job %s: steps %s, methods %s", job_dir, steps, methods)

    for step in CHAIN:
        if step.name not in steps:
            continue
        if step.reuse is not None and step.reuse in paths.reuse:
            logger.info("%s: skipped, app.reuse.%s is %s", step.name, step.reuse,
                        paths.reuse[step.reuse])
            continue
        if step.name == "calibrate_world" and (note := world_note(cfg)) is not None:
            logger.info("calibrate_world: %s", note)
        for item in step_items(step, cfg):
            step.run(cfg, paths, item)

    evaluations = {m: json.loads(path.read_text()) for m in methods
                   if (path := paths.method_evaluation(m) / "metrics.json").is_file()}
    summary = flat_summary(evaluations)
    atomic_write_json(job_dir / "metrics.json", summary)
    report = job_dir / "reports" / "README.md"
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
    from cmal_lcd.config import CheckoutNotFoundError, checkout_root
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
