"""Tiled runs (issue 9): tiles with buffers equal one piece, workers, Dask, resume."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import laspy
import numpy as np
import pytest
import shapely

from rooftrace.cli.main import main
from rooftrace.errors import InputError
from rooftrace.io.vector import Layer, read_layer
from rooftrace.tiling import (
    TileOptions,
    TileResult,
    merge_tiles,
    owned_buildings,
    sample_windows,
    split_to_tiles,
    tile_cell_ranges,
    tile_grid,
)

from .conftest import DELFT, need

LAYERS = ("roof_outlines", "ridges", "roof_faces")
# a 100 m synthetic block cut into 2 x 2 tiles of 50 m; outlier cells of
# 25 m let a 25 m buffer stay 25 m (buffered tiles follow the cell lines)
TILED = ["--tile-size", "50", "--buffer", "25"]


def _las(path, xyz):
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales = [0.001] * 3
    header.offsets = [0, 0, 0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.write(path)


def assert_same_layers(a, b, tol=1e-6):
    """Same features in the same order, geometries within ``tol`` metres, identical attributes."""
    for name in LAYERS:
        la, lb = read_layer(a, name), read_layer(b, name)
        assert len(la) == len(lb), name
        for ga, gb in zip(la.geometries, lb.geometries):
            assert (ga is None and gb is None) or shapely.equals_exact(ga, gb, tolerance=tol), name
        assert la.attributes.keys() == lb.attributes.keys(), name
        for key in la.attributes:
            va, vb = np.asarray(la.attributes[key]), np.asarray(lb.attributes[key])
            if va.dtype.kind == "f":
                np.testing.assert_array_equal(va, vb, err_msg=f"{name}.{key}")  # NaN == NaN here
            else:
                assert va.tolist() == vb.tolist(), (name, key)


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """A simulated 100 m block (about 50k points, a dozen buildings) and a config with 25 m outlier cells."""
    from rooftrace.io.las import write_las
    from rooftrace.synth import SceneOptions, simulate_scene

    d = tmp_path_factory.mktemp("block")
    scene = simulate_scene(SceneOptions(size=100.0, density=5.0, seed=2, image=False))
    write_las(d / "points.laz", scene.cloud)
    (d / "config.toml").write_text("[outliers]\ncell = 25.0\n")
    return d


@pytest.fixture(scope="module")
def one_piece(block):
    out = block / "one.gpkg"
    assert main(["run", str(block / "points.laz"), "-o", str(out), "--config", str(block / "config.toml"),
                 "--classified", str(block / "one.laz"), "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def tiled(block):
    out = block / "tiled.gpkg"
    args = ["run", str(block / "points.laz"), "-o", str(out), "--config", str(block / "config.toml"), *TILED,
            "--classified", str(block / "tiled.laz"), "-q"]
    assert main(args) == 0
    return out


def test_grid_is_anchored_at_multiples_of_the_tile_size():
    xs, ys = tile_grid([1030.0, 2010.0, 1490.0, 2260.0], 100.0)
    np.testing.assert_array_equal(xs, [1000, 1100, 1200, 1300, 1400])
    np.testing.assert_array_equal(ys, [2000, 2100, 2200])


def test_buffered_tiles_follow_the_cell_lines():
    r = tile_cell_ranges(np.array([1000.0, 1100.0]), 100.0, 20.0, 990.0, 25.0)
    # [980, 1120) widened to 25 m cells from 990: cells -1..5 ([965, 1140))
    np.testing.assert_array_equal(r, [[-1, 5], [3, 9]])


def test_split_puts_each_point_in_every_buffered_tile_that_holds_it(tmp_path, rng):
    xyz = np.column_stack([rng.uniform(0, 300, 5000), rng.uniform(0, 200, 5000), rng.uniform(0, 10, 5000)])
    a, b = tmp_path / "a.las", tmp_path / "b.laz"
    _las(a, xyz[:2500])
    _las(b, xyz[2500:])
    opts = TileOptions(tile_size=100.0, buffer=20.0, chunk_size=700)
    index = split_to_tiles([a, b], tmp_path / "run", opts, cell=10.0)
    assert index["tile_size"] == 100.0 and index["points"] == 5000 and index["sample_points"] == 5000
    ox, oy = index["origin"]
    pts = np.concatenate([np.asarray(laspy.read(p).xyz) for p in (a, b)])
    kx, ky = np.floor((pts[:, 0] - ox) / 10.0), np.floor((pts[:, 1] - oy) / 10.0)
    in_core = np.zeros(len(pts), int)
    for key, tile in index["tiles"].items():
        cx0, cx1, cy0, cy1 = tile["cells"]
        got = np.concatenate([np.load(p) for p in sorted((tmp_path / "run" / "tiles" / key).glob("*.npy"))])
        expect = pts[(kx >= cx0) & (kx <= cx1) & (ky >= cy0) & (ky <= cy1)]
        # the same points in the same (file, then point) order as the whole input
        np.testing.assert_array_equal(np.column_stack([got["x"], got["y"], got["z"]]), expect)
        assert tile["points"] == len(got)
        x0, y0 = tile["origin"]
        assert ox + cx0 * 10 <= x0 - 20 and ox + (cx1 + 1) * 10 >= x0 + 120
        in_core += (pts[:, 0] >= x0) & (pts[:, 0] < x0 + 100) & (pts[:, 1] >= y0) & (pts[:, 1] < y0 + 100)
    assert (in_core == 1).all()
    sample = np.concatenate([np.load(p) for p in sorted((tmp_path / "run" / "sample").glob("*.npy"))])
    np.testing.assert_array_equal(sample["x"], pts[:, 0])


def test_large_inputs_are_sampled_on_four_windows_of_whole_cells():
    assert sample_windows([0, 0, 1000, 1000], 1000, 2000, (0, 0), 50.0) is None
    w = sample_windows([0, 0, 1000, 1000], 10_000_000, 2_000_000, (0, 0), 50.0)
    assert w.shape == (4, 4)
    sides = (w[:, 1] - w[:, 0] + 1) * 50.0
    # 500k points at 10 pts/m² need about 224 m, rounded up to whole cells
    assert (sides >= 224).all() and (sides <= 300).all()
    assert len({tuple(r) for r in w}) == 4


def test_split_refuses_non_las(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("1 2 3\n")
    with pytest.raises(InputError, match="LAS/LAZ only"):
        split_to_tiles([p], tmp_path / "run", TileOptions())


def test_bad_tile_options_name_the_flag():
    with pytest.raises(InputError, match="tile_size"):
        TileOptions(tile_size=-5)
    with pytest.raises(InputError, match="workers must"):
        TileOptions(workers=0)


def test_a_building_belongs_to_the_tile_holding_its_centre():
    # building 1 spans the seam x = 10 with its box centre at 9.5; building 2 is all right of it
    xyz = np.array([[5.0, 0, 3], [14.0, 1, 3], [6.0, 2, 3], [11.0, 0, 5], [13.0, 1, 5], [1.0, 1, 0]])
    bid = np.array([1, 1, 1, 2, 2, 0])
    ids, owned, key, box = owned_buildings(xyz, bid, (-np.inf, 10.0, -np.inf, np.inf), (0.0, 0.0))
    assert ids.tolist() == [1, 2] and owned.tolist() == [True, False]
    np.testing.assert_array_equal(key, [[5, 0, 3], [11, 0, 5]])
    np.testing.assert_array_equal(box[0], [5, 0, 14, 2])
    ids, owned, _, _ = owned_buildings(xyz, bid, (10.0, np.inf, -np.inf, np.inf), (0.0, 0.0))
    assert owned.tolist() == [False, True]


def test_the_default_tile_holds_about_three_million_points_with_its_buffer():
    from rooftrace.tiling.split import TARGET_TILE_POINTS, derived_tile_size

    box = (0.0, 0.0, 0.0, 1000.0, 1000.0, 50.0)
    sizes = [derived_tile_size([int(d * 1e6)], [box], 60.0) for d in (2.0, 13.5, 30.0, 500.0)]
    assert sizes == [1000.0, 350.0, 150.0, 100.0]  # sparse ... dense, clipped to 100-1000 m
    assert (sizes[1] + 120) ** 2 * 13.5 <= TARGET_TILE_POINTS < (sizes[1] + 50 + 120) ** 2 * 13.5
    # the densest file decides; a file without points does not count
    assert derived_tile_size([2_000_000, 30_000_000, 0], [box, box, box], 60.0) == 150.0
    assert derived_tile_size([0], [box], 60.0) == 200.0


def test_only_a_side_where_the_data_goes_on_can_cut_a_building():
    from rooftrace.tiling.split import near_open_side

    # a 100 x 10 m tile box in a 200 x 10 m input: only its east side has data beyond it
    boxes = np.array([[1.0, 5, 3, 6], [97, 5, 99, 6], [50, 8.5, 52, 9.5], [40, 2, 60, 4]])
    assert near_open_side(boxes, [0, 0, 100, 10], [0, 0, 200, 10], 2.0).tolist() == [False, True, False, False]
    # the same tile as the whole input: nothing to miss anywhere
    assert not near_open_side(boxes, [0, 0, 100, 10], [0, 0, 100, 10], 2.0).any()


def test_merge_numbers_buildings_by_their_lowest_point_whatever_the_tile_order():
    def tile(ids, keys, xs):
        polys = [shapely.box(x, 0, x + 1, 1) for x in xs]
        layer = Layer(polys, {"building_id": ids, "area": [1.0] * len(ids)}, "Polygon")
        return TileResult("0_0", layers={"roof_outlines": layer}, building_ids=np.array(ids),
                          building_keys=np.array(keys, float))

    a = tile([1, 2], [[5, 0, 0], [1, 0, 0]], [5, 1])
    b = tile([1], [[3, 0, 0]], [3])
    for order in ([a, b], [b, a]):
        layer = merge_tiles(order)["roof_outlines"]
        assert layer.attributes["building_id"] == [1, 2, 3]
        assert [g.bounds[0] for g in layer.geometries] == [1, 3, 5]


def test_fixed_parameters_reproduce_the_detection(rng):
    from rooftrace.cloud import PointCloud
    from rooftrace.lidar.detect import DerivedParams, detect_buildings

    from .lidar.scenes import scene

    xyz, _ = scene(rng, size=50.0, boxes=((8, 8, 12, 9, 6), (30, 28, 10, 14, 9)), trees=((35, 10, 4, 3, 9),))
    cloud = PointCloud(xyz + [85000.0, 447000.0, 0.0])
    free = detect_buildings(cloud)
    d = free.derived
    assert d.origin == tuple(cloud.xyz[:, :2].min(axis=0)) and d.entropy_threshold is not None
    assert DerivedParams.from_dict(json.loads(json.dumps(d.to_dict()))) == d
    fixed = detect_buildings(cloud, derived=d)
    np.testing.assert_array_equal(free.classification, fixed.classification)
    np.testing.assert_array_equal(free.building_id, fixed.building_id)
    assert fixed.params["classify"]["method"] == "fixed"
    with pytest.raises(ValueError, match="derived.sigma_h"):
        DerivedParams(sigma_h=-1.0)


def test_four_tiles_give_the_buildings_of_one_piece(block, one_piece, tiled):
    assert len(read_layer(one_piece, "roof_outlines")) >= 5
    assert_same_layers(one_piece, tiled)
    assert not Path(str(tiled) + ".parts").exists()


def test_two_workers_give_the_output_of_one(block, tiled, tmp_path):
    out = tmp_path / "w2.gpkg"
    args = ["run", str(block / "points.laz"), "-o", str(out), "--config", str(block / "config.toml"), *TILED,
            "--workers", "2", "-q"]
    assert main(args) == 0
    assert_same_layers(tiled, out, tol=0.0)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_runs_on_a_dask_scheduler_and_worker(block, tiled, tmp_path):
    dask = str(Path(sys.executable).with_name("dask"))
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, env=env)]
    try:
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1", "--nthreads", "1",
                                       "--no-dashboard", "--host", "127.0.0.1"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                                      env=env, cwd=tmp_path))
        from dask.distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(1, timeout=60)
        out = tmp_path / "dask.gpkg"
        args = ["run", str(block / "points.laz"), "-o", str(out), "--config", str(block / "config.toml"), *TILED,
                "--scheduler", address, "-q"]
        assert main(args) == 0
        assert_same_layers(tiled, out, tol=0.0)
    finally:
        for p in reversed(procs):
            os.killpg(p.pid, signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def test_a_killed_run_resumes_without_redoing_finished_tiles(block, tiled, tmp_path, monkeypatch):
    import rooftrace.pipeline

    out = tmp_path / "killed.gpkg"
    args = ["run", str(block / "points.laz"), "-o", str(out), "--config", str(block / "config.toml"), *TILED, "-q"]
    proc = subprocess.Popen([str(Path(sys.executable).with_name("rooftrace")), *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    results = Path(str(out) + ".parts") / "results"
    try:
        deadline = time.monotonic() + 120
        while len(list(results.glob("*.pkl"))) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    done = {p.name: p.stat().st_mtime_ns for p in results.glob("*.pkl")}
    n_tiles = len(json.loads((results.parent / "tiles.json").read_text())["tiles"])
    assert 2 <= len(done) < n_tiles and not out.exists()

    calls = []
    original = rooftrace.pipeline.run_pipeline

    def counting(*a, **k):
        calls.append(1)
        return original(*a, **k)

    monkeypatch.setattr(rooftrace.pipeline, "run_pipeline", counting)
    assert main([*args, "--resume"]) == 0
    # only the parameters were kept too: every pipeline call is an unfinished tile
    assert len(calls) == n_tiles - len(done)
    assert_same_layers(tiled, out, tol=0.0)


def test_resume_refuses_other_options(block, tmp_path, capsys):
    out = tmp_path / "r.gpkg"
    parts = Path(str(out) + ".parts")
    parts.mkdir()
    (parts / "run.json").write_text(json.dumps({"inputs": ["elsewhere.laz"]}))
    code = main(["run", str(block / "points.laz"), "-o", str(out), *TILED, "--resume", "-q"])
    assert code == 2
    assert "different inputs or options" in capsys.readouterr().err


def test_tiled_classified_points_equal_one_piece(block, one_piece, tiled):
    a, b, src = laspy.read(block / "one.laz"), laspy.read(block / "tiled.laz"), laspy.read(block / "points.laz")
    assert len(a.points) == len(b.points) == len(src.points)
    np.testing.assert_array_equal(np.asarray(b.classification), np.asarray(a.classification))
    np.testing.assert_array_equal(np.asarray(b["building_id"]), np.asarray(a["building_id"]))
    assert set(np.unique(b["building_id"])) - {0} == set(read_layer(tiled, "roof_outlines").attributes["building_id"])
    kept = [d for d in src.point_format.dimension_names if d != "classification"]
    assert {"X", "Y", "Z", "intensity", "gps_time", "return_number"} <= set(kept)
    for name in kept:  # every input dimension, untouched
        np.testing.assert_array_equal(np.asarray(b[name]), np.asarray(src[name]), err_msg=name)


def test_tiled_footprints_give_the_buildings_of_one_piece(block, one_piece, tmp_path):
    """Footprints are split along the tiles as the points are: every footprint's building, its number and
    its points' labels are those of the untiled run, a footprint over no data included."""
    from rooftrace.io.vector import write_layers

    outlines = read_layer(one_piece, "roof_outlines")
    # the buildings' outlines drawn a little inside, as a cadastre draws walls under the eaves, and one
    # footprint far from the data (status no_points, owned by the nearest tile)
    polygons = [shapely.force_2d(g).buffer(-0.5, join_style="mitre") for g in outlines.geometries if g is not None]
    x1, y1 = shapely.total_bounds(polygons)[2:]
    polygons = [p for p in polygons if not p.is_empty] + [shapely.box(x1 + 200, y1 + 200, x1 + 210, y1 + 210)]
    prints = tmp_path / "footprints.gpkg"
    write_layers(prints, {"pand": Layer(polygons, {"identificatie": [f"p{i}" for i in range(len(polygons))]},
                                        "Polygon")}, read_layer(one_piece, "roof_outlines").crs)
    common = ["--config", str(block / "config.toml"), "--footprints", str(prints), "-q"]
    a, b = tmp_path / "one.gpkg", tmp_path / "tiled.gpkg"
    assert main(["run", str(block / "points.laz"), "-o", str(a), "--classified", str(tmp_path / "one.laz"),
                 *common]) == 0
    assert main(["run", str(block / "points.laz"), "-o", str(b), "--classified", str(tmp_path / "tiled.laz"),
                 *common, *TILED]) == 0
    assert_same_layers(a, b, tol=0.0)
    fa, fb = read_layer(a, "roof_outlines"), read_layer(b, "roof_outlines")
    assert fa.attributes["footprint_id"] == fb.attributes["footprint_id"] == [f"p{i}" for i in range(len(polygons))]
    assert fb.attributes["footprint_status"][-1] == "no_points" and len(polygons) > 5
    la, lb = laspy.read(tmp_path / "one.laz"), laspy.read(tmp_path / "tiled.laz")
    np.testing.assert_array_equal(np.asarray(lb["building_id"]), np.asarray(la["building_id"]))
    np.testing.assert_array_equal(np.asarray(lb.classification), np.asarray(la.classification))


