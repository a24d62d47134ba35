"""`rooftrace run --footprints`: one building per footprint, its id in every layer, bad footprint files refused."""

import json

import laspy
import numpy as np
import pyproj
import pytest
import shapely

from rooftrace.cli.main import main
from rooftrace.io.vector import Layer, list_layers, read_layer, write_layers


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene")
    assert main(["simulate", "-o", str(out), "--size", "60", "--density", "8", "--seed", "4", "-q"]) == 0
    truth = read_layer(out / "truth.gpkg", "footprints")
    cloud_box = shapely.box(*read_layer(out / "truth.gpkg", "roof_outlines").geometries[0].bounds)
    # the walls of every building, plus a footprint on open ground at the scene's edge
    free = next(b for b in (shapely.box(*(np.array(cloud_box.bounds[:2]) + d), *(np.array(cloud_box.bounds[:2]) + d + 4))
                            for d in (-25, 25, -20, 20)) if not any(b.intersects(g) for g in truth.geometries))
    geoms = [*truth.geometries, free]
    ids = [f"B{int(b)}" for b in truth.attributes["building_id"]] + ["empty"]
    path = out / "footprints.gpkg"
    write_layers(path, {"pand": Layer(geoms, {"identificatie": ids, "other": list(range(len(ids)))}, "Polygon")},
                 truth.crs)
    return out, path, ids


def test_one_building_per_footprint_with_its_id_in_every_layer(scene, tmp_path, capsys):
    out_dir, fp, ids = scene
    out, laz = tmp_path / "roofs.gpkg", tmp_path / "classified.laz"
    assert main(["run", str(out_dir / "points.laz"), "--footprints", str(fp), "-o", str(out), "--classified",
                 str(laz), "--json", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["footprints"]["count"] == len(ids) and summary["footprints"]["id_field"] == "identificatie"
    outlines = read_layer(out, "roof_outlines")
    assert list(outlines.attributes["footprint_id"]) == ids  # in the file's order
    status = dict(zip(ids, outlines.attributes["footprint_status"]))
    assert status["empty"] in ("no_building_points", "no_points") and outlines.geometries[-1] is None
    assert sum(s == "ok" for s in status.values()) >= len(ids) - 2
    # each traced outline covers its footprint (walls) and reaches beyond it (the simulated overhangs)
    truth = read_layer(fp, "pand")
    for g, f, s in zip(outlines.geometries, truth.geometries, outlines.attributes["footprint_status"]):
        if s == "ok":
            assert shapely.force_2d(g).intersection(f).area > 0.9 * f.area
    assert set(list_layers(out)) >= {"roof_outlines", "ridges", "roof_faces", "building_parts"}
    for name in ("ridges", "roof_faces", "building_parts", "lod12", "lod22"):
        layer = read_layer(out, name)
        assert len(layer) and set(layer.attributes["footprint_id"]) <= set(ids)
    # the classified points carry the footprint building of each point: the ids of the layers
    point_ids = np.asarray(laspy.read(laz)["building_id"])
    ok = [i + 1 for i, s in enumerate(outlines.attributes["footprint_status"]) if s == "ok"]
    assert set(np.unique(point_ids[point_ids > 0])) == set(ok)


@pytest.mark.parametrize("case,message", [
    ("field", "no attribute 'bag'"),
    ("far", "no footprint lies over the point cloud"),
    ("lines", "no polygon layer"),
    ("junk", "not a readable vector file"),
])
def test_bad_footprint_files_give_one_error_line_and_no_output(scene, tmp_path, capsys, case, message):
    out_dir, fp, _ = scene
    args = []
    if case == "field":
        args = ["--footprint-id", "bag"]
    elif case == "far":
        fp = tmp_path / "far.geojson"
        write_layers(fp, {"far": Layer([shapely.box(0, 0, 10, 10)], {"id": [1]}, "Polygon")}, pyproj.CRS(28992))
    elif case == "lines":
        fp = tmp_path / "lines.gpkg"
        write_layers(fp, {"roads": Layer([shapely.LineString([(0, 0), (5, 5)])], {}, "LineString")},
                     pyproj.CRS(28992))
    elif case == "junk":
        fp = tmp_path / "junk.fgb"
        fp.write_bytes(b"\x00" * 64)
    out = tmp_path / "roofs.gpkg"
    assert main(["run", str(out_dir / "points.laz"), "--footprints", str(fp), *args, "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error:") and message in err[-1] and not out.exists()
