"""Bad input through the real command line (subprocess): exit code 2, one ``error:`` line, no traceback.

Issue 10.  Each row is (name, arguments, files to create, text the error line must contain).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest

ROOFTRACE = [sys.executable, "-m", "rooftrace.cli.main"]


def _las(path: Path, n: int = 200, crs: str | None = None, xyz: np.ndarray | None = None) -> Path:
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales = [0.001] * 3
    header.offsets = [0, 0, 0]
    if crs:
        import pyproj

        header.add_crs(pyproj.CRS.from_user_input(crs))
    las = laspy.LasData(header)
    if xyz is None:
        rng = np.random.default_rng(0)
        xyz = np.column_stack([rng.uniform(0, 50, n), rng.uniform(0, 50, n), rng.uniform(0, 5, n)])
    las.x, las.y, las.z = xyz.T
    las.write(path)
    return path


def _files(tmp: Path) -> dict[str, Path]:
    f = {
        "missing": tmp / "missing.laz",
        "notlas": tmp / "not.las",
        "empty": _las(tmp / "empty.las", xyz=np.empty((0, 3))),
        "ok": _las(tmp / "ok.laz"),
        "ok_rd": _las(tmp / "ok_rd.las", crs="EPSG:28992"),
        "ok_l93": _las(tmp / "ok_l93.las", crs="EPSG:2154"),
        "text": tmp / "c.xyz",
        "badtoml": tmp / "bad.toml",
    }
    f["notlas"].write_bytes(b"PK\x03\x04 this is a zip, not LAS" * 20)
    f["text"].write_text("1 2 3\n4 5 6\n")
    f["badtoml"].write_text("[ground\nx = 1\n")
    data = f["ok"].read_bytes()
    (tmp / "cut.laz").write_bytes(data[: len(data) // 2])
    f["cut"] = tmp / "cut.laz"
    return f


CASES = [
    ("info missing file", ["info", "{missing}"], "no such file"),
    ("info not a LAS file", ["info", "{notlas}"], "not a readable LAS/LAZ"),
    ("info truncated LAZ", ["info", "{cut}"], "cut.laz"),
    ("info bad crs", ["info", "{ok}", "--crs", "EPSG:99999999"], "--crs"),
    ("info crs mismatch", ["info", "{ok_rd}", "{ok_l93}"], "CRS"),
    ("unknown option", ["info", "{ok}", "--frobnicate"], "No such option"),
    ("unknown command", ["frobnicate"], "No such command"),
]


@pytest.mark.parametrize("name,args,expect", CASES, ids=[c[0] for c in CASES])
def test_bad_input_gives_one_error_line(tmp_path, name, args, expect):
    files = _files(tmp_path)
    argv = [a.format(**files) for a in args]
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    proc = subprocess.run(ROOFTRACE + argv, capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)
    assert proc.returncode == 2, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, proc.stderr
    assert expect in errors[0]
    assert "Traceback" not in proc.stderr
