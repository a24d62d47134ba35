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
