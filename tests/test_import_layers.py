"""Imports run one way: every import between graphtrack / factors modules (those
inside functions included) goes down the layer order, and no two modules import
each other, directly or through others.

Layers, lowest first (a unit may import any unit below it, never one above):

    errors < threads (< study, commands);  allocator (< track);  errors < geometry < robot < io < detect < factors < estimate < eval < track < study < commands < cli
                                    detect < sim < training < commands

``sim`` renders recordings (geometry, robot, io, detect), ``training`` trains
the learned detector on them, ``eval`` holds the metrics and overlays that the
tracking loop writes, ``study`` runs many tracking runs.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: unit -> the units it may import directly (the allowed set is the transitive closure)
BELOW = {
    "errors": set(),
    "threads": {"errors"},   # graphtrack/threads.py: thread pools, set before numpy loads
    "allocator": set(),      # graphtrack/allocator.py: malloc thresholds (ctypes only)
    "geometry": {"errors"},
    "robot": {"geometry"},
    "io": {"robot"},
    "detect": {"io"},
    "factors": {"detect"},
    "estimate": {"factors"},
    "eval": {"estimate"},
    "track": {"eval", "allocator"},   # a tracking run keeps its freed frame buffers
    "study": {"track", "threads"},   # study workers run one thread each (limit_threads)
    "sim": {"detect"},
    "training": {"sim"},
    "commands": {"study", "training", "threads"},
    "cli": {"commands"},
    "data": set(),
    "graphtrack": set(),   # graphtrack/__init__.py
}


def _closure(unit: str) -> set[str]:
    seen, todo = set(), list(BELOW[unit])
    while todo:
        u = todo.pop()
        if u not in seen:
            seen.add(u)
            todo.extend(BELOW[u])
    return seen


def _modules() -> dict[str, Path]:
    mods = {}
    for top in ("graphtrack", "factors"):
        for f in sorted((ROOT / top).rglob("*.py")):
            parts = list(f.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = f
    return mods


def _unit(module: str) -> str:
    parts = module.split(".")
    if parts[0] == "factors":
        return "factors"
    return parts[1] if len(parts) > 1 else "graphtrack"


def _imports(module: str, path: Path, mods: dict[str, Path]) -> list[tuple[str, int]]:
    """(imported project module, line) for every import statement in the file, at any depth.
    ``from pkg import name`` counts as importing pkg.name when that is a module, else pkg."""
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: len(module.split(".")) - node.level + (1 if is_pkg else 0)]
                src = ".".join(base + ([node.module] if node.module else []))
            else:
                src = node.module or ""
            targets = [f"{src}.{a.name}" if f"{src}.{a.name}" in mods else src for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in mods:
                t = t.rpartition(".")[0]
            if t and t != module:
                out.append((t, node.lineno))
    return out


def _graph():
    mods = _modules()
    return mods, {m: _imports(m, p, mods) for m, p in mods.items()}


def test_every_unit_has_a_layer():
    mods, _ = _graph()
    assert {_unit(m) for m in mods} <= set(BELOW)


def test_no_import_runs_upward():
    _, graph = _graph()
    bad = []
    for m, imps in graph.items():
        u = _unit(m)
        for t, line in imps:
            v = _unit(t)
            if v != u and v not in _closure(u):
                bad.append(f"{m}:{line} imports {t} ({u} may not import {v})")
    assert not bad, "\n".join(bad)


def test_no_import_cycle():
    """Tarjan's strongly connected components of the module graph: all of size one.
    A package's __init__ importing its own submodules is an edge like any other."""
    _, graph = _graph()
    edges = {m: sorted({t for t, _ in imps}) for m, imps in graph.items()}
    index, low, stack, on, cycles, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in edges:
        if v not in index:
            visit(v)
    assert not cycles, cycles


def test_the_checker_sees_imports_inside_functions(tmp_path):
    """The walk reaches an import nested in a function (oracle: a two-line module)."""
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from graphtrack.track import track\n")
    mods = {"graphtrack.track": Path("x"), "graphtrack.io.m": f}
    assert _imports("graphtrack.io.m", f, mods) == [("graphtrack.track", 2)]
