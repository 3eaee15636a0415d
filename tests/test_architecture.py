"""The library's layering rules (docs/architecture.md, section 2), checked on the source.

* no import cycle between modules of src/sonardet, counting imports inside functions;
* no module imports a private name (`_name`) from another module;
* no function (or method) longer than 80 lines;
* a module never imports a module of a higher layer;
* workflow scripts never recover names from directory depth (`parent.parent.name`).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
PKG = SRC / "sonardet"
MAX_FUNCTION_LINES = 80

#: Layer of each top-level part of the package (docs/architecture.md); a module may import only
#: modules of its own layer or lower ones.
LAYERS = {
    "sonardet": 0, "sonardet.seeds": 0, "sonardet.geometry": 0,
    "sonardet.io": 1,
    "sonardet.objects": 2,
    "sonardet.sim": 3, "sonardet.eval": 3,
    "sonardet.detect": 4,
    "sonardet.survey": 5,
    "sonardet.methods": 6,
    "sonardet.experiments": 7, "sonardet.report": 7,
    "sonardet.config": 8, "sonardet.workflow": 8, "sonardet.cli": 8, "sonardet.warm": 8,
}


def _modules() -> dict[str, Path]:
    out = {}
    for f in sorted(PKG.rglob("*.py")):
        rel = f.relative_to(SRC).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        out[".".join(parts)] = f
    return out


MODULES = _modules()


def _targets(module: str, node) -> list[tuple[str, str | None]]:
    """(imported module, imported name or None) of an import statement in `module`."""
    if isinstance(node, ast.Import):
        return [(a.name, None) for a in node.names]
    base = module.split(".")
    if node.level:
        keep = len(base) - node.level + (1 if MODULES[module].name == "__init__.py" else 0)
        target = ".".join(base[:keep] + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    return [(target, a.name) for a in node.names]


def _imports() -> dict[str, list[tuple[str, str | None, int]]]:
    """module -> [(imported sonardet module, imported name, line)] (every import, also in functions)."""
    out = {}
    for m, f in MODULES.items():
        rows = []
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            for target, name in _targets(m, node):
                if not target.startswith("sonardet"):
                    continue
                full = f"{target}.{name}" if name else target
                dep = full if full in MODULES else target if target in MODULES else None
                if dep is not None:
                    rows.append((dep, name, node.lineno))
        out[m] = rows
    return out


IMPORTS = _imports()


def _edges() -> dict[str, set[str]]:
    edges = {}
    for m, rows in IMPORTS.items():
        # A package's __init__ importing its own submodules is not a dependency of those submodules.
        edges[m] = {d for d, _, _ in rows if d != m and not (MODULES[d].name == "__init__.py" and m.startswith(d + "."))}
    return edges


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = 0
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def _layer(module: str) -> int:
    parts = module.split(".")
    for k in range(len(parts), 0, -1):
        key = ".".join(parts[:k])
        if key in LAYERS:
            return LAYERS[key]
    raise KeyError(module)


def test_every_module_has_a_layer():
    missing = []
    for m in MODULES:
        try:
            _layer(m)
        except KeyError:
            missing.append(m)
    assert not missing, f"modules without a layer in LAYERS (add them, and to docs/architecture.md): {missing}"


def test_no_import_cycles():
    cycles = _cycles(_edges())
    assert not cycles, "import cycles (imports inside functions count): " + "; ".join(" <-> ".join(c) for c in cycles)


def test_no_private_names_across_modules():
    bad = [f"{m}:{line} imports {d}.{name}" for m, rows in IMPORTS.items() for d, name, line in rows
           if name and name.startswith("_") and not name.startswith("__") and d != m]
    assert not bad, "private names imported from other modules: " + "; ".join(bad)


def test_lower_layers_do_not_import_higher_ones():
    bad = [f"{m} (layer {_layer(m)}):{line} imports {d} (layer {_layer(d)})" for m, rows in IMPORTS.items()
           for d, _, line in rows if _layer(d) > _layer(m)]
    assert not bad, "layering violations (docs/architecture.md section 2): " + "; ".join(bad)


def test_functions_are_short():
    long = []
    for m, f in MODULES.items():
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{m}.{node.name} ({n} lines)")
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: " + ", ".join(long)


def test_workflow_scripts_do_not_parse_paths():
    scripts = sorted((ROOT / "workflow_scripts").glob("*.py"))
    bad = [p.name for p in scripts if "parent.parent.name" in p.read_text(encoding="utf-8")]
    assert not bad, f"scripts recovering names from directory depth: {bad}"


def test_cycle_finder_finds_a_cycle():
    """The checker itself: a two-module cycle and a three-module one are found, a chain is not."""
    assert _cycles({"a": {"b"}, "b": {"a"}}) == [["a", "b"]]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


@pytest.mark.parametrize("literal", ["results/"])
def test_no_results_paths_in_the_library(literal):
    """The results/ layout lives in the workflow (rules/common.smk), not in the library."""
    bad = []
    for m, f in MODULES.items():
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith(literal):
                bad.append(f"{m}:{node.lineno} {node.value!r}")
    assert not bad, "results/ path literals in src/: " + "; ".join(bad)
