"""``rooftrace run`` killed (SIGKILL) at any moment: no partial output, an earlier result intact (issue 10).

The kill lands at a different moment in each process (reading, detection,
outlining, writing); whatever it interrupted, the output is either absent
(or still the earlier result) or a complete GeoPackage with all its layers,
and only hidden temporary files may be left beside it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from rooftrace.io.vector import list_layers, read_layer
from tests.cli.badfiles import scene_xyz, write_las_file

GOOD = b"a good earlier result"
DELAYS = [0.3, 0.8, 1.3, 1.8, 2.4, 3.0, 4.0]


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")
def test_sigkill_at_any_moment_leaves_no_partial_output(tmp_path):
    src = write_las_file(tmp_path / "scene.laz", scene_xyz())
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    runs = []
    for i, delay in enumerate(DELAYS):
        folder = tmp_path / f"k{i}"
        folder.mkdir()
        out = folder / "roofs.gpkg"
        existing = i % 2 == 1
        if existing:
            out.write_bytes(GOOD)
        args = [sys.executable, "-m", "rooftrace.cli.main", "run", str(src), "-o", str(out), "-q", "--overwrite"]
        runs.append((subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE), delay,
                     out, existing))
    t0 = time.monotonic()
    for proc, delay, _, _ in sorted(runs, key=lambda r: r[1]):
        time.sleep(max(0.0, t0 + delay - time.monotonic()))
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
    finished = 0
    for proc, _delay, out, existing in runs:
        code = proc.wait(timeout=120)
        assert code in (0, -signal.SIGKILL), proc.stderr.read().decode()
        finished += code == 0
        if out.exists() and out.read_bytes() != GOOD:
            # a new file under the output's name is always a whole one
            assert set(list_layers(out)) == {"roof_outlines", "ridges", "roof_faces", "lod12", "lod13", "lod22"}
            assert len(read_layer(out, "roof_outlines")) == 1
        elif code == 0:
            pytest.fail(f"run finished but {out} holds no result")
        else:
            assert not out.exists() or existing  # killed: nothing, or the earlier result untouched
        assert all(p.name.startswith(".roofs.gpkg.") for p in out.parent.iterdir() if p != out)
    assert finished < len(DELAYS), "every run finished before its kill; the test killed nothing"
