"""Where the chain reads and writes: the one definition of every path of ``dvc.yaml``.

:class:`ChainPaths` lays the folders out under a root: the repository for ``dvc repro``
(:data:`REPO`, ``ChainPaths(Path("."))``: exactly the relative paths of ``dvc.yaml``, and the
defaults of every stage's command line and ``main``). No heavy import: stages and commands
import it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class ChainPaths:
    """Where every step of the chain reads and writes, under ``root``.

    ``root`` is the repository for ``dvc repro`` (``ChainPaths(Path("."))`` gives exactly the
    relative paths of ``dvc.yaml``).
    """

    root: Path

    @property
    def dataset(self) -> Path:
        """``data/dataset``: written by ``dataset``, read by every later step."""
        return self.root / "data" / "dataset"

    @property
    def manifest(self) -> Path:
        """``data/manifest.csv``: the split manifest, beside the dataset folder."""
        return self.root / "data" / "manifest.csv"

    @property
    def models(self) -> Path:
        """``models``: one ``models/<model>`` folder per trained model."""
        return self.root / "models"

    def model(self, name: str) -> Path:
        return self.models / name

    def checkpoints(self, name: str) -> Path:
        """``checkpoints/<model>``: training's resume state (never read downstream)."""
        return self.root / "checkpoints" / name

    @property
    def features(self) -> Path:
        """``data/features``: one ``data/features/<method>`` folder per method."""
        return self.root / "data" / "features"

    def method_features(self, method: str) -> Path:
        return self.features / method

    @property
    def timings(self) -> Path:
        """``data/timing``: one ``<method>.json`` (Table III) per method."""
        return self.root / "data" / "timing"

    def timing(self, method: str) -> Path:
        return self.timings / f"{method}.json"

    @property
    def protocols(self) -> Path:
        """``data/protocol``: one ``data/protocol/<method>.json`` per method."""
        return self.root / "data" / "protocol"

    def protocol(self, method: str) -> Path:
        return self.protocols / f"{method}.json"

    @property
    def evaluation(self) -> Path:
        """``data/evaluation``: ``<method>/`` per method and ``invariance.json``."""
        return self.root / "data" / "evaluation"

    def method_evaluation(self, method: str) -> Path:
        return self.evaluation / method

    @property
    def loops(self) -> Path:
        """``data/evaluation_loops``: ``<method>/`` per method (loop closure within a drive)."""
        return self.root / "data" / "evaluation_loops"

    def method_loops(self, method: str) -> Path:
        return self.loops / method

    @property
    def invariance(self) -> Path:
        return self.evaluation / "invariance.json"

    @property
    def reports(self) -> Path:
        """``reports``: tables, figures, ``README.md``, ``metrics.json``."""
        return self.root / "reports"

    @property
    def world(self) -> Path:
        """``reports/world``: ``calibrate_world``'s difficulty of the weather world."""
        return self.reports / "world"


#: The repository's layout: the paths of ``dvc.yaml`` and the stages' defaults.
REPO = ChainPaths(Path("."))
