"""The house rules of python/rspiv (issue 16), checked on the source tree:

- no import cycle between rspiv modules (top-level imports, the ones that run at import time);
- no Python file over 800 lines;
- no import of an rspiv module inside a function, except a deferred optional dependency
  (matplotlib through ``rspiv.plots``, dask), marked with a ``# deferred:`` comment on its line.
"""

from __future__ import annotations

import ast
import pathlib

import rspiv

PKG = pathlib.Path(rspiv.__file__).resolve().parent
MAX_LINES = 800


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _resolve(name: str, modules: dict[str, pathlib.Path]) -> str | None:
    """The rspiv module (or package) an import of ``name`` loads, None outside rspiv."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def _top_level_imports(path: pathlib.Path, modules: dict[str, pathlib.Path]) -> set[str]:
    tree = ast.parse(path.read_text())
    deps: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module.split(".")[0] != "rspiv":
                continue
            for alias in node.names:
                # "from rspiv import x": x may be a submodule
                target = _resolve(f"{node.module}.{alias.name}", modules)
                if target is not None:
                    deps.add(target)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "rspiv":
                    target = _resolve(alias.name, modules)
                    if target is not None:
                        deps.add(target)
    return deps


def _packages_of(name: str) -> list[str]:
    """Importing ``a.b.c`` first imports ``a`` and ``a.b``."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def test_no_import_cycles():
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps = _top_level_imports(path, modules)
        # a module's own parent packages run before it: not an edge of its own making
        graph[name] = {d for d in deps if d != name and d not in _packages_of(name)}
    # The package __init__ re-exports: an edge into "rspiv" itself is how every submodule
    # starts, so only cycles among submodules count.
    for deps in graph.values():
        deps.discard("rspiv")
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(n: str) -> None:
        state[n] = 1
        stack.append(n)
        for d in sorted(graph.get(n, ())):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d) :] + [d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_no_file_over_800_lines():
    long = {
        str(p.relative_to(PKG)): n
        for p in PKG.rglob("*.py")
        if (n := len(p.read_text().splitlines())) > MAX_LINES
    }
    assert not long, f"files over {MAX_LINES} lines: {long}"


def test_no_function_level_rspiv_imports():
    bad = []
    for p in sorted(PKG.rglob("*.py")):
        text = p.read_text()
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for sub in ast.walk(node):
                if isinstance(sub, ast.ImportFrom):
                    names = [sub.module or ""]
                elif isinstance(sub, ast.Import):
                    names = [a.name for a in sub.names]
                else:
                    continue
                if not any(n == "rspiv" or n.startswith("rspiv.") for n in names):
                    continue
                span = lines[sub.lineno - 1 : sub.end_lineno]
                if not any("# deferred:" in line for line in span):
                    where = f"{p.relative_to(PKG)}:{sub.lineno}"
                    bad.append(f"{where}: {lines[sub.lineno - 1].strip()}")
    assert not bad, "function-level rspiv imports:\n" + "\n".join(bad)
