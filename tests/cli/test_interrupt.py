"""SIGINT and SIGTERM at seeded random moments of real runs (issue 21).

Every interrupted run ends with exactly one ``error: interrupted`` line on
stderr and exit code 130 (SIGINT) or 143 (SIGTERM); it leaves no temporary
file beside its outputs, and an earlier output is either untouched or (a
signal that came while the outputs were being renamed into place) the
whole new one.  The signal goes to the whole process group, as a Ctrl-C in a
terminal does, so the workers of a local Dask cluster get it too.  The full
set (50 interrupts of a Delft run) is ``benchmarks/bench_interrupt.py``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from rooftrace.io.vector import list_layers, read_layer
from tests.cli.badfiles import scene_xyz, write_las_file

GOOD = b"a good earlier result"
CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
LAYERS = {"roof_outlines", "ridges", "roof_faces"}


def start_run(src, folder, *, existing: bool, tiled: bool, classified: bool) -> tuple[subprocess.Popen, list]:
    """``python -m rooftrace run`` in its own session (so that a signal can go to its process group)."""
    out = folder / "roofs.gpkg"
    outputs = [out] + ([folder / "points.laz"] if classified else [])
    if existing:
        for path in outputs:
            path.write_bytes(GOOD)
    args = [sys.executable, "-m", "rooftrace", "run", str(src), "-o", str(out), "-q", "--overwrite"]
    if classified:
        args += ["--classified", str(outputs[1])]
    if tiled:
        args += ["--workers", "2", "--tile-size", "20"]
    # the user's environment as it is (no PYTHONWARNINGS=ignore): a warning on stderr is a failure
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    return proc, outputs


def check_interrupted(proc: subprocess.Popen, signum: int, outputs: list, existing: bool) -> bool:
    """Assert what an interrupted (or finished) run left; True when the signal interrupted it."""
    code = proc.wait(timeout=120)
    err = proc.stderr.read().decode()
    folder = outputs[0].parent
    if code == 0:  # finished before its signal
        assert err == "", err
        assert set(list_layers(outputs[0])) == LAYERS
    else:
        assert code == CODES[signum], err
        assert err == "error: interrupted\n", err
    for path in outputs:
        if path.exists() and path.read_bytes() != GOOD:  # a new file under the output's name is a whole one
            if path.suffix == ".gpkg":
                assert set(list_layers(path)) == LAYERS
                assert len(read_layer(path, "roof_outlines")) == 1
            else:
                import laspy

                assert len(laspy.read(path).points) > 0
        else:
            assert path.exists() == existing
    if existing:  # renamed into place together, or neither
        assert len({path.read_bytes() == GOOD for path in outputs if path.exists()}) == 1
    # no temporary file; a tiled run keeps its run folder for --resume
    left = {p.name for p in folder.iterdir()} - {p.name for p in outputs} - {"roofs.gpkg.parts"}
    assert not left, left
    return code != 0


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")
def test_sigint_and_sigterm_at_random_moments(tmp_path):
    src = write_las_file(tmp_path / "scene.laz", scene_xyz())
    rng = np.random.default_rng(21)
    runs = []
    for i in range(8):
        folder = tmp_path / f"r{i}"
        folder.mkdir()
        signum = (signal.SIGINT, signal.SIGTERM)[i % 2]
        existing, tiled, classified = i % 4 in (2, 3), i in (5, 6), i % 3 == 0
        proc, outputs = start_run(src, folder, existing=existing, tiled=tiled, classified=classified)
        runs.append((float(rng.uniform(0.4, 3.0)), proc, signum, outputs, existing))
    t0 = time.monotonic()
    for moment, proc, signum, _, _ in sorted(runs, key=lambda r: r[0]):
        time.sleep(max(0.0, t0 + moment - time.monotonic()))
        if proc.poll() is None:
            os.killpg(proc.pid, signum)
    interrupted = [check_interrupted(proc, signum, outputs, existing) for _, proc, signum, outputs, existing in runs]
    assert sum(interrupted) >= 4, "most runs finished before their signal; the test interrupted too little"
