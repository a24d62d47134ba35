"""benchmarks/val3dity.py: valid solids per LoD and error codes from val3dity, skipped when it is not built."""

from __future__ import annotations

import importlib.util
import json

import pytest

from tests.conftest import ROOT

_spec = importlib.util.spec_from_file_location("bench_val3dity", ROOT / "benchmarks" / "val3dity.py")
val3dity = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(val3dity)

# a unit cube, faces counter-clockwise seen from outside
VERTICES = [[0, 0, 0], [1000, 0, 0], [1000, 1000, 0], [0, 1000, 0],
            [0, 0, 1000], [1000, 0, 1000], [1000, 1000, 1000], [0, 1000, 1000]]
CUBE = [[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]], [[2, 3, 7, 6]], [[3, 0, 4, 7]]]


def _city(path, shells_by_lod):
    geometry = [{"type": "Solid", "lod": lod, "boundaries": [shell]} for lod, shell in shells_by_lod]
    doc = {"type": "CityJSON", "version": "2.0", "transform": {"scale": [0.001] * 3, "translate": [0, 0, 0]},
           "CityObjects": {"b1": {"type": "Building", "geometry": geometry}}, "vertices": VERTICES}
    path.write_text(json.dumps(doc))
    return path


def test_missing_binary_skips_cleanly(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("VAL3DITY", str(tmp_path / "nowhere"))
    monkeypatch.setattr(val3dity, "DEFAULT_BINARY", tmp_path / "nowhere")
    monkeypatch.setattr(val3dity.shutil, "which", lambda name: None)
    assert val3dity.find_val3dity() is None
    assert val3dity.validate(_city(tmp_path / "a.city.json", [("1.2", CUBE)])) is None
    assert val3dity.main([str(tmp_path / "a.city.json")]) == 0
    assert "build.sh" in capsys.readouterr().err


def test_valid_and_invalid_solids_per_lod(tmp_path):
    if val3dity.find_val3dity() is None:
        pytest.skip(val3dity.BUILD_HINT)
    flipped = [[list(reversed(CUBE[0][0]))], *CUBE[1:]]  # the bottom face points inwards
    res = val3dity.validate(_city(tmp_path / "b.city.json", [("1.2", CUBE), ("2.2", [list(f) for f in flipped])]))
    assert res["lod"]["1.2"] == {"solids": 1, "valid": 1, "share": 1.0}
    assert res["lod"]["2.2"]["valid"] == 0 and res["lod"]["2.2"]["solids"] == 1
    assert res["invalid"] and res["invalid"][0][:2] == ("b1", "2.2")
    assert set(res["errors"]) & {307, 305, 203, 204}  # wrong orientation (or the shell's faces inconsistent)