def test_tiled_classified_needs_one_point_format(block, tmp_path, capsys):
    src = laspy.read(block / "points.laz")
    other = laspy.convert(src, point_format_id=1 if src.point_format.id != 1 else 3)
    other.write(tmp_path / "other.laz")
    code = main(["run", str(block / "points.laz"), str(tmp_path / "other.laz"), "-o", str(tmp_path / "a.gpkg"),
                 "--classified", str(tmp_path / "a.laz"), *TILED, "-q"])
    assert code == 2 and "point format" in capsys.readouterr().err
    assert not (tmp_path / "a.laz").exists()


@pytest.mark.slow
def test_delft_tiles_detect_every_building_with_the_points_of_one_piece(tmp_path):
    """Issue 9 on real data: 2 x 2 tiles of 250 m with a 60 m buffer; each building a tile owns has exactly
    the points of the same building in the whole cloud, so its outline, planes and ridges are the same
    (benchmarks/bench_scale.py compares the full outputs)."""
    import dataclasses

    from rooftrace.io.points import read_points
    from rooftrace.lidar.detect import detect_buildings
    from rooftrace.tiling import load_tile_points, tile_core, tile_extent

    files = [need(DELFT / "ahn3_cropped_1.laz"), need(DELFT / "ahn3_cropped_2.laz")]
    whole_cloud = read_points(files, "EPSG:28992")
    whole = detect_buildings(whole_cloud)
    index = split_to_tiles(files, tmp_path, TileOptions(tile_size=250.0, buffer=60.0))
    assert len(index["tiles"]) == 4 and tuple(index["origin"]) == whole.derived.origin
    w_ids, _, w_keys, _ = owned_buildings(whole_cloud.xyz, whole.building_id, (-np.inf, np.inf, -np.inf, np.inf),
                                          whole.derived.origin)
    def rows(p):
        return p[np.lexsort(p.T[::-1])]

    w_points = {tuple(k): rows(whole_cloud.xyz[whole.building_id == b]) for b, k in zip(w_ids, w_keys)}
    seen = []
    for key in index["tiles"]:
        cloud = load_tile_points(tmp_path / "tiles" / key, whole_cloud.crs)
        det = detect_buildings(cloud, derived=dataclasses.replace(whole.derived, extent=tuple(tile_extent(index, key))))
        ids, owned, keys, _ = owned_buildings(cloud.xyz, det.building_id, tile_core(index, key), whole.derived.origin)
        for b, k in zip(ids[owned], keys[owned]):
            np.testing.assert_array_equal(rows(cloud.xyz[det.building_id == b]), w_points[tuple(k)])
            seen.append(tuple(k))
    assert sorted(seen) == sorted(w_points) and len(seen) > 20
