"""The generated documentation is current and the top-level API is what the docs promise."""

from __future__ import annotations

import importlib.util
import inspect
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_api_page_is_generated_from_the_current_docstrings():
    make_api = _load(ROOT / "docs" / "make_api.py")
    assert (ROOT / "docs" / "api.md").read_text(encoding="utf-8") == make_api.render(), \
        "docs/api.md is stale: run python docs/make_api.py"


def test_every_top_level_entry_point_is_documented_with_parameters_returns_and_examples():
    import rooftrace

    functions = [n for n in rooftrace.__all__ if inspect.isfunction(getattr(rooftrace, n, None))]
    assert len(functions) >= 8
    for name in functions:
        doc = inspect.getdoc(getattr(rooftrace, name))
        for section in ("Parameters", "Returns", "Examples"):
            assert f"{section}\n---" in doc, f"rooftrace.{name} has no {section} section"


def test_unknown_top_level_names_raise_attribute_error():
    import pytest

    import rooftrace

    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        rooftrace.nonexistent  # noqa: B018


def test_results_table_is_generated_from_the_recorded_figures():
    make_results = _load(ROOT / "benchmarks" / "make_results.py")
    current = (ROOT / "benchmarks" / "RESULTS.md").read_text(encoding="utf-8")
    assert make_results.render(current, make_results.load_all()) == current, \
        "benchmarks/RESULTS.md is stale: run python benchmarks/make_results.py"


def test_user_docs_cite_papers_not_files_issues_or_internal_notes():
    import re

    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for page in pages:
        if page.name == "design-notes.md":
            continue  # the history of the measurements, for maintainers
        text = page.read_text(encoding="utf-8")
        for pattern in (r"\b\d{3}_[0-9a-f]{16}\.txt", r"\bDESIGN\.md", r"\bissue \d+", r"\bseed 00\d"):
            assert not re.search(pattern, text), f"{page.name}: {re.search(pattern, text).group(0)}"
