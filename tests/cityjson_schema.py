"""CityJSON 2.0.2 schema checks for every CityJSON file the tests write (``../shared/data/cityjson_schemas_2.0.2``)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest

from tests.conftest import DATA

SCHEMAS = DATA / "cityjson_schemas_2.0.2"


@functools.cache
def _validator(name: str):
    jsonschema = pytest.importorskip("jsonschema")
    path = SCHEMAS / name
    if not path.exists():
        pytest.skip(f"CityJSON schemas not available: {SCHEMAS}")
    return jsonschema.Draft7Validator(json.loads(path.read_text()))


def _errors(validator, doc) -> list[str]:
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message[:200]}" for e in validator.iter_errors(doc)][:5]


def assert_valid_cityjson(path: Path) -> dict:
    """A ``.city.json`` file valid against the CityJSON 2.0 schema; returns the document."""
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    assert _errors(_validator("cityjson.min.schema.json"), doc) == []
    return doc


def assert_valid_cityjsonseq(path: Path) -> list[dict]:
    """Every line of a ``.city.jsonl`` file valid (header: CityJSON, then CityJSONFeatures); returns the lines."""
    lines = [json.loads(line) for line in Path(path).read_text(encoding="utf-8").splitlines()]
    assert lines and lines[0]["type"] == "CityJSON" and lines[0]["CityObjects"] == {} and lines[0]["vertices"] == []
    assert _errors(_validator("cityjson.min.schema.json"), lines[0]) == []
    feature = _validator("cityjsonfeature.min.schema.json")
    for line in lines[1:]:
        assert line["type"] == "CityJSONFeature"
        assert _errors(feature, line) == []
    return lines
