"""No generic layer names a built-in method: the stages, the Hydra app, the evaluation, the
matching and the dataset code, and the models' shared training loop, ask a method's registry
entry or a model class for what it can do (``Method.trained``, ``Method.choose``,
``Method.model``; the config dataclass each model declares, with ``conditional``,
``cmal_lcd.models.MODEL_CONFIGS``), so that a method added in one file and one config node is
treated like the built-in ones. A model's own modules (its class and its config dataclass) and
the registries (``models/__init__.py``, ``features/``) name them, as they should.

``sad`` is left out of the search: it is also a metric (``metric="sad"``) and a config node
(``matching.sad``, SeqSLAM's own thumbnails), which these modules rightly name.
"""

import re
from pathlib import Path

import pytest

from cmal_lcd.features import METHOD_NAMES
from cmal_lcd.models import MODEL_CONFIGS

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "cmal_lcd"

#: The models' own modules (each one's class and config dataclass) and their registry: the
#: places that name them.
MODEL_MODULES = {"__init__.py", *(f"{module.rpartition('.')[2]}.py"
                                  for config in MODEL_CONFIGS.values()
                                  for module in (config.model_class.rpartition(".")[0],
                                                 config.__module__))}
#: The generic layers: every module of these folders (not sub-folders), the schema and the app.
GENERIC = sorted([*(PACKAGE / "stages").glob("*.py"), *(PACKAGE / "evaluation").glob("*.py"),
                  *(PACKAGE / "matching").glob("*.py"), *(PACKAGE / "data").glob("*.py"),
                  *(p for p in (PACKAGE / "models").glob("*.py") if p.name not in MODEL_MODULES),
                  PACKAGE / "schema.py", PACKAGE / "app.py"])

NAMES = [name for name in METHOD_NAMES if name != "sad"]
QUOTED = re.compile(r"""["'](%s)["']""" % "|".join(map(re.escape, NAMES)))


def test_the_generic_layers_are_found():
    assert len(GENERIC) > 30 and all(path.is_file() for path in GENERIC)
    assert PACKAGE / "models" / "training.py" in GENERIC
    assert MODEL_MODULES == {"__init__.py", "cmal.py", "cmal_config.py", "bigan.py",
                             "bigan_config.py"}


@pytest.mark.parametrize("path", GENERIC, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_a_generic_module_names_no_built_in_method(path):
    found = [f"{path.name}:{n}: {line.strip()}"
             for n, line in enumerate(path.read_text().splitlines(), 1)
             if QUOTED.search(line)]
    assert not found, "names a built-in method instead of asking its entry:\n" + "\n".join(found)
