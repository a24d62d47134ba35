"""The package's import structure: the library never imports the CLI, and no module imports itself in a circle.

Imports are read with ``ast`` from the sources, function-level imports
included, so a cycle hidden in a function body counts too.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "rooftrace"
CLI_ONLY = ("rooftrace.cli", "typer", "click")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, name: str | None = None) -> list[tuple[str, int]]:
    """Every module a file imports (absolute names), with the line, wherever the import statement is."""
    name = name or _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                module = f"{base}.{node.module}" if node.module else base
            else:
                module = node.module or ""
            # `from pkg import mod` imports the submodule when there is one
            found += [(f"{module}.{alias.name}", node.lineno) for alias in node.names] + [(module, node.lineno)]
    return found


def _graph() -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        edges = set()
        for target, _ in _imports(path):
            if target in modules and target != name:
                edges.add(target)
        graph[name] = edges
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph (a list of modules, first == last), or None."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return [*stack[stack.index(nxt):], nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def _package_edges(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The graph without the edges from a package's ``__init__`` to its own modules.

    ``pkg/__init__.py`` re-exporting ``pkg.mod`` while ``pkg.mod`` imports
    ``pkg.other`` (which runs ``pkg/__init__``) is how Python packages work,
    not a cycle between concepts; every other edge counts.
    """
    out = {}
    for node, targets in graph.items():
        is_package = (PACKAGE.parent / node.replace(".", "/") / "__init__.py").exists()
        out[node] = {t for t in targets if not (is_package and t.startswith(node + "."))}
    return out


def test_the_import_reader_sees_function_level_and_relative_imports(tmp_path):
    probe = tmp_path / "_probe.py"
    probe.write_text("import os\nfrom . import sibling\n\ndef f():\n    from rooftrace.cli.app import app\n")
    names = {n for n, _ in _imports(probe, "rooftrace.roof._probe")}
    assert {"os", "rooftrace.roof.sibling", "rooftrace.cli.app"} <= names


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_the_library_never_imports_the_cli_typer_or_click():
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if _module_name(path).startswith("rooftrace.cli") or path.name == "__main__.py":
            continue  # ``python -m rooftrace`` is the command line's second door, not library code
        for target, line in _imports(path):
            if any(target == m or target.startswith(m + ".") for m in CLI_ONLY):
                offenders.append(f"{path.relative_to(SRC)}:{line} imports {target}")
    assert not offenders, "\n".join(offenders)


def test_no_import_cycles_among_modules():
    cycle = _cycle(_package_edges(_graph()))
    assert cycle is None, " -> ".join(cycle)
