"""The package's layers: no module imports a module of a higher layer at module level, and the
module-level import graph has no circles (a circle would make import order matter)."""

import ast
from pathlib import Path

import pytest

import sssbake.exporters
import sssbake.pipeline

#: Lowest first; a module may import its own layer and those below it.
LAYERS = (
    ("pipeline.core",),
    ("pipeline.mesh",),
    ("exporters",),
    ("pipeline.render",),
    ("pipeline.techniques",),  # each technique, then technique.py's protocol and registry.py (same layer)
    ("pipeline.options", "pipeline.config"),
    ("pipeline.planning",),
    ("pipeline.bake", "pipeline.verify", "pipeline.view"),
    ("pipeline.doctor",),  # checks the run-time parts the layers below need: the validator, three.js, EGL
    ("pipeline.cli",),
)


def _modules() -> dict[str, Path]:
    out = {}
    for package in (sssbake.pipeline, sssbake.exporters):
        root = Path(package.__file__).parent
        for path in root.rglob("*.py"):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join((package.__name__.split(".")[-1], *parts)).rstrip(".")] = path
    return out


MODULES = _modules()


def _layer(module: str) -> int:
    for i, prefixes in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return i
    return -1  # the packages' __init__ files


def _top_level_imports(path: Path) -> set[str]:
    """sssbake modules `path` imports at module level (inside functions: late bindings, not counted)."""
    found = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("sssbake."):
            base = node.module[len("sssbake."):]
            for alias in node.names:  # `from sssbake.pipeline import x` imports the module x
                found.add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base)
        elif isinstance(node, ast.Import):
            found |= {a.name[len("sssbake."):] for a in node.names if a.name.startswith("sssbake.")}
    return {m for m in found if m in MODULES}


GRAPH = {m: _top_level_imports(p) for m, p in MODULES.items()}


def test_every_module_has_a_layer():
    assert [m for m in MODULES if _layer(m) < 0 and not MODULES[m].name == "__init__.py"] == []


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_only_its_layer_or_lower(module):
    upward = sorted(m for m in GRAPH[module] if _layer(m) > _layer(module))
    assert upward == [], f"{module} (layer {_layer(module)}) imports higher layers: {upward}"


def test_no_import_circles():
    # Tarjan's strongly connected components over the module-level graph
    index, low, stack, on_stack, circles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in GRAPH:
        if v not in index:
            visit(v)
    assert circles == []


def test_techniques_are_independent():
    """A technique's package imports no other technique's package (shared code lives lower)."""
    crossing = sorted((m, i) for m, imports in GRAPH.items() if m.startswith("pipeline.techniques.")
                      for i in imports if i.startswith("pipeline.techniques.")
                      and len(m.split(".")) > 3 and len(i.split(".")) > 3 and m.split(".")[2] != i.split(".")[2])
    assert crossing == []
