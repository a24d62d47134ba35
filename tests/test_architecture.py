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


def test_every_flag_of_run_is_an_option_of_the_library_and_back():
    """``rooftrace run``'s flags and the library's options cannot drift apart.

    Every flag is a scalar field of :class:`RunOptions` (``--no-planes``
    sets ``planes``), a field of :class:`TileOptions`, a keyword of
    :func:`run_tiled` / :func:`run_pipeline`, or an input/output of the
    command; every scalar field of both options classes that a user sets per
    run has a flag (the stage tables are the config file's).
    """
    import dataclasses
    import inspect

    import typer.main

    from rooftrace.cli.main import app
    from rooftrace.cli.options import flag_for
    from rooftrace.config import SECTIONS, RunOptions
    from rooftrace.pipeline import run_pipeline
    from rooftrace.tiling import TileOptions, run_tiled

    command = typer.main.get_command(app).commands["run"]
    flags = {p.name: p for p in command.params}
    run_fields = {f.name: f for f in dataclasses.fields(RunOptions)}
    # the fields that are not a stage's options dataclass
    scalar = {n for n, f in run_fields.items() if not dataclasses.is_dataclass(f.default_factory)}
    tile_fields = {f.name for f in dataclasses.fields(TileOptions)}
    keywords = set(inspect.signature(run_tiled).parameters) | set(inspect.signature(run_pipeline).parameters)
    command_only = {"inputs", "outputs", "config", "json_", "overwrite", "quiet", "footprint_id"}
    renamed = {"no_planes": "planes"}
    for name, param in flags.items():
        field = renamed.get(name, name)
        assert field in scalar | tile_fields | keywords | command_only, f"flag of run {name!r} maps to no option"
        if field in scalar | tile_fields and param.opts:
            assert flag_for(name) in param.opts, (name, param.opts)  # library errors spell it so
    # the stage options of a run come from the config's tables, each one a known section
    assert all(name in [renamed.get(f, f) for f in flags] for name in scalar)
    config_only = {"chunk_size", "sample_points"}  # [tiling] tuning, not per run
    assert tile_fields - config_only <= set(flags), tile_fields - config_only - set(flags)
    assert SECTIONS["tiling"] is TileOptions and SECTIONS["run"] is RunOptions


def test_helpers_that_cross_modules_are_public():
    """No module imports another's ``_private`` name, nor a ``_private`` module of another package.

    A helper two modules share is part of the package's design: it gets a
    public name in a module named by its role.  (A package's own
    ``_kernels`` module stays private to that package.)
    """
    crossing = []
    for path in PACKAGE.rglob("*.py"):
        name = _module_name(path)
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if not isinstance(node, ast.ImportFrom) or not (node.module or "").startswith("rooftrace"):
                continue
            private = [a.name for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
            if private and node.module != name:
                crossing.append(f"{name}:{node.lineno} imports {', '.join(private)} from {node.module}")
            parts = node.module.split(".")
            for i, part in enumerate(parts):
                if part.startswith("_") and not part.startswith("__") and ".".join(parts[:i]) != package:
                    crossing.append(f"{name}:{node.lineno} imports the private module {node.module}")
    assert not crossing, "\n".join(crossing)
