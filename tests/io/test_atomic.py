"""A run killed mid-write leaves no output and never damages an existing one (issue 10)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from rooftrace.errors import OutputExistsError
from rooftrace.io.atomic import atomic_path

WRITER = textwrap.dedent(
    """
    import sys, numpy as np
    from rooftrace.cloud import PointCloud
    from rooftrace.io.las import write_las
    rng = np.random.default_rng(0)
    n = 4_000_000
    cloud = PointCloud(np.column_stack([rng.uniform(0, 1000, n), rng.uniform(0, 1000, n), rng.uniform(0, 50, n)]))
    print("writing", flush=True)
    write_las(sys.argv[1], cloud, classification=np.ones(n, np.uint8), overwrite=True)
    print("done", flush=True)
    """
)


@pytest.mark.parametrize("existing", [False, True])
def test_sigkill_mid_write_leaves_no_partial_output(tmp_path, existing):
    out = tmp_path / "out.laz"
    if existing:
        out.write_bytes(b"a good earlier result")
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"
    time.sleep(0.3)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.stdout.read() == "", "the write finished before the kill; make the cloud larger"
    if existing:
        assert out.read_bytes() == b"a good earlier result"
    else:
        assert not out.exists()
    # only a hidden temporary file may remain, never something under the output's name
    assert all(p.name.startswith(".out.laz.") for p in tmp_path.iterdir() if p != out)


def test_atomic_path_cleans_up_on_error(tmp_path):
    target = tmp_path / "x.gpkg"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    target.write_text("keep")
    with pytest.raises(OutputExistsError), atomic_path(target):
        pass
    assert target.read_text() == "keep"
