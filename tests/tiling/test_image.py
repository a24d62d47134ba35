"""Tiled runs with an image: the merged buildings are refined once, as the untiled run refines them."""

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import shapely

from rooftrace.cli.main import main
from rooftrace.io.vector import read_layer
from rooftrace.tiling import TileResult
from rooftrace.tiling.image import cut_neighbourhoods, image_fingerprint, join_neighbourhoods, neighbourhood_points

LAYERS = ("roof_outlines", "ridges", "roof_faces")
# a 60 m scene with four buildings in tiles of 30 m (3 x 3: the scene spills over 60 m); 15 m outlier cells
# keep the buffered tiles at 60 m, so each tile sees only part of the scene
TILED = ["--tile-size", "30", "--buffer", "15"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """Simulated points, image and a camera with an EO covariance (so the refinement corrects the orientation)."""
    d = tmp_path_factory.mktemp("tiled_image")
    assert main(["simulate", "-o", str(d), "--size", "60", "--density", "8", "--seed", "4", "-q"]) == 0
    cam = json.loads((d / "camera.json").read_text())
    sigma = [0.3, 0.3, 0.3, *3 * [np.radians(0.01)]]  # m, rad
    cam["exterior_covariance"] = np.diag(np.square(sigma)).tolist()
    (d / "camera.json").write_text(json.dumps(cam))
    (d / "config.toml").write_text("[outliers]\ncell = 15.0\n")
    return d


def _run(scene, out, *extra, image=True) -> dict:
    """``rooftrace run ... --json``; returns the summary."""
    args = ["run", str(scene / "points.laz"), "-o", str(out), "--config", str(scene / "config.toml"), "--json", "-q",
            *(["--image", str(scene / "image.tif"), "--camera", str(scene / "camera.json")] if image else []), *extra]
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(args) == 0
    return json.loads(stdout.getvalue().strip().splitlines()[-1])


@pytest.fixture(scope="module")
def untiled(scene):
    out = scene / "untiled.gpkg"
    return out, _run(scene, out)


@pytest.fixture(scope="module")
def tiled(scene):
    out = scene / "tiled.gpkg"
    return out, _run(scene, out, *TILED, "--workers", "1")


def _features(path, name):
    """Features sorted by building id, then centroid: (building_id, geometry, attributes)."""
    layer = read_layer(path, name)
    rows = []
    for i, g in enumerate(layer.geometries):
        c = g.centroid if g is not None and not g.is_empty else shapely.Point(np.nan, np.nan)
        rows.append((int(layer.attributes["building_id"][i]), c.x, c.y, g,
                     {k: v[i] for k, v in layer.attributes.items()}))
    return sorted(rows, key=lambda r: r[:3])


def assert_same_features(a, b, tol=1e-6):
    for name in LAYERS:
        fa, fb = _features(a, name), _features(b, name)
        assert len(fa) == len(fb), name
        for ra, rb in zip(fa, fb):
            assert ra[0] == rb[0], name
            assert (ra[3] is None and rb[3] is None) or shapely.equals_exact(ra[3], rb[3], tolerance=tol), name
            assert ra[4].keys() == rb[4].keys(), name
            for key in ra[4]:
                va, vb = ra[4][key], rb[4][key]
                if isinstance(va, float) and np.isnan(va):
                    assert isinstance(vb, float) and np.isnan(vb), (name, key)
                elif isinstance(va, float):
                    assert va == pytest.approx(vb, abs=tol), (name, key)
                else:
                    assert va == vb, (name, key)


def test_tiled_run_with_an_image_equals_the_untiled_run(untiled, tiled):
    (untiled, untiled_summary), (tiled, tiled_summary) = untiled, tiled
    assert tiled_summary["tiles"] >= 4 and tiled_summary["buildings"] == untiled_summary["buildings"] >= 3
    assert tiled_summary["refined"] and untiled_summary["refined"]
    # the orientation is corrected from the line matches of all buildings together, so a per-tile
    # refinement would give each tile its own camera; one pass over the merged set gives the untiled one
    assert tiled_summary["orientation"]["lines"] == untiled_summary["orientation"]["lines"] >= 12
    for k, v in untiled_summary["orientation"]["delta"].items():
        assert tiled_summary["orientation"]["delta"][k] == pytest.approx(v, abs=1e-9), k
    assert_same_features(untiled, tiled)
    status = read_layer(tiled, "roof_outlines").attributes["refine_status"]
    assert "refined" in status


def test_the_image_changes_the_tiled_outlines(scene, tiled):
    lidar = scene / "lidar_only.gpkg"
    assert not _run(scene, lidar, *TILED, image=False)["refined"]
    a, b = _features(lidar, "roof_outlines"), _features(tiled[0], "roof_outlines")
    assert [r[0] for r in a] == [r[0] for r in b]
    moved = [shapely.hausdorff_distance(ra[3], rb[3]) for ra, rb in zip(a, b) if ra[3] is not None]
    assert max(moved) > 0.05  # metres: the refinement ran and moved sides to image lines
    assert "refine_status" not in read_layer(lidar, "roof_outlines").attributes


@pytest.mark.slow  # a LocalCluster starts in about 8 s; the refinement itself runs in the parent
def test_two_workers_give_the_output_of_one(scene, tiled, tmp_path):
    out = tmp_path / "w2.gpkg"
    summary = _run(scene, out, *TILED, "--workers", "2")
    assert summary["refined"] and summary["orientation"] == tiled[1]["orientation"]
    assert_same_features(tiled[0], out, tol=0.0)


def _bad_camera(scene, tmp_path, change):
    cam = json.loads((scene / "camera.json").read_text())
    change(cam)
    path = tmp_path / "camera_bad.json"
    path.write_text(json.dumps(cam))
    return path


BAD = {
    "camera CRS": (lambda c: c.update(crs="EPSG:2154"), "different CRSs"),
    "image far away": (lambda c: c["exterior"].update(X0=c["exterior"]["X0"] + 10000.0), "does not cover"),
    "image size": (lambda c: c.update(image_size=[c["image_size"][0] + 10, c["image_size"][1]]), "px but"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_image_input_fails_before_any_tile_work(scene, tmp_path, capsys, monkeypatch, case):
    import rooftrace.tiling

    def no_split(*a, **k):
        raise AssertionError("tiles were made before the image was checked")

    monkeypatch.setattr(rooftrace.tiling, "split_to_tiles", no_split)
    change, text = BAD[case]
    out = tmp_path / "out.gpkg"
    code = main(["run", str(scene / "points.laz"), "-o", str(out), "--image", str(scene / "image.tif"),
                 "--camera", str(_bad_camera(scene, tmp_path, change)), *TILED, "-q"])
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == 2 and len(errors) == 1 and text in errors[0], err
    assert not out.exists() and not Path(str(out) + ".parts").exists()


def test_resume_refuses_another_image_or_camera(scene, untiled, tmp_path, capsys, monkeypatch):
    import rooftrace.tiling
    from rooftrace.config import RunOptions
    from rooftrace.tiling import TileOptions, run_tiled

    class Killed(Exception):
        pass

    def killed(*a, **k):
        raise Killed

    out = tmp_path / "r.gpkg"
    camera = tmp_path / "camera.json"
    shutil.copy(scene / "camera.json", camera)
    with monkeypatch.context() as m:  # a run stopped after the split and the parameters
        m.setattr(rooftrace.tiling, "_execute", killed)
        with pytest.raises(Killed):
            run_tiled([scene / "points.laz"], RunOptions.from_config({"outliers": {"cell": 15.0}}),
                      TileOptions(tile_size=30.0, buffer=15.0), run_dir=Path(str(out) + ".parts"),
                      image=scene / "image.tif", camera=camera)
    assert (Path(str(out) + ".parts") / "run.json").exists()

    other = tmp_path / "other.tif"
    shutil.copy(scene / "image.tif", other)
    args = ["run", str(scene / "points.laz"), "-o", str(out), "--config", str(scene / "config.toml"), *TILED,
            "--resume", "-q", "--camera", str(camera)]
    assert main([*args, "--image", str(other)]) == 2
    assert "different inputs or options" in capsys.readouterr().err
    cam = json.loads(camera.read_text())
    camera.write_text(json.dumps({**cam, "principal_point_mm": [0.001, 0.0]}))
    assert main([*args, "--image", str(scene / "image.tif")]) == 2
    assert "different inputs or options" in capsys.readouterr().err
    camera.write_text(json.dumps(cam))
    assert main([*args, "--image", str(scene / "image.tif")]) == 0
    assert_same_features(untiled[0], out)


def test_fingerprint_follows_the_camera_content(tmp_path):
    image, camera = tmp_path / "i.tif", tmp_path / "c.json"
    image.write_bytes(b"pixels")
    camera.write_text("{}")
    a = image_fingerprint(image, camera)
    assert image_fingerprint(image, camera) == a
    camera.write_text('{"type": "frame"}')
    assert image_fingerprint(image, camera)["camera"] != a["camera"]


def test_neighbourhoods_of_tiles_join_into_the_points_of_the_whole_cloud(rng):
    xyz = rng.uniform(0, 100, (4000, 3))
    gidx = np.arange(len(xyz))
    square = shapely.box(40, 40, 50, 50)
    # two overlapping "tiles", their points in any order
    parts = []
    for lo, hi in ((0, 70), (30, 100)):
        sel = rng.permutation(np.flatnonzero((xyz[:, 0] >= lo) & (xyz[:, 0] < hi)))
        pts, discs = neighbourhood_points(xyz[sel], gidx[sel], [square, None], context=10.0)
        assert np.all(np.diff(pts["gidx"]) > 0)
        parts.append(TileResult("0_0", refine_points=pts))
    np.testing.assert_allclose(discs, [[45, 45, np.hypot(10, 10) / 2 + 10]])
    joined = join_neighbourhoods(parts)
    np.testing.assert_array_equal(joined, join_neighbourhoods(parts[::-1]))  # whatever the tile order
    # every point of the whole cloud within the disc is there once, in the input order
    d = np.hypot(xyz[:, 0] - 45, xyz[:, 1] - 45)
    inside = joined[np.hypot(joined[:, 0] - 45, joined[:, 1] - 45) <= discs[0, 2]]
    np.testing.assert_array_equal(inside, xyz[d <= discs[0, 2]])
    assert join_neighbourhoods([TileResult("0_0"), TileResult("0_1", refine_points={"gidx": np.zeros(0)})]) is None


def test_a_neighbourhood_past_the_buffer_is_cut_only_where_the_data_goes_on():
    discs = np.array([[50.0, 50.0, 10.0], [5.0, 50.0, 10.0], [95.0, 50.0, 10.0]])
    # the tile's buffered extent reaches the inputs' left border but not their right one
    cut = cut_neighbourhoods(discs, [0.0, 0.0, 100.0, 100.0], [0.0, 0.0, 200.0, 100.0])
    assert cut.tolist() == [False, False, True]
