"""Tiny input files, good and bad, for the bad-input suite (issue 10).

:func:`make_files` writes every file once into a folder and returns their
paths by name, so a table of command lines can refer to them as ``{name}``.
Everything is small (a 40 x 40 m scene at 4 pts/m², a 400 x 400 px image)
so a whole table runs in seconds.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import laspy
import numpy as np
import pyproj
import shapely

__all__ = ["make_files", "scene_xyz", "write_las_file", "SHIFT"]

#: map-sized coordinates (Dutch RD New), so CRS and precision issues show up
SHIFT = np.array([85000.0, 447000.0, 0.0])
RD = "EPSG:28992"

# LAS 1.4 public header byte offsets (ASPRS LAS 1.4 R15, table 3)
_LEGACY_COUNT = 107
_MAX_X = 179
_COUNT_14 = 247


def scene_xyz(seed: int = 0, building: bool = True, size: float = 40.0) -> np.ndarray:
    """Ground on a jittered 0.5 m grid and, optionally, a 12 x 10 m flat roof 6 m up (metres, RD-sized)."""
    rng = np.random.default_rng(seed)
    g = np.mgrid[0:size:0.5, 0:size:0.5].reshape(2, -1).T
    g = g + rng.uniform(-0.2, 0.2, g.shape)
    z = rng.normal(0.0, 0.03, len(g))
    if building:
        inside = (g[:, 0] > 14) & (g[:, 0] < 26) & (g[:, 1] > 15) & (g[:, 1] < 25)
        z[inside] += 6.0
    return np.column_stack([g, z]) + SHIFT


def write_las_file(path: Path, xyz: np.ndarray, crs: str | None = RD, *, classification=None,
                   scales=(0.001, 0.001, 0.001)) -> Path:
    """Write points as LAS 1.4 / format 6 (LAZ by the suffix), with a WKT CRS when ``crs`` is given."""
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales = list(scales)
    header.offsets = [float(np.floor(xyz[:, 0].min())) if len(xyz) else 0.0,
                      float(np.floor(xyz[:, 1].min())) if len(xyz) else 0.0, 0.0]
    if crs:
        header.add_crs(pyproj.CRS.from_user_input(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.asarray(xyz, float).T
    if classification is not None:
        las.classification = np.asarray(classification, np.uint8)
    las.write(path)
    return path


def _patch(path: Path, offset: int, fmt: str, *values) -> None:
    data = bytearray(path.read_bytes())
    struct.pack_into(fmt, data, offset, *values)
    path.write_bytes(bytes(data))


def _patch_count(path: Path, count: int) -> None:
    # LAS 1.4 keeps the legacy 32-bit count at 0 for point formats 6-10; patch it only when used
    if struct.unpack_from("<I", path.read_bytes(), _LEGACY_COUNT)[0]:
        _patch(path, _LEGACY_COUNT, "<I", count)
    _patch(path, _COUNT_14, "<Q", count)


def _camera(x0: float, y0: float, crs: str | None = RD, size: int = 400) -> dict:
    # nadir frame camera 1200 m up: 0.012 mm pixels at f = 120 mm give 0.12 m on the ground,
    # so 400 px cover 48 m, the whole 40 m scene
    return {
        "type": "frame",
        "crs": crs,
        "image_size": [size, size],
        "pixel_size_mm": 0.012,
        "focal_length_mm": 120.0,
        "principal_point_mm": [0.0, 0.0],
        "distortion": {"k1": 0, "k2": 0, "k3": 0, "p1": 0, "p2": 0},
        "exterior": {"X0": x0, "Y0": y0, "Z0": 1200.0, "omega_deg": 0.0, "phi_deg": 0.0, "kappa_deg": 0.0},
        "exterior_covariance": (np.eye(6) * [0.01, 0.01, 0.01, 1e-8, 1e-8, 1e-8]).tolist(),
    }


def _write_json(path: Path, obj) -> Path:
    path.write_text(obj if isinstance(obj, str) else json.dumps(obj), encoding="utf-8")
    return path


def make_files(tmp: Path) -> dict[str, Path]:
    """Write every input of the bad-input table into ``tmp``; returns name -> path.

    Good files: ``scene`` (LAZ, RD New, one building), ``ground`` (no
    building), ``empty`` (0 points), ``image``, ``camera``, ``outlines``
    (GeoPackage), ``seeds`` (GeoJSON), ``gcps`` (CSV), ``existing`` (a file
    an output must not replace).  The others are named after what is wrong
    with them.
    """
    from rooftrace.io.raster import write_geotiff
    from rooftrace.io.vector import Layer, write_layers

    tmp = Path(tmp)
    f: dict[str, Path] = {"tmp": tmp, "missing": tmp / "missing.laz", "missing_json": tmp / "missing.json",
                          "missing_gpkg": tmp / "missing.gpkg", "folder": tmp}
    xyz = scene_xyz()
    centre = SHIFT + [20.0, 20.0, 0.0]

    # point clouds
    f["scene"] = write_las_file(tmp / "scene.laz", xyz)
    f["scene_las"] = write_las_file(tmp / "scene.las", xyz)
    f["nocrs"] = write_las_file(tmp / "nocrs.las", xyz, crs=None)
    f["l93"] = write_las_file(tmp / "l93.las", xyz - SHIFT + [700000.0, 6600000.0, 0.0], crs="EPSG:2154")
    lonlat = np.column_stack([5.0 + (xyz[:, 0] - SHIFT[0]) * 1e-5, 52.0 + (xyz[:, 1] - SHIFT[1]) * 1e-5, xyz[:, 2]])
    f["wgs84"] = write_las_file(tmp / "wgs84.las", lonlat, crs="EPSG:4326", scales=(1e-7, 1e-7, 0.001))
    f["degrees_nocrs"] = write_las_file(tmp / "degrees_nocrs.las", lonlat, crs=None, scales=(1e-7, 1e-7, 0.001))
    f["ground"] = write_las_file(tmp / "ground.las", scene_xyz(building=False))
    f["empty"] = write_las_file(tmp / "empty.las", np.empty((0, 3)))
    f["identical"] = write_las_file(tmp / "identical.las", np.tile(centre, (50, 1)))
    t = np.linspace(0, 30, 200)
    f["collinear"] = write_las_file(tmp / "collinear.las", SHIFT + np.column_stack([t, 0.5 * t, np.sin(t)]))
    f["two_points"] = write_las_file(tmp / "two_points.las", np.array([centre, centre + [1.0, 1.0, 0.0]]))

    data = f["scene"].read_bytes()
    f["truncated"] = tmp / "truncated.laz"
    f["truncated"].write_bytes(data[: len(data) // 2])
    f["header_only"] = tmp / "header_only.laz"
    f["header_only"].write_bytes(data[:400])
    f["zero_bytes"] = tmp / "zero.las"
    f["zero_bytes"].write_bytes(b"")
    f["not_las"] = tmp / "zip.las"
    f["not_las"].write_bytes(b"PK\x03\x04 this is a zip archive, not LAS" * 20)
    f["gpkg_as_cloud"] = tmp / "outlines_as.laz"
    f["count_high"] = write_las_file(tmp / "count_high.las", xyz)  # header announces more points than stored
    _patch_count(f["count_high"], len(xyz) + 500)
    f["count_low"] = write_las_file(tmp / "count_low.las", xyz)  # header announces fewer points than stored
    _patch_count(f["count_low"], len(xyz) - 500)
    f["bounds_lie"] = write_las_file(tmp / "bounds_lie.las", xyz)  # max x 30 m short of the points
    _patch(f["bounds_lie"], _MAX_X, "<d", float(xyz[:, 0].max()) - 30.0)
    f["nan_scale"] = write_las_file(tmp / "nan_scale.las", xyz)  # x scale NaN: every x is NaN
    _patch(f["nan_scale"], 131, "<d", float("nan"))

    f["text"] = tmp / "cloud.xyz"
    np.savetxt(f["text"], xyz, fmt="%.3f")
    f["text_nan"] = tmp / "nan.xyz"
    f["text_nan"].write_text("x y z\n" + "\n".join(f"{a:.3f} {b:.3f} {c:.3f}" for a, b, c in xyz[:50])
                             + "\nnan 1 2\n1 inf 2\n")
    f["text_words"] = tmp / "words.txt"
    f["text_words"].write_text("this is a letter\nnot a point cloud\n")
    f["text_two_cols"] = tmp / "two.csv"
    f["text_two_cols"].write_text("1,2\n3,4\n5,6\n")
    f["ply_bad"] = tmp / "bad.ply"
    f["ply_bad"].write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n")
    f["unknown_suffix"] = tmp / "cloud.e57"
    f["unknown_suffix"].write_bytes(b"ASTM-E57")
    f["classified_no6"] = write_las_file(tmp / "classified_no6.las", xyz, classification=np.full(len(xyz), 2))
    cls6 = np.where(xyz[:, 2] > 3, 6, 2)
    f["classified"] = write_las_file(tmp / "classified.las", xyz, classification=cls6)
    one = np.flatnonzero(cls6 == 6)[:1]
    cls_one = np.full(len(xyz), 2)
    cls_one[one] = 6
    f["classified_one"] = write_las_file(tmp / "classified_one.las", xyz, classification=cls_one)

    # image and cameras
    rng = np.random.default_rng(1)
    f["image"] = write_geotiff(tmp / "image.tif", rng.integers(0, 255, (400, 400), dtype=np.uint8))
    f["image_small"] = write_geotiff(tmp / "image_small.tif", rng.integers(0, 255, (100, 120), dtype=np.uint8))
    f["not_image"] = tmp / "not_image.tif"
    f["not_image"].write_bytes(b"II*\x00 garbage" * 10)
    f["camera"] = _write_json(tmp / "camera.json", _camera(centre[0], centre[1]))
    f["camera_nocrs"] = _write_json(tmp / "camera_nocrs.json", _camera(centre[0], centre[1], crs=None))
    f["camera_far"] = _write_json(tmp / "camera_far.json", _camera(centre[0] + 10000.0, centre[1]))
    f["camera_l93"] = _write_json(tmp / "camera_l93.json", _camera(centre[0], centre[1], crs="EPSG:2154"))
    f["camera_wgs84"] = _write_json(tmp / "camera_wgs84.json", _camera(centre[0], centre[1], crs="EPSG:4326"))
    f["camera_syntax"] = _write_json(tmp / "camera_syntax.json", '{"type": "frame", "image_size": [400, 400],')
    f["camera_list"] = _write_json(tmp / "camera_list.json", [1, 2, 3])
    bad = _camera(centre[0], centre[1])
    del bad["exterior"]
    f["camera_no_exterior"] = _write_json(tmp / "camera_no_exterior.json", bad)
    bad = _camera(centre[0], centre[1])
    bad["image_size"] = ["400", 400]
    f["camera_size"] = _write_json(tmp / "camera_size.json", bad)
    bad = _camera(centre[0], centre[1])
    bad["principal_point_mm"] = ["a", "b"]
    f["camera_pp"] = _write_json(tmp / "camera_pp.json", bad)
    bad = _camera(centre[0], centre[1])
    bad["exterior_covariance"] = [[1, 2], [3, 4]]
    f["camera_cov"] = _write_json(tmp / "camera_cov.json", bad)
    bad = _camera(centre[0], centre[1])
    bad["type"] = "fisheye"
    f["camera_type"] = _write_json(tmp / "camera_type.json", bad)
    bad = _camera(centre[0], centre[1])
    bad["focal_length_mm"] = -120
    f["camera_focal"] = _write_json(tmp / "camera_focal.json", bad)
    bad = _camera(centre[0], centre[1])
    bad["exterior"]["omega_deg"] = "level"
    f["camera_angle"] = _write_json(tmp / "camera_angle.json", bad)
    bad = _camera(centre[0], centre[1])
    bad["crs"] = "EPSG:nonsense"
    f["camera_crs"] = _write_json(tmp / "camera_crs.json", bad)
    f["ortho"] = _write_json(tmp / "ortho.json", {"type": "orthophoto"})
    f["camera_binary"] = tmp / "camera_binary.json"
    f["camera_binary"].write_bytes(b"\xff\xfe\x00garbage")

    # vectors
    roof = shapely.Polygon(np.array([[14, 15, 6], [26, 15, 6], [26, 25, 6], [14, 25, 6]]) + SHIFT)
    layer = Layer([roof], {"building_id": [1]}, "PolygonZ")
    f["outlines"] = write_layers(tmp / "outlines.gpkg", {"roof_outlines": layer}, pyproj.CRS.from_user_input(RD))
    f["outlines_l93"] = write_layers(tmp / "outlines_l93.gpkg", {"roof_outlines": layer},
                                     pyproj.CRS.from_user_input("EPSG:2154"))
    lon = shapely.Polygon([(5.0, 52.0, 6), (5.0002, 52.0, 6), (5.0002, 52.0001, 6), (5.0, 52.0001, 6)])
    f["outlines_wgs84"] = write_layers(tmp / "outlines_wgs84.gpkg",
                                       {"roof_outlines": Layer([lon], {"building_id": [1]}, "PolygonZ")},
                                       pyproj.CRS.from_user_input("EPSG:4326"))
    f["outlines_far"] = write_layers(tmp / "outlines_far.gpkg",
                                     {"roof_outlines": Layer([shapely.affinity.translate(roof, 10000.0)],
                                                             {"building_id": [1]}, "PolygonZ")},
                                     pyproj.CRS.from_user_input(RD))
    f["outlines_empty"] = write_layers(tmp / "outlines_empty.gpkg",
                                       {"roof_outlines": Layer([], {"building_id": []}, "PolygonZ")},
                                       pyproj.CRS.from_user_input(RD))
    f["lines"] = write_layers(tmp / "lines.gpkg", {"ridges": Layer([shapely.LineString([(0, 0, 0), (1, 1, 0)])],
                                                                   {}, "LineStringZ")},
                              pyproj.CRS.from_user_input(RD))
    f["gpkg_as_cloud"].write_bytes(f["outlines"].read_bytes())
    f["not_vector"] = tmp / "not_vector.gpkg"
    f["not_vector"].write_bytes(b"SQLite format 3\x00 but not really" * 5)
    corners = np.array([[14, 15], [26, 15], [26, 25], [14, 25]]) + SHIFT[:2] + 0.3
    f["seeds"] = write_layers(tmp / "seeds.geojson",
                              {"seeds": Layer([shapely.Point(p) for p in corners], {"building": ["a"] * 4}, "Point")},
                              pyproj.CRS.from_user_input(RD))
    f["seeds_l93"] = write_layers(tmp / "seeds_l93.gpkg",
                                  {"seeds": Layer([shapely.Point(p) for p in corners], {"building": ["a"] * 4},
                                                  "Point")}, pyproj.CRS.from_user_input("EPSG:2154"))
    f["seeds_no_building"] = write_layers(tmp / "seeds_nob.gpkg",
                                          {"seeds": Layer([shapely.Point(p) for p in corners], {"name": ["a"] * 4},
                                                          "Point")}, pyproj.CRS.from_user_input(RD))
    f["seeds_two"] = write_layers(tmp / "seeds_two.gpkg",
                                  {"seeds": Layer([shapely.Point(p) for p in corners[:2]], {"building": ["a"] * 2},
                                                  "Point")}, pyproj.CRS.from_user_input(RD))
    f["seeds_far"] = write_layers(tmp / "seeds_far.gpkg",
                                  {"seeds": Layer([shapely.Point(p + [10000.0, 0]) for p in corners],
                                                  {"building": ["a"] * 4}, "Point")}, pyproj.CRS.from_user_input(RD))

    # ground control points
    f["gcps"] = tmp / "gcps.csv"
    f["gcps"].write_text("id,X,Y,Z,col,row\n1,85010,447010,0,116.7,283.3\n2,85030,447010,0,283.3,283.3\n"
                         "3,85030,447030,0,283.3,116.7\n4,85010,447030,6,116.7,116.7\n")
    f["gcps_columns"] = tmp / "gcps_columns.csv"
    f["gcps_columns"].write_text("name,E,N,H\n1,2,3,4\n")
    f["gcps_value"] = tmp / "gcps_value.csv"
    f["gcps_value"].write_text("id,X,Y,Z,col,row\n1,85010,447010,zero,116.7,283.3\n")
    f["gcps_few"] = tmp / "gcps_few.csv"
    f["gcps_few"].write_text("id,X,Y,Z,col,row\n1,85010,447010,0,116.7,283.3\n")
    f["gcps_collinear"] = tmp / "gcps_collinear.csv"
    f["gcps_collinear"].write_text("id,X,Y,Z,col,row\n1,85010,447010,0,116.7,283.3\n2,85020,447010,0,200,283.3\n"
                                   "3,85030,447010,0,283.3,283.3\n4,85040,447010,0,366.7,283.3\n")

    # configs
    for name, text in {"cfg_section": "[segmnet]\nmin_height = 2\n", "cfg_key": "[alpha]\nstrategie = 'point'\n",
                       "cfg_value": "[alpha]\nstrategy = 'sideways'\n",
                       "cfg_type": "[ground]\niteration_distance = 'far'\n",
                       "cfg_syntax": "[ground\niteration_distance = 1\n", "cfg_toplevel": "seed = 3\n",
                       "cfg_sim_key": "[simulate]\ndensiti = 3\n", "cfg_snake_key": "[snake]\nstepz = 3\n",
                       "cfg_resection_key": "[resection]\nsigma = 3\n"}.items():
        f[name] = tmp / f"{name[4:]}.toml"
        f[name].write_text(text)

    # an earlier result an output must not replace
    f["existing"] = tmp / "existing.gpkg"
    f["existing"].write_bytes(b"a good earlier result")
    f["existing_laz"] = tmp / "existing.laz"
    f["existing_laz"].write_bytes(b"a good earlier result")
    f["existing_json"] = tmp / "existing.json"
    f["existing_json"].write_bytes(b"a good earlier result")
    f["evaldir"] = tmp / "evaldir"
    f["evaldir"].mkdir()
    (f["evaldir"] / "metrics.json").write_text("{}")
    f["nodir"] = tmp / "no" / "such" / "folder"
    return f
