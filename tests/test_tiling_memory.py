"""An input too large for memory runs in tiles by itself (DESIGN.md: no tiling for inputs that fit in memory)."""

import json

import numpy as np
import pytest
import shapely

from rooftrace.cli.main import main
from rooftrace.io.vector import read_layer
from rooftrace.tiling import memory


def test_the_estimate_grows_with_the_points_and_the_memory_decides():
    assert memory.untiled_bytes(2_000_000) - memory.untiled_bytes(1_000_000) == 1_000_000 * memory.BYTES_PER_POINT
    gib = 2**30
    assert memory.fits_in_memory(1_000_000, available=8 * gib)
    assert not memory.fits_in_memory(100_000_000, available=8 * gib)
    assert memory.fits_in_memory(100_000_000, available=512 * gib)


def test_header_points_sums_the_headers_and_gives_up_on_other_files(tmp_path):
    from rooftrace.cloud import PointCloud
    from rooftrace.io.las import write_las

    xyz = np.random.default_rng(1).uniform(0, 10, (300, 3))
    for name, n in (("a.laz", 100), ("b.laz", 200)):
        write_las(tmp_path / name, PointCloud(xyz[:n], crs=None))
    (tmp_path / "c.txt").write_text("0 0 0\n")
    assert memory.header_points([tmp_path / "a.laz", tmp_path / "b.laz"]) == 300
    assert memory.header_points([tmp_path / "a.laz", tmp_path / "c.txt"]) is None


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from rooftrace.io.las import write_las
    from rooftrace.synth import SceneOptions, simulate_scene

    d = tmp_path_factory.mktemp("scene")
    write_las(d / "points.laz", simulate_scene(SceneOptions(size=80.0, density=5.0, seed=4, image=False)).cloud)
    (d / "config.toml").write_text("[outliers]\ncell = 20.0\n")
    return d


def _run(scene, out, capsys):
    code = main(["run", str(scene / "points.laz"), "-o", str(out), "--config", str(scene / "config.toml"),
                 "--json", "-q"])
    assert code == 0
    captured = capsys.readouterr()
    return json.loads(captured.out), captured.err


def test_a_cloud_that_does_not_fit_runs_in_tiles_with_the_same_buildings(scene, tmp_path, capsys, monkeypatch):
    whole, _ = _run(scene, tmp_path / "whole.gpkg", capsys)
    assert "tiles" not in whole
    monkeypatch.setattr(memory, "available_bytes", lambda: memory.BASE_BYTES)  # nothing fits
    tiled, err = _run(scene, tmp_path / "tiled.gpkg", capsys)
    assert tiled["tiles"] >= 1 and "running in tiles" in " ".join(err.split())
    assert tiled["buildings"] == whole["buildings"] > 0
    a = read_layer(tmp_path / "whole.gpkg", "roof_outlines").geometries
    b = read_layer(tmp_path / "tiled.gpkg", "roof_outlines").geometries
    assert all(shapely.equals_exact(g, h, tolerance=1e-6) for g, h in zip(a, b))


def test_info_says_whether_run_would_tile(scene, capsys, monkeypatch):
    assert main(["info", str(scene / "points.laz"), "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["run"]["tiled"] is False and first["points"] > 0
    monkeypatch.setattr(memory, "available_bytes", lambda: memory.BASE_BYTES)
    assert main(["info", str(scene / "points.laz"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["run"]["tiled"] is True


def test_detect_refuses_a_cloud_larger_than_memory_before_reading_it(scene, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(memory, "available_bytes", lambda: memory.BASE_BYTES)
    out = tmp_path / "classified.laz"
    assert main(["detect", str(scene / "points.laz"), "-o", str(out)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "error:" in err and "--classified" in err and not out.exists()
