"""The real data are found through ROOFTRACE_DATA; a missing dataset skips, naming the variable, or fails in CI (issue 21)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PROBE = '''
from tests.conftest import DELFT, need

def test_probe():
    need(DELFT / "ahn3_cropped_1.laz")
'''


def _pytest(tmp_path, **env):
    probe = tmp_path / "test_probe.py"
    probe.write_text(PROBE)
    environ = {k: v for k, v in os.environ.items() if not k.startswith("ROOFTRACE_")}
    environ.update(env, PYTHONPATH=os.pathsep.join([str(ROOT), environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "pytest", "-ra", "-q", "-p", "no:cacheprovider", "--rootdir",
                           str(tmp_path), str(probe)], cwd=ROOT, env=environ, capture_output=True, text=True,
                          timeout=120)


def test_missing_data_skips_naming_the_variable(tmp_path):
    run = _pytest(tmp_path, ROOFTRACE_DATA=str(tmp_path / "nowhere"))
    assert run.returncode == 0, run.stdout + run.stderr
    skipped = [line for line in run.stdout.splitlines() if line.startswith("SKIPPED")]
    assert len(skipped) == 1 and "ROOFTRACE_DATA" in skipped[0] and "nowhere" in skipped[0], run.stdout


def test_missing_data_fails_when_required(tmp_path):
    run = _pytest(tmp_path, ROOFTRACE_DATA=str(tmp_path / "nowhere"), ROOFTRACE_REQUIRE_DATA="1")
    assert run.returncode == 1, run.stdout + run.stderr
    assert "1 failed" in run.stdout and "ROOFTRACE_REQUIRE_DATA" in run.stdout


def test_the_variable_points_to_the_data(tmp_path):
    (tmp_path / "data" / "3dfier_delft_ahn3_bgt").mkdir(parents=True)
    (tmp_path / "data" / "3dfier_delft_ahn3_bgt" / "ahn3_cropped_1.laz").write_bytes(b"")
    run = _pytest(tmp_path, ROOFTRACE_DATA=str(tmp_path / "data"))
    assert run.returncode == 0 and "1 passed" in run.stdout, run.stdout + run.stderr
