"""Bad input through the command line: exit 2, one ``error:`` line naming the file, no traceback (issue 10).

Most rows run in process (``rooftrace.cli.main.main(argv)`` returns the exit
code) so the whole table takes seconds; a few rows also run as a real
subprocess to prove that nothing but the one line reaches stderr.  The input
files are built once, tiny, by :func:`tests.cli.badfiles.make_files`; each
row names them as ``{name}``.  Output placeholders ``{out_gpkg}``,
``{out_laz}``, ``{out_json}`` and ``{out_dir}`` are fresh paths of the row.

A row is (id, argv, texts the error line must contain).  Empty clouds and
clouds without buildings are not errors: they have their own table below
(exit 0, an empty but valid output, a warning).
"""

from __future__ import annotations

import os
import subprocess
import sys

import laspy
import pytest

from rooftrace.cli.main import main
from rooftrace.io.vector import list_layers, read_layer
from tests.cli.badfiles import make_files

ROOFTRACE = [sys.executable, "-m", "rooftrace.cli.main"]
GOOD = "a good earlier result"

CAM = ["--image", "{image}", "--camera", "{camera}"]
SNAKE = ["snake", "--image", "{image}", "--camera", "{camera}", "--points", "{scene}", "--seeds", "{seeds}"]

CASES = [
    # missing, unreadable and non-cloud files
    ("info missing file", ["info", "{missing}"], ["missing.laz", "no such file"]),
    ("info folder as input", ["info", "{folder}"], ["is a folder"]),
    ("info zero-byte LAS", ["info", "{zero_bytes}"], ["zero.las", "empty (0 bytes)", "re-export"]),
    ("info zip named .las", ["info", "{not_las}"], ["zip.las", "not a readable LAS/LAZ"]),
    ("info GeoPackage named .laz", ["info", "{gpkg_as_cloud}"], ["outlines_as.laz", "not a readable LAS/LAZ"]),
    ("info words in a text cloud", ["info", "{text_words}"], ["words.txt", "not a text point cloud", "x y z"]),
    ("info text cloud with 2 columns", ["info", "{text_two_cols}"], ["two.csv", "3 numeric columns"]),
    ("info broken PLY", ["info", "{ply_bad}"], ["bad.ply", "not a readable PLY"]),
    ("info unknown suffix", ["info", "{unknown_suffix}"], ["cloud.e57", "unknown point cloud format", ".laz"]),
    ("detect missing file", ["detect", "{missing}", "-o", "{out_laz}"], ["missing.laz", "no such file"]),
    ("run missing file", ["run", "{missing}", "-o", "{out_gpkg}"], ["missing.laz", "no such file"]),
    ("outline missing file", ["outline", "{missing}", "-o", "{out_gpkg}"], ["missing.laz", "no such file"]),
    ("evaluate missing file", ["evaluate", "{missing_gpkg}", "{outlines}", "-o", "{out_dir}"], ["missing.gpkg"]),
    ("evaluate not a vector", ["evaluate", "{not_vector}", "{outlines}", "-o", "{out_dir}"],
     ["not_vector.gpkg", "not a readable vector file", "GeoPackage"]),
    ("evaluate a LAZ as vector", ["evaluate", "{scene}", "{outlines}", "-o", "{out_dir}"],
     ["scene.laz", "not a readable vector file"]),
    ("refine missing outlines", ["refine", "{missing_gpkg}", *CAM, "-o", "{out_gpkg}"], ["missing.gpkg", "no such file"]),
    ("refine no roof_outlines layer", ["refine", "{lines}", *CAM, "-o", "{out_gpkg}"],
     ["lines.gpkg", "no layer 'roof_outlines'"]),
    ("snake missing seeds", [*SNAKE[:-1], "{missing_gpkg}", "-o", "{out_gpkg}"], ["missing.gpkg", "no such file"]),
    ("snake seeds without building", [*SNAKE[:-1], "{seeds_no_building}", "-o", "{out_gpkg}"],
     ["seeds_nob.gpkg", "'building' attribute"]),
    ("snake two seeds", [*SNAKE[:-1], "{seeds_two}", "-o", "{out_gpkg}"], ["seeds_two.gpkg", "at least 3"]),
    ("resect missing GCPs", ["resect", "{missing}", "--camera-in", "{camera}", "-o", "{out_json}"],
     ["missing.laz", "no such GCP file"]),
    ("resect LAZ as GCPs", ["resect", "{scene}", "--camera-in", "{camera}", "-o", "{out_json}"],
     ["scene.laz", "not a UTF-8 text CSV"]),
    ("resect GCP columns", ["resect", "{gcps_columns}", "--camera-in", "{camera}", "-o", "{out_json}"],
     ["gcps_columns.csv", "id,X,Y,Z,col,row"]),
    ("resect GCP value", ["resect", "{gcps_value}", "--camera-in", "{camera}", "-o", "{out_json}"],
     ["gcps_value.csv, line 2", "Z must be a number"]),
    ("resect one GCP", ["resect", "{gcps_few}", "--camera-in", "{camera}", "-o", "{out_json}"],
     ["gcps_few.csv", "at least 3 GCPs"]),
    ("resect collinear GCPs", ["resect", "{gcps_collinear}", "--camera-in", "{camera}", "-o", "{out_json}"],
     ["gcps_collinear.csv", "collinear"]),
    ("run missing image", ["run", "{scene}", "--image", "{missing}", "--camera", "{camera}", "-o", "{out_gpkg}"],
     ["missing.laz", "no such image file"]),
    ("run not an image", ["run", "{scene}", "--image", "{not_image}", "--camera", "{camera}", "-o", "{out_gpkg}"],
     ["not_image.tif", "not a readable image"]),
    # truncated LAZ and LAS header lies
    ("info truncated LAZ", ["info", "{truncated}"], ["truncated.laz", "truncated or corrupt", "re-download"]),
    ("detect truncated LAZ", ["detect", "{truncated}", "-o", "{out_laz}"], ["truncated.laz", "truncated"]),
    ("run header-only LAZ", ["run", "{header_only}", "-o", "{out_gpkg}"], ["header_only.laz", "truncated"]),
    ("evaluate truncated points", ["evaluate", "{outlines}", "{outlines}", "-o", "{out_dir}", "--points", "{truncated}"],
     ["truncated.laz", "truncated"]),
    ("refine truncated points", ["refine", "{outlines}", *CAM, "--points", "{truncated}", "-o", "{out_gpkg}"],
     ["truncated.laz", "truncated"]),
    ("header announces more points", ["info", "{count_high}"], ["count_high.las", "truncated", "announces 6900 points", "only 6400"]),
    ("header announces fewer points", ["detect", "{count_low}", "-o", "{out_laz}"],
     ["count_low.las", "announces 5900 points", "holds 6400", "las2las"]),
    ("header bounds lie", ["run", "{bounds_lie}", "-o", "{out_gpkg}"], ["bounds_lie.las", "outside the header bounds"]),
    ("tiled truncated LAZ", ["run", "{truncated}", "-o", "{out_gpkg}", "--tile-size", "20"],
     ["truncated.laz", "truncated or corrupt"]),
    ("tiled not LAS", ["run", "{not_las}", "-o", "{out_gpkg}", "--tile-size", "20"], ["zip.las", "not a readable LAS"]),
    ("tiled text cloud", ["run", "{text}", "-o", "{out_gpkg}", "--tile-size", "20"], ["cloud.xyz", "LAS/LAZ only"]),
    ("tiled header count lie", ["run", "{count_low}", "-o", "{out_gpkg}", "--tile-size", "20"],
     ["count_low.las", "announces 5900 points"]),
    ("tiled header bounds lie", ["run", "{bounds_lie}", "-o", "{out_gpkg}", "--workers", "1", "--tile-size", "20"],
     ["bounds_lie.las", "outside the header bounds"]),
    # NaN / inf coordinates
    ("tiled NaN", ["run", "{nan_scale}", "-o", "{out_gpkg}", "--tile-size", "20"], ["nan_scale.las", "NaN"]),
    ("NaN scale in LAS", ["detect", "{nan_scale}", "-o", "{out_laz}"], ["nan_scale.las", "NaN or infinite", "remove"]),
    ("NaN and inf in text", ["outline", "{text_nan}", "--single-building", "-o", "{out_gpkg}"],
     ["nan.xyz", "2 points have NaN or infinite"]),
    # all points identical or collinear
    ("detect identical points", ["detect", "{identical}", "-o", "{out_laz}"], ["identical.las", "same x, y"]),
    ("run identical points", ["run", "{identical}", "-o", "{out_gpkg}"], ["identical.las", "same x, y"]),
    ("run collinear points", ["run", "{collinear}", "-o", "{out_gpkg}"], ["collinear.las", "on one line"]),
    ("run two points", ["run", "{two_points}", "-o", "{out_gpkg}"], ["two_points.las", "on one line"]),
    ("outline collinear building", ["outline", "{collinear}", "--single-building", "-o", "{out_gpkg}"],
     ["collinear.las", "on one line"]),
    ("snake identical points", ["snake", "--image", "{image}", "--camera", "{camera}", "--points", "{identical}",
                                "--seeds", "{seeds}", "-o", "{out_gpkg}"], ["identical.las", "same x, y"]),
    ("snake collinear points", ["snake", "--image", "{image}", "--camera", "{camera}", "--points", "{collinear}",
                                "--seeds", "{seeds}", "-o", "{out_gpkg}"], ["collinear.las", "on one line"]),
    ("snake empty cloud", ["snake", "--image", "{image}", "--camera", "{camera}", "--points", "{empty}",
                           "--seeds", "{seeds}", "-o", "{out_gpkg}"], ["empty.las", "no points", "covers the seeds"]),
    # no CRS where one is needed
    ("degrees without CRS", ["run", "{degrees_nocrs}", "-o", "{out_gpkg}"],
     ["degrees_nocrs.las", "no CRS", "look like degrees", "--crs"]),
    ("tiled degrees without CRS", ["run", "{degrees_nocrs}", "-o", "{out_gpkg}", "--tile-size", "20"],
     ["degrees_nocrs.las", "look like degrees"]),
    ("outline degrees without CRS", ["outline", "{degrees_nocrs}", "--single-building", "-o", "{out_gpkg}"],
     ["degrees_nocrs.las", "look like degrees"]),
    ("orthophoto without georeferencing", ["run", "{scene}", "--image", "{image}", "--camera", "{ortho}", "-o",
                                           "{out_gpkg}"], ["image.tif", "no georeferencing", "GeoTIFF"]),
    ("refine orthophoto without georeferencing", ["refine", "{outlines}", "--image", "{image}", "--camera", "{ortho}",
                                                  "-o", "{out_gpkg}"], ["image.tif", "no georeferencing"]),
    ("one file with and one without CRS", ["info", "{scene}", "{nocrs}"], ["nocrs.las", "differs", "--crs"]),
    # CRS mismatch between cloud, image/camera, outlines and seeds
    ("detect cloud vs cloud CRS", ["detect", "{scene}", "{l93}", "-o", "{out_laz}"], ["l93.las", "scene.laz", "CRS"]),
    ("run cloud vs camera CRS", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_l93}", "-o", "{out_gpkg}"],
     ["scene.laz", "camera_l93.json", "different CRSs", "reproject"]),
    ("refine outlines vs camera CRS", ["refine", "{outlines_l93}", *CAM, "-o", "{out_gpkg}"],
     ["outlines_l93.gpkg", "camera.json", "different CRSs"]),
    ("refine outlines vs points CRS", ["refine", "{outlines}", *CAM, "--points", "{l93}", "-o", "{out_gpkg}"],
     ["outlines.gpkg", "l93.las", "different CRSs"]),
    ("evaluate extracted vs reference CRS", ["evaluate", "{outlines}", "{outlines_l93}", "-o", "{out_dir}"],
     ["outlines.gpkg", "outlines_l93.gpkg", "different CRSs"]),
    ("evaluate points vs outlines CRS", ["evaluate", "{outlines}", "{outlines}", "--points", "{l93}", "-o", "{out_dir}"],
     ["l93.las", "different CRSs"]),
    ("snake cloud vs camera CRS", ["snake", "--image", "{image}", "--camera", "{camera_l93}", "--points", "{scene}",
                                   "--seeds", "{seeds}", "-o", "{out_gpkg}"], ["camera_l93.json", "different CRSs"]),
    ("snake cloud vs seeds CRS", [*SNAKE[:-1], "{seeds_l93}", "-o", "{out_gpkg}"], ["seeds_l93.gpkg", "different CRSs"]),
    # geographic CRS where metres are needed
    ("detect geographic cloud", ["detect", "{wgs84}", "-o", "{out_laz}"], ["wgs84.las", "geographic", "reproject"]),
    ("run geographic cloud", ["run", "{wgs84}", "-o", "{out_gpkg}"], ["wgs84.las", "geographic"]),
    ("outline geographic cloud", ["outline", "{wgs84}", "--single-building", "-o", "{out_gpkg}"], ["geographic"]),
    ("run --crs degrees", ["run", "{scene}", "--crs", "EPSG:4326", "-o", "{out_gpkg}"], ["scene.laz", "geographic"]),
    ("run geographic camera", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_wgs84}", "-o",
                               "{out_gpkg}"], ["camera_wgs84.json", "different CRSs"]),
    ("refine geographic outlines", ["refine", "{outlines_wgs84}", *CAM, "-o", "{out_gpkg}"],
     ["outlines_wgs84.gpkg", "geographic"]),
    ("evaluate geographic outlines", ["evaluate", "{outlines_wgs84}", "{outlines_wgs84}", "-o", "{out_dir}"],
     ["outlines_wgs84.gpkg", "geographic"]),
    ("snake geographic cloud", ["snake", "--image", "{image}", "--camera", "{camera}", "--points", "{wgs84}",
                                "--seeds", "{seeds}", "-o", "{out_gpkg}"], ["wgs84.las", "geographic"]),
    ("resect geographic camera", ["resect", "{gcps}", "--camera-in", "{camera_wgs84}", "-o", "{out_json}"],
     ["camera_wgs84.json", "geographic"]),
    # image that does not cover the cloud, or of the wrong size
    ("run image far from cloud", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_far}", "-o",
                                  "{out_gpkg}"], ["image.tif", "does not cover", "camera file"]),
    ("refine image far from outlines", ["refine", "{outlines_far}", *CAM, "-o", "{out_gpkg}"],
     ["image.tif", "does not cover"]),
    ("snake image far from seeds", ["snake", "--image", "{image}", "--camera", "{camera_far}", "--points", "{scene}",
                                    "--seeds", "{seeds}", "-o", "{out_gpkg}"], ["seeds.geojson", "outside the image"]),
    ("snake seeds far from cloud", [*SNAKE[:-1], "{seeds_far}", "-o", "{out_gpkg}"],
     ["seeds_far.gpkg", "LiDAR points near the seeds"]),
    ("run image size vs camera", ["run", "{scene}", "--image", "{image_small}", "--camera", "{camera}", "-o",
                                  "{out_gpkg}"], ["image_small.tif", "120 x 100", "400 x 400"]),
    # a tiled run checks the image on the headers before any tile work
    ("tiled run cloud vs camera CRS", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_l93}", "-o",
                                       "{out_gpkg}", "--tile-size", "20"], ["camera_l93.json", "different CRSs"]),
    ("tiled run image far from cloud", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_far}", "-o",
                                        "{out_gpkg}", "--tile-size", "20"], ["image.tif", "does not cover"]),
    ("tiled run image size vs camera", ["run", "{scene}", "--image", "{image_small}", "--camera", "{camera}", "-o",
                                        "{out_gpkg}", "--tile-size", "20"], ["image_small.tif", "120 x 100", "400 x 400"]),
    ("refine image size vs camera", ["refine", "{outlines}", "--image", "{image_small}", "--camera", "{camera}", "-o",
                                     "{out_gpkg}"], ["image_small.tif", "120 x 100"]),
    # malformed camera.json
    ("camera missing", ["run", "{scene}", "--image", "{image}", "--camera", "{missing_json}", "-o", "{out_gpkg}"],
     ["missing.json", "no such camera file"]),
    ("camera not JSON", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_syntax}", "-o", "{out_gpkg}"],
     ["camera_syntax.json", "not valid JSON", "fix the camera file"]),
    ("camera binary", ["refine", "{outlines}", "--image", "{image}", "--camera", "{camera_binary}", "-o", "{out_gpkg}"],
     ["camera_binary.json", "not valid JSON"]),
    ("camera is a list", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_list}", "-o", "{out_gpkg}"],
     ["camera_list.json", "JSON object"]),
    ("camera without exterior", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_no_exterior}", "-o",
                                 "{out_gpkg}"], ["camera_no_exterior.json", "'exterior'", "fix the camera file"]),
    ("camera image_size strings", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_size}", "-o",
                                   "{out_gpkg}"], ["camera_size.json", "'image_size'"]),
    ("camera principal point strings", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_pp}", "-o",
                                        "{out_gpkg}"], ["camera_pp.json", "'principal_point_mm' must be a number"]),
    ("camera covariance 2x2", ["refine", "{outlines}", "--image", "{image}", "--camera", "{camera_cov}", "-o",
                               "{out_gpkg}"], ["camera_cov.json", "6 x 6"]),
    ("camera unknown type", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_type}", "-o", "{out_gpkg}"],
     ["camera_type.json", "'frame' or 'orthophoto'"]),
    ("camera negative focal length", ["snake", "--image", "{image}", "--camera", "{camera_focal}", "--points",
                                      "{scene}", "--seeds", "{seeds}", "-o", "{out_gpkg}"],
     ["camera_focal.json", "must be positive"]),
    ("camera angle text", ["resect", "{gcps}", "--camera-in", "{camera_angle}", "-o", "{out_json}"],
     ["camera_angle.json", "'omega_deg' must be a number"]),
    ("camera bad CRS", ["run", "{scene}", "--image", "{image}", "--camera", "{camera_crs}", "-o", "{out_gpkg}"],
     ["camera_crs.json", "not a valid CRS"]),
    ("resect orthophoto camera", ["resect", "{gcps}", "--camera-in", "{ortho}", "-o", "{out_json}"],
     ["ortho.json", "orthophoto"]),
    # config files: unknown sections and keys, wrong types and values, syntax
    ("config missing", ["detect", "{scene}", "-o", "{out_laz}", "--config", "{missing_json}"],
     ["missing.json", "no such config file"]),
    ("config syntax", ["run", "{scene}", "-o", "{out_gpkg}", "--config", "{cfg_syntax}"], ["syntax.toml", "not valid TOML"]),
    ("config top-level key", ["outline", "{text}", "--single-building", "-o", "{out_gpkg}", "--config",
                              "{cfg_toplevel}"], ["toplevel.toml", "'seed'", "[table]"]),
    ("config unknown section run", ["run", "{scene}", "-o", "{out_gpkg}", "--config", "{cfg_section}"],
     ["section.toml", "unknown section", "segmnet", "known:"]),
    ("config unknown section detect", ["detect", "{scene}", "-o", "{out_laz}", "--config", "{cfg_section}"],
     ["section.toml", "segmnet"]),
    ("config unknown section outline", ["outline", "{text}", "--single-building", "-o", "{out_gpkg}", "--config",
                                        "{cfg_section}"], ["section.toml", "segmnet"]),
    ("config unknown section refine", ["refine", "{outlines}", *CAM, "-o", "{out_gpkg}", "--config", "{cfg_section}"],
     ["section.toml", "segmnet"]),
    ("config unknown section snake", [*SNAKE, "-o", "{out_gpkg}", "--config", "{cfg_section}"], ["segmnet"]),
    ("config unknown section resect", ["resect", "{gcps}", "--camera-in", "{camera}", "-o", "{out_json}", "--config",
                                       "{cfg_section}"], ["section.toml", "segmnet"]),
    ("config unknown section simulate", ["simulate", "-o", "{out_dir}", "--config", "{cfg_section}"], ["segmnet"]),
    ("config unknown key run", ["run", "{scene}", "-o", "{out_gpkg}", "--config", "{cfg_key}"],
     ["key.toml", "[alpha]", "strategie", "known:"]),
    ("config unknown key detect", ["detect", "{scene}", "-o", "{out_laz}", "--config", "{cfg_key}"],
     ["key.toml", "strategie"]),
    ("config unknown key refine", ["refine", "{outlines}", *CAM, "-o", "{out_gpkg}", "--config", "{cfg_key}"],
     ["key.toml", "strategie"]),
    ("config unknown key snake", [*SNAKE, "-o", "{out_gpkg}", "--config", "{cfg_snake_key}"], ["snake_key.toml", "stepz"]),
    ("config unknown key resect", ["resect", "{gcps}", "--camera-in", "{camera}", "-o", "{out_json}", "--config",
                                   "{cfg_resection_key}"], ["resection_key.toml", "sigma"]),
    ("config unknown key simulate", ["simulate", "-o", "{out_dir}", "--config", "{cfg_sim_key}"],
     ["sim_key.toml", "densiti"]),
    ("config wrong type", ["run", "{scene}", "-o", "{out_gpkg}", "--config", "{cfg_type}"],
     ["type.toml", "[ground] iteration_distance must be a number", "'far'"]),
    ("config wrong value", ["detect", "{scene}", "-o", "{out_laz}", "--config", "{cfg_value}"],
     ["value.toml", "[alpha]", "'sideways'"]),
    # bad option values
    ("bad --crs", ["info", "{scene}", "--crs", "EPSG:99999"], ["--crs", "EPSG:99999"]),
    ("bad --alpha run", ["run", "{scene}", "-o", "{out_gpkg}", "--alpha", "sideways"], ["--alpha", "sideways"]),
    ("bad --alpha outline", ["outline", "{text}", "--single-building", "-o", "{out_gpkg}", "--alpha", "x"], ["--alpha"]),
    ("frame --image without --camera", ["run", "{scene}", "-o", "{out_gpkg}", "--image", "{image}"],
     ["image.tif", "no georeference", "--camera camera.json", "georeferenced orthophoto"]),
    ("--camera without --image", ["run", "{scene}", "-o", "{out_gpkg}", "--camera", "{image}"],
     ["--camera needs --image"]),
    ("--workers 0", ["run", "{scene}", "-o", "{out_gpkg}", "--workers", "0"], ["--workers"]),
    ("--tile-size negative", ["run", "{scene}", "-o", "{out_gpkg}", "--tile-size", "-5"], ["--tile-size"]),
    ("--seed negative", ["run", "{scene}", "-o", "{out_gpkg}", "--seed", "-1"], ["--seed"]),
    ("--seed text", ["simulate", "-o", "{out_dir}", "--seed", "x"], ["--seed"]),
    ("simulate --seed negative", ["simulate", "-o", "{out_dir}", "--seed", "-1"], ["--seed"]),
    ("--min-area 0", ["detect", "{scene}", "-o", "{out_laz}", "--min-area", "0"], ["--min-area"]),
    ("--min-overlap 2", ["evaluate", "{outlines}", "{outlines}", "-o", "{out_dir}", "--min-overlap", "2"],
     ["--min-overlap"]),
    ("--ridge-buffer negative", ["evaluate", "{outlines}", "{outlines}", "-o", "{out_dir}", "--ridge-buffer", "-1"],
     ["--ridge-buffer"]),
    ("--sigma-px negative", ["resect", "{gcps}", "--camera-in", "{camera}", "-o", "{out_json}", "--sigma-px", "-1"],
     ["--sigma-px"]),
    ("simulate --density 0", ["simulate", "-o", "{out_dir}", "--density", "0"], ["density must be a positive number"]),
    ("simulate --size 1", ["simulate", "-o", "{out_dir}", "--size", "1"], ["size must be between"]),
    ("demo --density 0", ["demo", "-o", "{out_dir}", "--density", "0"], ["--density"]),
    ("demo --size 10", ["demo", "-o", "{out_dir}", "--size", "10"], ["--size"]),
    ("unknown option", ["info", "{scene}", "--frobnicate"], ["No such option"]),
    ("unknown command", ["frobnicate"], ["No such command"]),
    ("missing argument", ["detect"], ["Missing argument"]),
    ("outline unclassified cloud", ["outline", "{scene}", "-o", "{out_gpkg}"],
     ["scene.laz", "not classified", "rooftrace detect", "--single-building"]),
    # output formats and places
    ("run output not gpkg", ["run", "{scene}", "-o", "{tmp}/x.laz"], ["x.laz", "*.gpkg"]),
    ("run --classified not LAZ", ["run", "{scene}", "-o", "{out_gpkg}", "--classified", "{tmp}/x.gpkg"],
     ["x.gpkg", "--classified", "*.laz"]),
    ("detect output not LAZ", ["detect", "{scene}", "-o", "{tmp}/x.gpkg"], ["x.gpkg", ".las or .laz"]),
    ("outline Shapefile output", ["outline", "{text}", "--single-building", "-o", "{tmp}/x.shp"],
     ["x.shp", "Shapefile output is not supported", ".gpkg"]),
    ("outline unknown vector suffix", ["outline", "{text}", "--single-building", "-o", "{tmp}/x.txt"],
     ["x.txt", "unknown vector format"]),
    ("snake Shapefile output", [*SNAKE, "-o", "{tmp}/x.shp"], ["x.shp", "Shapefile"]),
    ("refine output not gpkg", ["refine", "{outlines}", *CAM, "-o", "{tmp}/x.geojson"], ["x.geojson", "*.gpkg"]),
    ("output folder missing", ["detect", "{scene}", "-o", "{nodir}/x.laz"], ["does not exist", "create it"]),
    ("output is a folder", ["detect", "{scene}", "-o", "{folder}", "--overwrite"], ["is a folder", "file name"]),
    ("evaluate -o a file", ["evaluate", "{outlines}", "{outlines}", "-o", "{existing}"], ["existing.gpkg", "folder"]),
    ("simulate -o a file", ["simulate", "-o", "{existing}"], ["existing.gpkg", "not a folder"]),
    ("demo -o a file", ["demo", "-o", "{existing}"], ["existing.gpkg", "not a folder"]),
    # -o onto an existing result without --overwrite
    ("run -o existing", ["run", "{scene}", "-o", "{existing}"], ["existing.gpkg", "--overwrite"]),
    ("run --classified existing", ["run", "{scene}", "-o", "{out_gpkg}", "--classified", "{existing_laz}"],
     ["existing.laz", "--overwrite"]),
    ("detect -o existing", ["detect", "{scene}", "-o", "{existing_laz}"], ["existing.laz", "--overwrite"]),
    ("outline -o existing", ["outline", "{text}", "--single-building", "-o", "{existing}"],
     ["existing.gpkg", "--overwrite"]),
    ("refine -o existing", ["refine", "{outlines}", *CAM, "-o", "{existing}"], ["existing.gpkg", "--overwrite"]),
    ("snake -o existing", [*SNAKE, "-o", "{existing}"], ["existing.gpkg", "--overwrite"]),
    ("resect -o existing", ["resect", "{gcps}", "--camera-in", "{camera}", "-o", "{existing_json}"],
     ["existing.json", "--overwrite"]),
    ("evaluate -o earlier evaluation", ["evaluate", "{outlines}", "{outlines}", "-o", "{evaldir}"],
     ["metrics.json", "--overwrite"]),
    ("demo -o non-empty folder", ["demo", "-o", "{evaldir}"], ["evaldir", "--overwrite"]),
]

