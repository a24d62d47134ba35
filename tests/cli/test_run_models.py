"""`rooftrace run -o ...` writing 3D models: every format from one run, valid, and the same with tiles."""

import json

import numpy as np
import pyogrio
import pytest

from rooftrace.cli.main import main
from rooftrace.io.vector import list_layers, read_layer
from rooftrace.model import Solid, Surface, solid_errors
from tests.cityjson_schema import assert_valid_cityjson, assert_valid_cityjsonseq


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene")
    assert main(["simulate", "-o", str(out), "--size", "60", "--density", "8", "--seed", "4", "-q"]) == 0
    return out / "points.laz"


@pytest.fixture(scope="module")
def outputs(scene, tmp_path_factory):
    d = tmp_path_factory.mktemp("models")
    files = [d / "m.gpkg", d / "m.city.jsonl", d / "m.city.json", d / "m.obj"]
    argv = ["run", str(scene), *[a for f in files for a in ("-o", str(f))], "--json", "-q"]
    return files, argv


def test_one_run_writes_every_format(outputs, capsys):
    files, argv = outputs
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["outputs"] == [str(f) for f in files]
    gpkg, seq, doc, obj = files
    assert list_layers(gpkg) == ["roof_outlines", "ridges", "roof_faces", "lod12", "lod13", "lod22"]
    lod22 = read_layer(gpkg, "lod22")
    assert pyogrio.read_info(gpkg, layer="lod22")["geometry_type"] == "MultiPolygon Z"
    assert set(lod22.attributes["surface_type"]) == {"RoofSurface", "WallSurface", "GroundSurface"}
    lines = assert_valid_cityjsonseq(seq)
    city = assert_valid_cityjson(doc)
    buildings = [o for o in city["CityObjects"].values() if o["type"] == "Building"]
    assert len(lines) - 1 == len(buildings) == sum(summary["models"].values()) >= 1
    assert set(read_layer(gpkg, "roof_outlines").attributes["building_id"]) >= {
        b["attributes"]["building_id"] for b in buildings}
    for b in buildings:
        a = b["attributes"]
        assert a["status"] in ("ok", "partial") and a["h_ground"] < a["h_roof_70p"]
    # the solids read back from the file are valid
    t = city["transform"]
    v = np.asarray(city["vertices"]) * t["scale"] + t["translate"]
    for b in buildings:
        for g in b["geometry"]:
            kinds = [g["semantics"]["surfaces"][i]["type"] for i in g["semantics"]["values"][0]]
            solid = Solid([Surface([v[r] for r in s], k) for s, k in zip(g["boundaries"][0], kinds)])
            assert solid_errors(solid) == [], (b["attributes"]["building_id"], g["lod"])
    assert obj.read_text().startswith("# rooftrace")


def test_tiles_and_workers_give_the_same_model_files(scene, outputs, tmp_path):
    files, argv = outputs
    if not files[1].exists():
        assert main(argv) == 0
    tiled = [tmp_path / "t.gpkg", tmp_path / "t.city.jsonl", tmp_path / "t.city.json"]
    assert main(["run", str(scene), *[a for f in tiled for a in ("-o", str(f))], "--tile-size", "30", "-q"]) == 0
    assert tiled[1].read_bytes() == files[1].read_bytes()
    assert tiled[2].read_bytes() == files[2].read_bytes()
    for layer in ("lod12", "lod22"):
        a, b = read_layer(files[0], layer), read_layer(tiled[0], layer)
        assert [g.wkb for g in a.geometries] == [g.wkb for g in b.geometries]


@pytest.mark.parametrize("args,message", [
    (["-o", "{d}/a.json"], "unknown output format"),
    (["-o", "{d}/a.gpkg", "-o", "{d}/b.gpkg"], "more than one .gpkg"),
    (["-o", "{d}/a.city.jsonl", "-o", "{d}/a.city.jsonl"], "given twice"),
])
def test_bad_outputs_are_refused_before_any_work(scene, tmp_path, capsys, args, message):
    argv = ["run", str(scene)] + [a.format(d=tmp_path) for a in args]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and message in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []
