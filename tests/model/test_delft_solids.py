"""Real data: the solids of a Delft block with its BGT footprints, written and read back, pass the own check."""

from __future__ import annotations

import json

import numpy as np
import shapely

from rooftrace.footprints import Footprints
from rooftrace.io.footprints import read_footprints
from rooftrace.io.models import write_models
from rooftrace.io.points import read_points
from rooftrace.model import Solid, Surface, solid_errors
from rooftrace.pipeline import run_pipeline
from tests.cityjson_schema import assert_valid_cityjsonseq
from tests.conftest import DELFT, need

#: a block of the west tile: terraced rows with shared walls, dormers and sheds (22 footprints)
BLOCK = shapely.box(84900, 447520, 84960, 447560)


def _read_back(path):
    """Every solid of a CityJSONSeq file as ``(CityObject id, lod, Solid)``, from its integer vertices."""
    lines = path.read_text().splitlines()
    t = json.loads(lines[0])["transform"]
    for line in lines[1:]:
        doc = json.loads(line)
        v = np.asarray(doc["vertices"], dtype=np.float64).reshape(-1, 3) * t["scale"] + t["translate"]
        for coid, obj in doc["CityObjects"].items():
            for g in obj.get("geometry", []):
                kinds = [g["semantics"]["surfaces"][i]["type"] for i in g["semantics"]["values"][0]]
                yield coid, g["lod"], Solid([Surface([v[r] for r in s], k) for s, k in zip(g["boundaries"][0], kinds)])


def test_every_solid_of_a_delft_block_is_valid_after_writing(tmp_path):
    cloud = read_points([need(DELFT / "ahn3_cropped_1.laz")], crs="EPSG:7415")
    fps = read_footprints(need(DELFT / "bgt_pand.sqlite"), cloud.crs)
    keep = [i for i, p in enumerate(fps.polygons) if p.intersects(BLOCK)]
    fps = Footprints(tuple(fps.polygons[i] for i in keep), tuple(fps.ids[i] for i in keep), fps.id_field)
    x0, y0, x1, y1 = shapely.total_bounds(np.asarray(fps.polygons, dtype=object)) + [-5, -5, 5, 5]
    cloud = cloud.subset((cloud.x >= x0) & (cloud.x <= x1) & (cloud.y >= y0) & (cloud.y <= y1))
    result = run_pipeline(cloud, footprints=fps)
    # the roof faces tile each outline: a face lost from the partition leaves a hole that the solid's builder
    # fills with a neighbour's plane, extended far beyond its points (a 50-degree face rose 10 m over a lower roof)
    holes = {st.building_id: round(shapely.difference(st.outline, shapely.union_all(
        [shapely.force_2d(f) for f in st.faces])).area, 2) for st in result.structures if st.faces}
    assert {b: a for b, a in holes.items() if a > 0.01} == {}
    path = tmp_path / "block.city.jsonl"
    write_models([path], result.models, cloud.crs)
    assert_valid_cityjsonseq(path)
    statuses = [m.attributes for m in result.models]
    # no level was left out for being invalid (the builder drops those and says so)
    assert not any("invalid solid" in str(a["status_reason"]) for a in statuses), statuses
    solids = list(_read_back(path))
    lods = [lod for _, lod, _ in solids]
    assert len(fps) >= 20 and lods.count("1.2") == lods.count("1.3") >= len(fps) - 2
    # every building with points has a LoD 2.2: its roof planes, or flat (the LoD 1.3 solid) with the reason
    assert lods.count("2.2") == lods.count("1.2")
    assert all(a["status"] == "ok" or (a["status"] == "flat_lod22" and "lod22: flat" in a["status_reason"])
               for a in statuses), statuses
    # the check val3dity would make: vertices within 1 mm of each other are one, triangles within 20 degrees
    bad = [(coid, lod, errors[:2]) for coid, lod, solid in solids if (errors := solid_errors(solid))]
    assert bad == []


def test_lidar_only_parts_of_a_delft_row_do_not_overlap():
    from rooftrace.model.validity import overlapping_parts

    # terraced houses split into parts without footprints; opening a saddle vertex on a party wall
    # once bent one side of it by a lattice step into the neighbour (val3dity error 601)
    cloud = read_points([need(DELFT / f"ahn3_cropped_{i}.laz") for i in (1, 2)], crs="EPSG:7415")
    x0, y0, x1, y1 = 84809, 447598, 84877, 447644
    cloud = cloud.subset((cloud.x >= x0) & (cloud.x <= x1) & (cloud.y >= y0) & (cloud.y <= y1))
    models = run_pipeline(cloud).models
    assert max(len(m.parts) for m in models) >= 5
    assert all("2.2" in p.lods for m in models for p in m.parts)
    for m in models:
        for lod in ("1.2", "1.3", "2.2"):
            solids = [p.lods[lod] for p in m.parts if lod in p.lods]
            assert overlapping_parts(solids) == [], (m.building_id, lod)
            assert all(solid_errors(s) == [] for s in solids)
