"""Units stay readable: no function over MAX_FUNCTION_LINES and no module over
MAX_MODULE_LINES in graphtrack/ and factors/, except the few in ALLOWED, each
with its reason. A unit that grows past a limit is split by concept (one
concept per module) or by step (a function per step of its docstring's math).

Run as a script (``python3 tests/test_code_size.py [FUNC MODULE]``) to list the
units over any limits, e.g. ``70 350`` to find the next candidates.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_FUNCTION_LINES = 80   #: def line to last line, docstring included (issue #22: ~80)
MAX_MODULE_LINES = 400   #: issue #22: ~400

#: "path" (a module) or "path:qualified.name" (a function) -> why it may stay over its limit.
#: estimate/ and factors/ are being edited on other branches: an offender a merge brings
#: there goes here as "in progress" (none on main when this test was written).
ALLOWED: dict[str, str] = {}


def _functions(tree: ast.AST, prefix: str = ""):
    """(qualified name, lines) of every function and method, nested ones included."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            name = prefix + node.name
            yield name, node.end_lineno - node.lineno + 1
            yield from _functions(node, name + ".")
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, prefix + node.name + ".")
        else:
            yield from _functions(node, prefix)


def oversized(max_function: int = MAX_FUNCTION_LINES, max_module: int = MAX_MODULE_LINES,
              root: Path = ROOT) -> dict[str, int]:
    """{"path" or "path:function": lines} of the units over the limits."""
    out = {}
    for top in ("graphtrack", "factors"):
        for f in sorted((root / top).rglob("*.py")):
            rel = f.relative_to(root).as_posix()
            src = f.read_text()
            n = len(src.splitlines())
            if n > max_module:
                out[rel] = n
            for name, lines in _functions(ast.parse(src, rel)):
                if lines > max_function:
                    out[f"{rel}:{name}"] = lines
    return out


def test_no_unit_over_the_limits_outside_the_allow_list():
    new = {k: v for k, v in oversized().items() if k not in ALLOWED}
    assert not new, ("over the limits (split it, or allow it with a reason): "
                     + ", ".join(f"{k} ({v} lines)" for k, v in sorted(new.items())))


def test_every_allow_list_entry_is_still_needed_and_has_a_reason():
    found = oversized()
    stale = [k for k in ALLOWED if k not in found]
    assert not stale, f"back under the limits, remove from ALLOWED: {stale}"
    assert all(reason.strip() for reason in ALLOWED.values())


def test_the_counter_sees_methods_and_nested_functions(tmp_path):
    """Oracle: a hand-written module with a 3-line method and a 4-line nested function."""
    (tmp_path / "graphtrack").mkdir()
    (tmp_path / "graphtrack" / "m.py").write_text(
        "class C:\n    def f(self):\n        x = 1\n        return x\n\n"
        "def g():\n    def h():\n        a = 1\n        b = 2\n        return a + b\n    return h\n")
    got = oversized(max_function=2, max_module=10, root=tmp_path)
    assert got == {"graphtrack/m.py": 11, "graphtrack/m.py:C.f": 3, "graphtrack/m.py:g": 6,
                   "graphtrack/m.py:g.h": 4}


if __name__ == "__main__":
    limits = [int(a) for a in sys.argv[1:3]] or [MAX_FUNCTION_LINES, MAX_MODULE_LINES]
    for unit, lines in sorted(oversized(*limits).items()):
        print(f"{lines:5d}  {unit}{'  (allowed: ' + ALLOWED[unit] + ')' if unit in ALLOWED else ''}")
