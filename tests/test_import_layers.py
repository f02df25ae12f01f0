"""The package's import graph has no cycle: ``cmal_lcd``'s packages and top-level modules,
counting every ``cmal_lcd`` import of every module, those inside function bodies too (a lazy
import hides a cycle from Python, not from a reader). docs/architecture.md gives the order."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import networkx as nx

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "cmal_lcd"


def unit(module: str) -> str:
    """``cmal_lcd.data.frames`` -> ``data``; ``cmal_lcd.config`` -> ``config``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] == "cmal_lcd":
            names.update([node.module] if node.module != "cmal_lcd"
                         else [f"cmal_lcd.{a.name}" for a in node.names])
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names if a.name.startswith("cmal_lcd."))
    return names


def import_graph() -> tuple[nx.DiGraph, dict]:
    graph, why = nx.DiGraph(), defaultdict(list)
    for path in PACKAGE.rglob("*.py"):
        module = ".".join(("cmal_lcd", *path.relative_to(PACKAGE).with_suffix("").parts))
        for name in imported_modules(path):
            a, b = unit(module), unit(name)
            if a != b and "cmal_lcd" not in (a, b):
                graph.add_edge(a, b)
                why[a, b].append(f"{module} imports {name}")
    return graph, why


def test_the_packages_import_one_another_without_a_cycle():
    graph, why = import_graph()
    assert {"data", "features", "evaluation", "workflows", "stages"} <= set(graph)
    cycle = next(iter(nx.simple_cycles(graph)), None)
    assert cycle is None, "import cycle: " + "; ".join(
        why[a, b][0] for a, b in zip(cycle, cycle[1:] + cycle[:1]))


def test_the_check_sees_an_import_inside_a_function(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("def f():\n    from cmal_lcd.evaluation import monitor\n")
    assert imported_modules(source) == {"cmal_lcd.evaluation"}
