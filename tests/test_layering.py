"""The package's layering (docs/layout.md): no import circle, no import from a layer above.

Two checks of the same rule. The static one reads every ``import`` in frl, those inside
functions included, so a lazy import cannot hide a circle. The dynamic one imports each
module in a fresh interpreter, with frl's modules forgotten between modules, and looks
at which frl modules came with it.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

import frl

PACKAGE_DIR = Path(frl.__file__).resolve().parent

LAYERS: tuple[tuple[str, ...], ...] = (
    ("frl", "frl.fileio", "frl.conf", "frl.cli", "frl.update_count", "frl.retirement"),
    ("frl.run_directory", "frl.envs", "frl.agents"),
    ("frl.episodes", "frl.policies", "frl.recording", "frl.yardsticks", "frl.provenance"),
    ("frl.federation",),
    ("frl.train_config", "frl.run_opening"),
    ("frl.flower", "frl.evaluate"),
    ("frl.training",),
    (
        "frl.train",
        "frl.demo",
        "frl.report",
        "frl.reproduce",
        "frl.side_by_side",
        "frl.launchers",
        "frl.plot",
    ),
)
"""Bottom to top; a module may import its own layer's modules and those below."""

NEEDS = {"frl.flower": "flwr"}
"""Subpackages that import an optional dependency at import time."""


def module_names() -> dict[str, Path]:
    names = {}
    for path in PACKAGE_DIR.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts)
        if "app" in parts[:-1] and parts[:2] == ["frl", "flower"]:
            continue  # the Flower app directory is not a package of frl
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


MODULES = module_names()


def layer_of(module: str) -> int:
    for index, layer in enumerate(LAYERS):
        if any(in_unit(module, unit) for unit in layer):
            return index
    raise AssertionError(f"{module} is in no layer of LAYERS; add it there and to docs/layout.md")


def in_unit(module: str, unit: str) -> bool:
    """``module`` is ``unit`` or inside it; the root ``frl`` is only itself."""
    return module == unit or (unit != "frl" and module.startswith(f"{unit}."))


def static_imports(module: str) -> set[str]:
    """The frl modules ``module`` imports anywhere in its source."""

    def known(name: str) -> str:
        while name not in MODULES:
            name = name.rpartition(".")[0]
        return name

    found = set()
    for node in ast.walk(ast.parse(MODULES[module].read_text())):
        if isinstance(node, ast.Import):
            found |= {known(a.name) for a in node.names if a.name.split(".")[0] == "frl"}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "frl":
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                found.add(full if full in MODULES else known(str(node.module)))
    return found - {module}


def test_every_module_sits_in_a_layer():
    for module in MODULES:
        layer_of(module)


def test_no_module_imports_from_a_layer_above():
    upward = [
        f"{module} (layer {layer_of(module)}) imports {target} (layer {layer_of(target)})"
        for module in MODULES
        for target in static_imports(module)
        if layer_of(target) > layer_of(module)
    ]
    assert upward == []


def test_no_import_circle():
    graph = {module: static_imports(module) for module in MODULES}
    circles = [c for c in strongly_connected(graph) if len(c) > 1]
    assert circles == []


def unit_of(module: str) -> str:
    """The top-level module or folder of frl that ``module`` belongs to."""
    return ".".join(module.split(".")[:2])


def test_no_import_circle_between_folders():
    """Folders and top-level modules, each taken as one node, import in one direction:
    a module of ``report/`` importing ``plot`` while ``plot`` imports ``report.runs`` is a
    circle here even where no two modules import each other."""
    graph: dict[str, set[str]] = {}
    for module in MODULES:
        targets = {unit_of(target) for target in static_imports(module)} - {unit_of(module)}
        graph.setdefault(unit_of(module), set()).update(targets - {"frl"})
    circles = [c for c in strongly_connected(graph) if len(c) > 1]
    assert circles == []


def test_importing_each_module_alone_brings_no_module_from_a_layer_above():
    importable = [
        m
        for m in sorted(MODULES)
        if not any(
            in_unit(m, unit) and importlib.util.find_spec(dep) is None
            for unit, dep in NEEDS.items()
        )
    ]
    script = (
        "import importlib, json, sys\n"
        "loaded = {}\n"
        "for name in json.loads(sys.argv[1]):\n"
        "    for key in [k for k in sys.modules if k == 'frl' or k.startswith('frl.')]:\n"
        "        del sys.modules[key]\n"
        "    importlib.import_module(name)\n"
        "    loaded[name] = sorted(k for k in sys.modules if k == 'frl' or k.startswith('frl.'))\n"
        "print(json.dumps(loaded))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script, json.dumps(importable)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    loaded = json.loads(result.stdout.strip().splitlines()[-1])
    upward = [
        f"importing {module} loads {other}"
        for module, others in loaded.items()
        for other in others
        if other in MODULES and layer_of(other) > layer_of(module)
    ]
    assert upward == []
    assert set(loaded) == set(importable)


@pytest.mark.parametrize(
    "module", ["frl.flower.vehicle", "frl.federation.vehicle_host", "frl.federation.frames"]
)
def test_the_client_apps_relay_modules_stay_light(module):
    """The ClientApp starts afresh for every message: its relay must not pull torch or SUMO."""
    script = (
        f"import sys, {module}; print(sorted(m for m in ('torch', 'libsumo') if m in sys.modules))"
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=True
    )
    assert result.stdout.strip() == "[]"


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of ``graph``."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            components.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return components


def test_docs_layout_lists_every_layer_as_the_code_has_it():
    """docs/layout.md's table names each layer's modules exactly as LAYERS does, so the
    page cannot fall behind the package."""
    page = (PACKAGE_DIR.parent / "docs" / "layout.md").read_text()
    documented: dict[int, set[str]] = {}
    for line in page.splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].isdigit():
            names = {name.rstrip("/") for name in cells[1].replace("`", "").split(", ")}
            documented[int(cells[0])] = {f"frl.{name}" for name in names}
    expected = {index: set(layer) - {"frl"} for index, layer in enumerate(LAYERS)}
    assert documented == expected
