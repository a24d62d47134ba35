"""Same input and seed, same answer (issue 10): two runs give identical layers.

A GeoPackage stores the time of writing (``gpkg_contents.last_change``), so
the files are compared layer by layer as read back: exact WKB of every
geometry (coordinates to the last bit) and every attribute value.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from rooftrace.cli.main import main
from rooftrace.io.vector import list_layers, read_layer


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene")
    assert main(["simulate", "-o", str(out), "--size", "40", "--density", "6", "--seed", "3", "-q"]) == 0
    return out


def _same_value(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def assert_same_layers(path_a, path_b) -> None:
    """Every layer of two vector files holds the same geometries (bit for bit) and attributes."""
    names = list_layers(path_a)
    assert names == list_layers(path_b)
    for name in names:
        a, b = read_layer(path_a, name), read_layer(path_b, name)
        assert len(a) == len(b), name
        wkb_a = [None if g is None else shapely.to_wkb(g, output_dimension=3) for g in a.geometries]
        wkb_b = [None if g is None else shapely.to_wkb(g, output_dimension=3) for g in b.geometries]
        assert wkb_a == wkb_b, f"layer {name}: geometries differ"
        assert list(a.attributes) == list(b.attributes), name
        for key in a.attributes:
            va = [v.item() if isinstance(v, np.generic) else v for v in a.attributes[key]]
            vb = [v.item() if isinstance(v, np.generic) else v for v in b.attributes[key]]
            assert all(_same_value(x, y) for x, y in zip(va, vb)), f"layer {name}: attribute {key} differs"
        assert (a.crs is None) == (b.crs is None) and (a.crs is None or a.crs.equals(b.crs))


def test_run_twice_with_the_same_seed_gives_identical_layers(scene, tmp_path):
    outs = [tmp_path / f"run{i}.gpkg" for i in (1, 2)]
    for out in outs:
        assert main(["run", str(scene / "points.laz"), "--image", str(scene / "image.tif"), "--camera",
                     str(scene / "camera.json"), "--seed", "5", "-o", str(out), "-q"]) == 0
    assert len(read_layer(outs[0], "roof_outlines")) >= 1 and len(read_layer(outs[0], "ridges")) >= 1
    assert_same_layers(*outs)


def test_detect_then_outline_twice_gives_identical_results(scene, tmp_path):
    laz = [tmp_path / f"c{i}.laz" for i in (1, 2)]
    for path in laz:
        assert main(["detect", str(scene / "points.laz"), "-o", str(path), "-q"]) == 0
    import laspy

    a, b = laspy.read(laz[0]), laspy.read(laz[1])
    np.testing.assert_array_equal(np.asarray(a.classification), np.asarray(b.classification))
    np.testing.assert_array_equal(np.asarray(a["building_id"]), np.asarray(b["building_id"]))
    outs = [tmp_path / f"o{i}.gpkg" for i in (1, 2)]
    for out in outs:
        assert main(["outline", str(laz[0]), "-o", str(out), "--alpha", "point", "-q"]) == 0
    assert len(read_layer(outs[0], "roof_outlines")) >= 1
    assert_same_layers(*outs)
