"""``rooftrace resect`` through the command-line entry point."""

import json

import numpy as np
import pytest

from rooftrace.cli.main import main
from rooftrace.image.camera import FrameCamera
from rooftrace.io.camera import read_camera, write_camera

TRUE_EO = np.array([500.0, 800.0, 900.0, 0.02, -0.01, 0.4])


def _setup(tmp_path, rng, n=8, noise=0.3):
    truth = FrameCamera((3000, 2000), 0.012, 80.0, TRUE_EO, crs=None)
    xyz = np.column_stack([rng.uniform(400, 600, n), rng.uniform(700, 900, n), rng.uniform(0, 30, n)])
    cr = truth.project(xyz) + rng.normal(0, noise, (n, 2))
    gcps = tmp_path / "gcps.csv"
    lines = ["id,X,Y,Z,col,row"] + [f"g{i},{x:.4f},{y:.4f},{z:.4f},{c:.3f},{r:.3f}"
                                    for i, ((x, y, z), (c, r)) in enumerate(zip(xyz, cr))]
    gcps.write_text("\n".join(lines) + "\n")
    cam_in = tmp_path / "cam_in.json"
    write_camera(cam_in, truth.with_exterior(TRUE_EO + [20, -10, 40, 0.01, 0.01, 0.05]))
    return gcps, cam_in


def test_resect_writes_an_oriented_camera(tmp_path, rng, capsys):
    gcps, cam_in = _setup(tmp_path, rng)
    out = tmp_path / "camera.json"
    assert main(["resect", str(gcps), "--camera-in", str(cam_in), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["gcps"] == 8 and 0.1 < summary["sigma0_px"] < 0.6 and summary["rms_px"] < 0.6
    cam = read_camera(out)
    assert cam.exterior_covariance.shape == (6, 6)
    # recovered within the precision it reports (X0 and phi correlate strongly over a small block)
    z = (cam.exterior - TRUE_EO) / np.sqrt(np.diag(cam.exterior_covariance))
    assert np.abs(z).max() < 4
    assert summary["std"]["X0"] == pytest.approx(np.sqrt(cam.exterior_covariance[0, 0]), rel=1e-3)  # rounded in --json
    # no overwrite without --overwrite; plain text output otherwise
    assert main(["resect", str(gcps), "--camera-in", str(cam_in), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["resect", str(gcps), "--camera-in", str(cam_in), "-o", str(out), "--overwrite"]) == 0
    assert "residual RMS" in capsys.readouterr().out


@pytest.mark.parametrize(
    "content, message",
    [
        ("id,X,Y,col,row\na,1,2,3,4\n", "missing column"),
        ("id,X,Y,Z,col,row\na,1,2,3,4,5\nb,1,2,3,x,5\nc,1,1,1,1,1\n", "line 3: col must be a number"),
        ("id,X,Y,Z,col,row\na,1,2,3,4,5\nb,3,2,3,4,5\n", "at least 3 GCPs"),
        ("id,X,Y,Z,col,row\na,1,2,3,4,5\na,3,2,3,4,5\nb,1,5,1,1,1\n", "duplicated"),
        ("id,X,Y,Z,col,row\na,0,0,0,4,5\nb,1,1,0,40,5\nc,2,2,0,80,5\nd,3,3,0,120,5\n", "collinear"),
    ],
)
def test_resect_bad_gcps(tmp_path, rng, capsys, content, message):
    _, cam_in = _setup(tmp_path, rng)
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    code = main(["resect", str(bad), "--camera-in", str(cam_in), "-o", str(tmp_path / "o.json")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error:") and message in err
    assert not (tmp_path / "o.json").exists()


def test_resect_missing_files_and_orthophoto(tmp_path, rng, capsys):
    gcps, cam_in = _setup(tmp_path, rng)
    assert main(["resect", str(tmp_path / "no.csv"), "--camera-in", str(cam_in), "-o", str(tmp_path / "o.json")]) == 2
    assert "no such GCP file" in capsys.readouterr().err
    ortho = tmp_path / "ortho.json"
    ortho.write_text('{"type": "orthophoto"}')
    assert main(["resect", str(gcps), "--camera-in", str(ortho), "-o", str(tmp_path / "o.json")]) == 2
    assert "error:" in capsys.readouterr().err
