"""dvc.yaml as DVC itself resolves it: stage names, deps, params keys, and the stage graph.

:func:`resolved` copies ``dvc.yaml`` and ``params.yaml`` into a scratch folder, initialises a
DVC repository there (no git) and reads its index, so ``foreach``/``matrix`` expansion and
interpolation are DVC's own; nothing is read from, or written into, the checkout's ``.dvc``.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Stage:
    """One resolved stage: ``params`` is None when it depends on the whole params file."""

    name: str
    cmd: str
    deps: tuple[str, ...]
    params: frozenset[str] | None
    outs: tuple[str, ...]


@dataclass(frozen=True)
class Pipeline:
    stages: dict[str, Stage]
    #: stage name -> names of the stages that (directly or not) consume its outputs
    downstream: dict[str, frozenset[str]]


def resolved(scratch: Path, *, dvc_yaml: str | None = None, params_yaml: str | None = None
             ) -> Pipeline:
    """The pipeline of ``dvc_yaml`` (default: the checkout's dvc.yaml) resolved by DVC."""
    import logging

    import dvc.logger
    import networkx as nx
    from dvc.dependency.param import ParamsDependency
    from dvc.repo import Repo

    scratch.mkdir(parents=True, exist_ok=True)
    for name, text in (("dvc.yaml", dvc_yaml), ("params.yaml", params_yaml)):
        if text is None:
            shutil.copy(ROOT / name, scratch / name)
        else:
            (scratch / name).write_text(text)
    # dvc binds its log handlers to sys.stdout/stderr when first imported; a test that imported
    # it under pytest's capture left them pointing at a closed stream: bind new ones
    logging.getLogger("dvc").handlers.clear()
    dvc.logger.setup()
    if not (scratch / ".dvc").exists():
        Repo.init(str(scratch), no_scm=True)
    repo = Repo(str(scratch))
    try:
        stages, by_obj = {}, {}
        for stage in repo.index.stages:
            params: set[str] | None = set()
            for dep in stage.deps:
                if isinstance(dep, ParamsDependency):
                    assert Path(dep.def_path).name == "params.yaml", dep.def_path
                    if not dep.params:
                        params = None
                    elif params is not None:
                        params.update(dep.params)
            stages[stage.name] = Stage(
                name=stage.name, cmd=stage.cmd,
                deps=tuple(d.def_path for d in stage.deps if not isinstance(d, ParamsDependency)),
                params=None if params is None else frozenset(params),
                outs=tuple(o.def_path for o in stage.outs))
            by_obj[stage] = stage.name
        graph = repo.index.graph  # edges: consumer -> producer
        downstream = {by_obj[s]: frozenset(by_obj[a] for a in nx.ancestors(graph, s))
                      for s in graph.nodes}
    finally:
        repo.close()
    return Pipeline(stages=stages, downstream=downstream)


def declares(stage: Stage, key: str) -> bool:
    """Whether a change of params key ``key`` (dotted) is seen by ``stage``'s params deps."""
    if stage.params is None:
        return True
    return any(key == p or key.startswith(p + ".") or p.startswith(key + ".")
               for p in stage.params)