#: rows also run as a real subprocess: the ones that used to end in a traceback or "internal failure"
SUBPROCESS = ["detect truncated LAZ", "camera principal point strings", "orthophoto without georeferencing",
              "run collinear points", "config unknown key detect", "run -o existing"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return make_files(tmp_path_factory.mktemp("bad_inputs"))


def _argv(args: list[str], files: dict, out) -> list[str]:
    names = {**files, "out_gpkg": out / "out.gpkg", "out_laz": out / "out.laz", "out_json": out / "out.json",
             "out_dir": out / "outdir", "nodir": files["tmp"] / "no" / "such"}
    return [a.format(**names) for a in args]


def _snapshot(folder) -> dict:
    return {p.relative_to(folder): p.stat().st_mtime_ns for p in folder.rglob("*")}


@pytest.mark.parametrize("name,args,expect", CASES, ids=[c[0] for c in CASES])
def test_bad_input_gives_one_error_line(files, tmp_path, capsys, name, args, expect):
    before = _snapshot(files["tmp"])
    code = main(_argv(args, files, tmp_path))
    err = capsys.readouterr().err
    assert code == 2, err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, err
    for text in expect:
        assert text in errors[0], f"{text!r} not in {errors[0]!r}"
    assert "Traceback" not in err
    # nothing written: neither a new output nor a changed input or earlier result (a tiled run
    # keeps its OUTPUT.parts folder of finished tiles for --resume, never the output itself)
    assert [p.name for p in tmp_path.iterdir() if not p.name.endswith(".parts")] == []
    assert _snapshot(files["tmp"]) == before
    assert files["existing"].read_text() == GOOD


@pytest.mark.parametrize("name", SUBPROCESS)
def test_bad_input_in_a_real_process_prints_only_the_error_line(files, tmp_path, name):
    args, expect = next((a, e) for n, a, e in CASES if n == name)
    # the user's environment as it is: no warning filter, no --quiet
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONWARNINGS", "ROOFTRACE_DEBUG")}
    proc = subprocess.run(ROOFTRACE + _argv(args, files, tmp_path), capture_output=True, text=True,
                          cwd=tmp_path, env=env, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("error:") and proc.stderr.count("\n") == 1, proc.stderr
    assert all(text in proc.stderr for text in expect), proc.stderr
    assert proc.stdout == ""


# not errors: empty clouds, clouds without buildings, degenerate buildings -> exit 0, valid output, a warning
EMPTY_CASES = [
    ("run empty cloud", ["run", "{empty}", "-o", "{out_gpkg}"], "no points", "out.gpkg"),
    ("run empty cloud with image", ["run", "{empty}", *CAM, "-o", "{out_gpkg}", "--classified", "{out_laz}"],
     "no points", "out.gpkg"),
    ("run no buildings", ["run", "{ground}", "-o", "{out_gpkg}"], "no buildings found", "out.gpkg"),
    ("run empty cloud tiled", ["run", "{empty}", "-o", "{out_gpkg}", "--tile-size", "20"], "no points", "out.gpkg"),
    ("run no buildings tiled", ["run", "{ground}", "-o", "{out_gpkg}", "--tile-size", "20"], "no buildings found",
     "out.gpkg"),
    ("detect empty cloud", ["detect", "{empty}", "-o", "{out_laz}"], "no points", "out.laz"),
    ("detect no buildings", ["detect", "{ground}", "-o", "{out_laz}"], "no buildings found", "out.laz"),
    ("outline empty cloud", ["outline", "{empty}", "-o", "{out_gpkg}"], "no points", "out.gpkg"),
    ("outline empty single building", ["outline", "{empty}", "--single-building", "-o", "{out_gpkg}"], "no points",
     "out.gpkg"),
    ("outline classified, no buildings", ["outline", "{classified_no6}", "-o", "{out_gpkg}"], "no class-6",
     "out.gpkg"),
    ("outline one-point building", ["outline", "{classified_one}", "-o", "{out_gpkg}"], "have no outline", "out.gpkg"),
    ("refine empty outlines", ["refine", "{outlines_empty}", *CAM, "-o", "{out_gpkg}"], "no outlines", "out.gpkg"),
    ("refine empty points", ["refine", "{outlines}", *CAM, "--points", "{empty}", "-o", "{out_gpkg}"], "no points",
     "out.gpkg"),
    ("evaluate empty extracted", ["evaluate", "{outlines_empty}", "{outlines}", "-o", "{out_dir}"], "no outlines",
     "outdir/metrics.json"),
]


@pytest.mark.parametrize("name,args,warning,written", EMPTY_CASES, ids=[c[0] for c in EMPTY_CASES])
def test_empty_input_gives_an_empty_valid_output_and_a_warning(files, tmp_path, capsys, name, args, warning, written):
    code = main(_argv(args, files, tmp_path))
    err = capsys.readouterr().err
    assert code == 0, err
    assert warning in " ".join(err.split()) and "error:" not in err
    out = tmp_path / written
    assert out.is_file()
    if out.suffix == ".gpkg":
        layers = list_layers(out)
        assert "roof_outlines" in layers
        outlines = read_layer(out, "roof_outlines")
        if name == "outline one-point building":
            assert outlines.attributes["status"] == ["too_few_points"] and outlines.geometries[0] is None
        elif name != "refine empty points":
            assert len(outlines) == 0 and "building_id" in outlines.attributes
        if name.startswith("run"):
            assert {"roof_outlines", "ridges", "roof_faces"} <= set(layers)
    elif out.suffix == ".laz":
        las = laspy.read(out)
        assert "building_id" in las.point_format.dimension_names
        assert not (las.classification == 6).any()
    if name == "run empty cloud with image":
        assert laspy.read(tmp_path / "out.laz").header.point_count == 0
