"""Where the chain reads and writes: a view of the ``outs`` of ``dvc.yaml``, their one definition.

:class:`ChainPaths` lays the folders out under a root: the repository for ``dvc repro``
(:data:`REPO`, ``ChainPaths(Path("."))``: exactly the relative paths of ``dvc.yaml``, and the
defaults of every stage's command line and ``main``), or the Hydra app's job folder. Each path
is an ``outs`` entry of a ``dvc.yaml`` stage (:data:`OUTS`), read from the checkout's
``dvc.yaml`` (:func:`cmal_lcd.checkout.checkout_dvc_yaml`) when a path is first asked for; an
entry's ``${item.<key>}`` or ``${key}`` is the model or method. No heavy import: stages and
commands import it.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from pathlib import Path

#: Each path of the chain: the ``dvc.yaml`` stage whose ``outs`` hold it, and its position there.
OUTS = {
    "dataset": ("dataset", 0),
    "manifest": ("dataset", 1),
    "world": ("calibrate_world", 0),
    "model": ("train", 0),
    "checkpoints": ("train", 1),
    "method_features": ("extract_features", 0),
    "timing": ("extract_features", 1),
    "protocol": ("select_protocol", 0),
    "method_evaluation": ("evaluate", 0),
    "method_loops": ("evaluate_loops", 0),
    "invariance": ("analyse_codes", 0),
    "report_tables": ("report", 0),
}


@functools.cache
def _layout(dvc_yaml: Path) -> dict[str, str]:
    """``{name: outs entry}`` of :data:`OUTS` in ``dvc_yaml``, unresolved
    (``models/${item.model}``)."""
    from cmal_lcd.chain import out_path, read_stages

    stages, _ = read_stages(dvc_yaml)
    return {name: out_path(stages[stage]["outs"][at]) for name, (stage, at) in OUTS.items()}


def layout() -> dict[str, str]:
    """The chain's paths as the checkout's ``dvc.yaml`` declares them (:func:`_layout`)."""
    from cmal_lcd.checkout import checkout_dvc_yaml

    return _layout(checkout_dvc_yaml())


def _path(name: str, item: str = "") -> Path:
    """Entry ``name`` of :func:`layout`, its ``${...}`` (the matrix item) set to ``item``."""
    return Path(re.sub(r"\$\{[^}]*\}", item, layout()[name]))


@dataclass(frozen=True)
class ChainPaths:
    """Where every step of the chain reads and writes, under ``root``.

    ``root`` is the repository for ``dvc repro`` (``ChainPaths(Path("."))`` gives exactly the
    relative paths of ``dvc.yaml``). A folder of one file or folder per method or model is the
    parent of that entry (``models`` of ``models/${item.model}``).
    """

    root: Path

    @property
    def dataset(self) -> Path:
        """``data/dataset``: written by ``dataset``, read by every later step."""
        return self.root / _path("dataset")

    @property
    def manifest(self) -> Path:
        """``data/manifest.csv``: the split manifest, beside the dataset folder."""
        return self.root / _path("manifest")

    @property
    def models(self) -> Path:
        """``models``: one ``models/<model>`` folder per trained model."""
        return self.model("x").parent

    def model(self, name: str) -> Path:
        return self.root / _path("model", name)

    def checkpoints(self, name: str) -> Path:
        """``checkpoints/<model>``: training's resume state (never read downstream)."""
        return self.root / _path("checkpoints", name)

    @property
    def features(self) -> Path:
        """``data/features``: one ``data/features/<method>`` folder per method."""
        return self.method_features("x").parent

    def method_features(self, method: str) -> Path:
        return self.root / _path("method_features", method)

    @property
    def timings(self) -> Path:
        """``data/timing``: one ``<method>.json`` (Table III) per method."""
        return self.timing("x").parent

    def timing(self, method: str) -> Path:
        return self.root / _path("timing", method)

    @property
    def protocols(self) -> Path:
        """``data/protocol``: one ``data/protocol/<method>.json`` per method."""
        return self.protocol("x").parent

    def protocol(self, method: str) -> Path:
        return self.root / _path("protocol", method)

    @property
    def evaluation(self) -> Path:
        """``data/evaluation``: ``<method>/`` per method and ``invariance.json``."""
        return self.method_evaluation("x").parent

    def method_evaluation(self, method: str) -> Path:
        return self.root / _path("method_evaluation", method)

    @property
    def loops(self) -> Path:
        """``data/evaluation_loops``: ``<method>/`` per method (loop closure within a drive)."""
        return self.method_loops("x").parent

    def method_loops(self, method: str) -> Path:
        return self.root / _path("method_loops", method)

    @property
    def invariance(self) -> Path:
        return self.root / _path("invariance")

    @property
    def reports(self) -> Path:
        """``reports``: tables, figures, ``README.md``, ``metrics.json`` (the folder of the
        ``report`` stage's outs)."""
        return self.root / _path("report_tables").parent

    @property
    def world(self) -> Path:
        """``reports/world``: ``calibrate_world``'s difficulty of the weather world."""
        return self.root / _path("world")


#: The repository's layout: the paths of ``dvc.yaml`` and the stages' defaults.
REPO = ChainPaths(Path("."))
