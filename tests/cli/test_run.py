"""`rooftrace run` and `rooftrace demo` end to end on small simulated scenes."""

import json
import re

import laspy
import numpy as np
import pyogrio
import pytest

from rooftrace.cli.app import rounded
from rooftrace.cli.main import main
from rooftrace.evaluate import evaluate
from rooftrace.io.vector import read_layer


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene")
    assert main(["simulate", "-o", str(out), "--size", "60", "--density", "8", "--seed", "4", "-q"]) == 0
    return out


def test_run_with_image_writes_the_three_layers_and_the_classified_points(scene_dir, tmp_path, capsys):
    out, laz = tmp_path / "roofs.gpkg", tmp_path / "classified.laz"
    code = main(["run", str(scene_dir / "points.laz"), "--image", str(scene_dir / "image.tif"),
                 "--camera", str(scene_dir / "camera.json"), "-o", str(out), "--classified", str(laz), "--json", "-q"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["refined"] and summary["buildings"] >= 1

    outlines = read_layer(out, "roof_outlines")
    ridges = read_layer(out, "ridges")
    faces = read_layer(out, "roof_faces")
    assert len(outlines) == summary["buildings"] and len(ridges) == summary["ridges"]
    assert len(faces) == summary["roof_faces"] > 0
    assert all(g.has_z for g in outlines.geometries)
    assert {"building_id", "status", "refine_status"} <= set(outlines.attributes)
    crs = pyogrio.read_info(out, layer="roof_outlines")["crs"]
    assert crs and crs == pyogrio.read_info(scene_dir / "truth.gpkg", layer="roof_outlines")["crs"]

    truth = read_layer(scene_dir / "truth.gpkg", "roof_outlines")
    metrics = evaluate(list(outlines.geometries), list(truth.geometries))
    assert metrics["f_score"] > 0.9
    assert metrics["polis_mean"] < 0.3
    assert metrics["rmse_z"] < 0.5  # outline heights are the eaves', not the walls'

    las = laspy.read(laz)
    ids = np.asarray(las["building_id"])
    assert set(np.unique(ids[ids > 0])) == set(outlines.attributes["building_id"])
    assert np.all(np.asarray(las.classification)[ids > 0] == 6)


def test_run_refuses_an_unknown_config_table_and_an_existing_output(scene_dir, tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[segmnet]\nmin_height = 2\n")
    out = tmp_path / "roofs.gpkg"
    assert main(["run", str(scene_dir / "points.laz"), "-o", str(out), "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "segmnet" in err and not out.exists()
    out.write_bytes(b"a good result")
    assert main(["run", str(scene_dir / "points.laz"), "-o", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"a good result"


def test_demo_writes_report_metrics_and_result(tmp_path, capsys):
    out = tmp_path / "demo"
    code = main(["demo", "-o", str(out), "--size", "50", "--density", "6", "--seed", "2", "--json", "-q"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for name in ("report.html", "metrics.json", "result.gpkg", "result.city.jsonl", "truth.gpkg", "points.laz",
                 "image.tif", "models_3d.png"):
        assert (out / name).is_file(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert rounded(metrics["f_score"]) == summary["f_score"] > 0.85  # the --json summary is rounded
    assert "polis_mean_lidar_only" in summary
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html
    # the report shows the image with both outline sets, and both sets' scores side by side
    assert (out / "image.png").is_file() and "<th>LiDAR only</th>" in html
    assert metrics["compare"]["label"] == "LiDAR only"
    assert metrics["compare"]["polis_mean"] == pytest.approx(summary["polis_mean_lidar_only"], abs=1e-4)  # rounded
    # a second demo into the same folder needs --overwrite
    assert main(["demo", "-o", str(out), "--size", "50", "--density", "6"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    # --overwrite replaces the whole folder: nothing of the run with the image stays beside a --no-image one
    before = {p.name for p in out.iterdir()}
    assert main(["demo", "-o", str(out), "--size", "50", "--density", "6", "--seed", "2", "--no-image",
                 "--overwrite", "-q"]) == 0
    after = {p.name for p in out.iterdir()}
    text = capsys.readouterr().out  # rounded, with units
    assert re.search(r"polis_mean: \d+\.\d{3} m\n", text) and not re.search(r"\d\.\d{4,}", text), text
    assert {"image.tif", "camera.json"} <= before and not after & {"image.tif", "camera.json"}
    assert {"report.html", "metrics.json", "result.gpkg", "truth.gpkg", "points.laz", ".rooftrace-demo"} <= after
    assert [p.name for p in tmp_path.iterdir()] == ["demo"]  # no temporary folder beside it


def test_demo_overwrite_refuses_a_folder_that_is_not_a_demo(tmp_path, capsys):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("keep me")
    assert main(["demo", "-o", str(folder), "--size", "50", "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {folder}: not the output of an earlier demo") and err.count("\n") == 1
    assert [p.name for p in folder.iterdir()] == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]
