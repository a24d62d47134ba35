"""``rooftrace detect`` through :func:`rooftrace.cli.main.main` (returns the exit code)."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from rooftrace.cli.main import main
from tests.lidar.scenes import BUILDING, GROUND, f1, scene


def _write(path: Path, xyz: np.ndarray, *, version: str = "1.4", fmt: int = 6, crs: str | None = "EPSG:28992",
           classification: int = 1) -> Path:
    header = laspy.LasHeader(version=version, point_format=fmt)
    header.scales = [0.001] * 3
    header.offsets = np.floor(xyz.min(axis=0)) if len(xyz) else [0, 0, 0]
    if crs:
        header.add_crs(pyproj.CRS(crs))
    las = laspy.LasData(header)
    if len(xyz):
        las.x, las.y, las.z = xyz.T
        las.classification = np.full(len(xyz), classification, np.uint8)
        las.intensity = np.arange(len(xyz)) % 1000
    las.write(path)
    return path


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    rng = np.random.default_rng(21)
    xyz, truth = scene(rng, size=50, density=8, boxes=((10.0, 10.0, 12.0, 10.0, 6.0), (30.0, 28.0, 10.0, 12.0, 8.0)),
                       trees=((35.0, 10.0, 3.0, 2.0, 8.0),))
    xyz = xyz + [85_000, 447_000, 0]
    folder = tmp_path_factory.mktemp("detect")
    half = xyz[:, 0] < 85_025
    # two tiles, LAS 1.2 (format 1) and LAZ 1.4 (format 6); their classes (all "building") must be ignored
    a = _write(folder / "a.las", xyz[half], version="1.2", fmt=1, classification=6)
    b = _write(folder / "b.laz", xyz[~half], classification=6)
    return folder, (a, b), np.concatenate([truth[half], truth[~half]])


def test_detect_writes_classes_and_building_id(block, capsys):
    folder, inputs, truth = block
    out = folder / "out.laz"
    code = main(["detect", *map(str, inputs), "-o", str(out), "--json", "--quiet"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["buildings"] == 2
    assert summary["points"] == len(truth)
    assert set(summary["timings"]) >= {"read", "ground", "segment", "classify", "write"}
    assert summary["params"]["segment"]["min_points"] >= 1
    las = laspy.read(out)
    assert las.header.parse_crs().equals(pyproj.CRS("EPSG:28992"))
    cls = np.asarray(las.classification)
    bid = np.asarray(las["building_id"])
    assert bid.dtype == np.int32 and set(np.unique(bid)) == {0, 1, 2}
    assert np.array_equal(bid > 0, cls == 6)
    assert f1(cls == 6, truth == BUILDING) > 0.97
    assert f1(cls == 2, truth == GROUND) > 0.99
    assert summary["classes"]["building"] == int((cls == 6).sum())
    # every input dimension is kept, in input order (tile a, then tile b)
    na = laspy.read(inputs[0]).header.point_count
    expected = np.concatenate([np.arange(na) % 1000, np.arange(len(truth) - na) % 1000])
    assert np.array_equal(np.asarray(las.intensity), expected)


def test_refuses_to_overwrite(block, capsys):
    folder, inputs, _ = block
    out = folder / "exists.laz"
    out.write_bytes(b"keep me")
    assert main(["detect", str(inputs[0]), "-o", str(out), "--quiet"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"keep me"
    assert main(["detect", str(inputs[0]), "-o", str(out), "--quiet", "--overwrite", "--min-area", "2"]) == 0
    assert laspy.read(out).header.point_count > 0


def test_config_file_and_unknown_key(block, tmp_path, capsys):
    _, inputs, _ = block
    cfg = tmp_path / "c.toml"
    cfg.write_text("[segment]\nmin_area = 5000.0\n")
    out = tmp_path / "o.laz"
    assert main(["detect", str(inputs[1]), "-o", str(out), "--config", str(cfg), "--json", "-q"]) == 0
    assert json.loads(capsys.readouterr().out)["buildings"] == 0
    cfg.write_text("[segment]\nmin_aera = 5.0\n")
    assert main(["detect", str(inputs[1]), "-o", str(tmp_path / "p.laz"), "--config", str(cfg), "-q"]) == 2
    assert "min_aera" in capsys.readouterr().err


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    assert "Traceback" not in err[0]
    return err[0]


def test_bad_input(tmp_path, capsys):
    out = str(tmp_path / "out.laz")
    assert main(["detect", str(tmp_path / "missing.laz"), "-o", out, "-q"]) == 2
    assert "missing.laz" in _error_line(capsys)

    fake = tmp_path / "fake.las"
    fake.write_text("this is not a LAS file\n")
    assert main(["detect", str(fake), "-o", out, "-q"]) == 2
    assert "fake.las" in _error_line(capsys)

    # issue 10: an empty cloud is not an error, it gives an empty classified file and a warning
    empty = _write(tmp_path / "empty.las", np.empty((0, 3)))
    assert main(["detect", str(empty), "-o", str(tmp_path / "empty_out.laz"), "-q"]) == 0
    assert "no points" in " ".join(capsys.readouterr().err.split())  # rich wraps long log lines
    assert laspy.read(tmp_path / "empty_out.laz").header.point_count == 0

    rng = np.random.default_rng(0)
    lonlat = np.column_stack([4.35 + rng.uniform(0, 1e-3, 300), 52.0 + rng.uniform(0, 1e-3, 300), rng.uniform(0, 5, 300)])
    geo = _write(tmp_path / "geo.laz", lonlat, crs="EPSG:4326")
    assert main(["detect", str(geo), "-o", out, "-q"]) == 2
    assert "geographic" in _error_line(capsys)

    ok = _write(tmp_path / "ok.laz", np.column_stack([rng.uniform(0, 20, (300, 2)), rng.uniform(0, 1, 300)]))
    assert main(["detect", str(ok), "-o", str(tmp_path / "out.txt"), "-q"]) == 2
    assert ".las or .laz" in _error_line(capsys)
    assert not (tmp_path / "out.laz").exists()
