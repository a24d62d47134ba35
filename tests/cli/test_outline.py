"""``rooftrace outline`` through the command line (in process, via main())."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pyproj
import pytest
import shapely

from rooftrace.cli.main import main
from rooftrace.evaluate.metrics import area_scores, polis
from rooftrace.io.vector import read_layer
from tests.conftest import CITY3D, need
from tests.contour.shapes import L_SHAPE, RECT, sample


def _las(path, xyz, classification, building_id=None, crs="EPSG:28992"):
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales = [0.001] * 3
    header.offsets = [float(np.floor(xyz[:, 0].min())), float(np.floor(xyz[:, 1].min())), 0.0]
    header.add_crs(pyproj.CRS.from_user_input(crs))
    if building_id is not None:
        header.add_extra_dim(laspy.ExtraBytesParams(name="building_id", type=np.int32))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.classification = classification
    if building_id is not None:
        las.building_id = building_id
    las.write(path)
    return path


def _scene():
    shift = np.array([85000.0, 447000.0, 0.0])
    a = sample(RECT, 10, seed=1) + shift
    b = sample(shapely.affinity.translate(L_SHAPE, 40, 0), 10, seed=2) + shift
    rng = np.random.default_rng(3)
    ground = np.column_stack([rng.uniform(-10, 70, 3000), rng.uniform(-10, 25, 3000), np.zeros(3000)]) + shift
    xyz = np.concatenate([a, b, ground])
    cls = np.concatenate([np.full(len(a) + len(b), 6), np.full(len(ground), 2)]).astype(np.uint8)
    return xyz, cls, len(a), len(b), shift


@pytest.mark.parametrize("with_ids", [False, True])
def test_outline_class6_las(tmp_path, capsys, with_ids):
    xyz, cls, na, nb, shift = _scene()
    ids = np.concatenate([np.full(na, 5), np.full(nb, 2), np.zeros(len(xyz) - na - nb)]).astype(np.int32)
    src = _las(tmp_path / "scene.laz", xyz, cls, ids if with_ids else None)
    out = tmp_path / "out.gpkg"
    assert main([ "outline", str(src), "-o", str(out), "--json", "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["buildings"] == 2 and summary["status"] == {"ok": 2}
    layer = read_layer(out, "roof_outlines")
    assert layer.crs.to_epsg() == 28992
    assert len(layer) == 2 and all(g.has_z for g in layer.geometries)
    if with_ids:
        assert sorted(layer.attributes["building_id"]) == [2, 5]
    truths = [shapely.affinity.translate(t, *shift[:2]) for t in (RECT, shapely.affinity.translate(L_SHAPE, 40, 0))]
    for truth in truths:
        best = max(layer.geometries, key=lambda g: g.intersection(truth).area)
        assert polis(best, truth) < 0.2
        assert area_scores(best, truth)["f_score"] > 0.97


def test_single_building_ply_and_text(tmp_path, capsys):
    xyz = sample(RECT, 10, seed=4)
    txt = tmp_path / "house.xyz"
    np.savetxt(txt, xyz)
    xyz2 = sample(L_SHAPE, 10, seed=5)
    txt2 = tmp_path / "annex.txt"
    np.savetxt(txt2, xyz2)
    out = tmp_path / "o.gpkg"
    assert main(["outline", str(txt), str(txt2), "--single-building", "-o", str(out), "--alpha", "building",
                 "--quiet"]) == 0
    layer = read_layer(out, "roof_outlines")
    assert layer.attributes["source"] == ["house.xyz", "annex.txt"]
    assert layer.attributes["alpha_strategy"] == ["building", "building"]
    assert polis(layer.geometries[0], RECT) < 0.2
    # refuses to overwrite, then does with --overwrite
    assert main(["outline", str(txt), "--single-building", "-o", str(out), "--quiet"]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["outline", str(txt), "--single-building", "-o", str(out), "--overwrite", "--quiet"]) == 0


def test_bad_input(tmp_path, capsys):
    xyz = sample(RECT, 10)
    txt = tmp_path / "a.xyz"
    np.savetxt(txt, xyz)
    out = tmp_path / "o.gpkg"
    assert main(["outline", str(txt), "-o", str(out)]) == 2
    assert "--single-building" in capsys.readouterr().err
    assert main(["outline", str(txt), "--single-building", "--alpha", "triangle", "-o", str(out)]) == 2
    assert "--alpha" in capsys.readouterr().err
    cfg = tmp_path / "c.toml"
    cfg.write_text("[alpha]\nradiuss = 2\n")
    assert main(["outline", str(txt), "--single-building", "--config", str(cfg), "-o", str(out)]) == 2
    assert "radiuss" in capsys.readouterr().err
    assert not out.exists()


def test_city3d_single_buildings_real(tmp_path):
    folder = need(CITY3D / "instances_002")
    feats = json.loads((folder / "002_footprint.geojson").read_text())["features"][:8]
    files = [str(folder / f["properties"]["instance_ply"]) for f in feats]
    out = tmp_path / "c.gpkg"
    assert main(["outline", *files, "--single-building", "-o", str(out), "--quiet"]) == 0
    layer = read_layer(out, "roof_outlines")
    assert layer.crs is None
    by_source = dict(zip(layer.attributes["source"], layer.geometries))
    p, f = [], []
    for feat in feats:
        truth = shapely.geometry.shape(feat["geometry"])
        got = by_source[feat["properties"]["instance_ply"]]
        p.append(polis(got, truth))
        f.append(area_scores(got, truth)["f_score"])
    assert np.mean(p) < 0.15 and np.mean(f) > 0.95
