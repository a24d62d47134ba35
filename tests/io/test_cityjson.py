"""CityJSON / CityJSONSeq / OBJ writers: schema-valid, integer vertices that give back the model, streamed."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
import shapely

from rooftrace.errors import InputError, OutputExistsError
from rooftrace.io.cityjson import CityJSONSeqWriter, reference_system
from rooftrace.io.models import output_format, write_models
from rooftrace.model import build_model, solid_errors
from rooftrace.roof import RoofStructure
from tests.cityjson_schema import assert_valid_cityjson, assert_valid_cityjsonseq
from tests.model.cases import gable, stepped

RD = pyproj.CRS("EPSG:28992")


def _models():
    out = []
    for bid, (case, x0) in enumerate([(gable, 85000.0), (stepped, 85050.0)], start=1):
        cells, _ = case()
        moved = [(shapely.affinity.translate(c, x0, 447000.0), p.copy()) for c, p in cells]
        for _, p in moved:
            p[3] -= p[0] * x0 + p[1] * 447000.0
        outline = shapely.union_all([c for c, _ in moved])
        rng = np.random.default_rng(bid)
        xy = np.column_stack([rng.uniform(*outline.bounds[::2], 3000), rng.uniform(*outline.bounds[1::2], 3000)])
        xy = xy[shapely.contains_xy(outline, xy[:, 0], xy[:, 1])]

        roof = RoofStructure(planes=np.array([p for _, p in moved]), faces=[c for c, _ in moved],
                             face_plane=list(range(len(moved))))  # what the roof stage gives
        z = np.full(len(xy), np.nan)
        for c, p in moved:
            inside = shapely.contains_xy(c, xy[:, 0], xy[:, 1])
            z[inside] = -(p[0] * xy[inside, 0] + p[1] * xy[inside, 1] + p[3]) / p[2]
        keep = np.isfinite(z)
        parts = None if bid == 1 else [shapely.box(85050, 447000, 85055, 447012), shapely.box(85055, 447000, 85060, 447012)]
        out.append(build_model(outline, roof, np.column_stack([xy[keep], z[keep]]), 0.5, parts=parts,
                               building_id=bid))
    return out


def test_cityjson_is_schema_valid_and_gives_back_the_vertices(tmp_path):
    models = _models()
    path = tmp_path / "a.city.json"
    assert write_models([path], models, RD) == 2
    doc = assert_valid_cityjson(path)
    assert doc["metadata"]["referenceSystem"] == "https://www.opengis.net/def/crs/EPSG/0/28992"
    types = sorted(o["type"] for o in doc["CityObjects"].values())
    assert types == ["Building", "Building", "BuildingPart", "BuildingPart"]
    t = doc["transform"]
    v = np.asarray(doc["vertices"]) * t["scale"] + t["translate"]
    roof = doc["CityObjects"]["b1"]["geometry"][-1]
    assert roof["lod"] == "2.2"
    shell = roof["boundaries"][0]
    back = [v[ring] for surface in shell for ring in surface]
    want = [r for s in models[0].parts[0].lods["2.2"].surfaces for r in s.rings]
    assert all(np.allclose(a, b, atol=5e-4) for a, b in zip(back, want))
    ext = doc["metadata"]["geographicalExtent"]
    assert ext[0] == pytest.approx(v[:, 0].min(), abs=1e-3) and ext[5] == pytest.approx(v[:, 2].max(), abs=1e-3)
    kinds = roof["semantics"]["surfaces"]
    assert {k["type"] for k in kinds} == {"RoofSurface", "WallSurface", "GroundSurface"}


def test_cityjsonseq_lines_are_valid_and_the_parts_are_children(tmp_path):
    path = tmp_path / "a.city.jsonl"
    write_models([path], _models(), RD)
    lines = assert_valid_cityjsonseq(path)
    assert len(lines) == 3
    second = lines[2]["CityObjects"]
    assert second["b2"]["children"] == ["b2-1", "b2-2"] and second["b2-1"]["parents"] == ["b2"]
    assert second["b2"]["attributes"]["building_id"] == 2


def test_one_pass_writes_all_formats_and_the_same_bytes_twice(tmp_path):
    models = _models()
    first = [tmp_path / "a.city.jsonl", tmp_path / "a.city.json", tmp_path / "a.obj"]
    again = [tmp_path / "b.city.jsonl", tmp_path / "b.city.json", tmp_path / "b.obj"]
    write_models(first, iter(models), RD)
    write_models(again, iter(models), RD)
    assert [p.read_bytes() for p in first] == [p.read_bytes() for p in again]
    obj = first[2].read_text().splitlines()
    assert sum(line.startswith("o ") for line in obj) == 2 and any(line == "g RoofSurface" for line in obj)
    n = sum(line.startswith("v ") for line in obj)
    faces = [list(map(int, line.split()[1:])) for line in obj if line.startswith("f ")]
    assert min(map(min, faces)) == 1 and max(map(max, faces)) == n


def test_an_existing_output_is_kept_and_a_failed_write_leaves_nothing(tmp_path):
    path = tmp_path / "a.city.jsonl"
    path.write_text("old")
    with pytest.raises(OutputExistsError):
        write_models([path], _models(), RD)

    def broken():
        yield from _models()
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        write_models([path], broken(), RD, overwrite=True)
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.city.jsonl"]


def test_an_empty_run_writes_a_valid_header(tmp_path):
    write_models([tmp_path / "e.city.jsonl", tmp_path / "e.city.json"], [], RD)
    assert len(assert_valid_cityjsonseq(tmp_path / "e.city.jsonl")) == 1
    assert assert_valid_cityjson(tmp_path / "e.city.json")["CityObjects"] == {}


def test_a_compound_crs_keeps_its_height_datum():
    assert reference_system(pyproj.CRS("EPSG:7415")) == "https://www.opengis.net/def/crs/EPSG/0/7415"
    assert reference_system(None) is None


def test_output_format_by_name():
    assert [output_format(p) for p in ("a.city.jsonl", "b.city.json", "c.OBJ", "d.gpkg")] == [
        "cityjsonseq", "cityjson", "obj", "gpkg"]
    for bad in ("a.json", "a.jsonl", "a.geojson", "a"):
        with pytest.raises(InputError, match="unknown output format"):
            output_format(bad)


def test_the_seq_writer_keeps_no_feature_in_memory(tmp_path):
    models = _models()
    with CityJSONSeqWriter(tmp_path / "s.city.jsonl", RD) as w:
        for m in models:
            w.add(m)
        assert not any(isinstance(v, (list, dict)) and len(v) > 3 for v in vars(w).values())
    assert w.count == 2


def test_models_written_are_valid_solids():
    for m in _models():
        for p in m.parts:
            assert set(p.lods) == {"1.2", "1.3", "2.2"}
            assert all(solid_errors(s) == [] for s in p.lods.values())


def test_cjio_reads_the_cityjson_file(tmp_path):
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    cjio = shutil.which("cjio") or str(Path(sys.executable).parent / "cjio")
    if not Path(cjio).exists():
        pytest.skip("cjio (a dev peer: pip install cjio) is not installed")
    path = tmp_path / "a.city.json"
    write_models([path], _models(), RD)
    out = subprocess.run([cjio, str(path), "info"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "Building (2)" in out.stdout and "BuildingPart (2)" in out.stdout and "EPSG = 28992" in out.stdout
