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


def test_temporary_paths_are_recorded_until_renamed(tmp_path):
    from rooftrace.io import atomic

    out = tmp_path / "roofs.gpkg"
    with atomic.atomic_path(out) as tmp:
        assert tmp in atomic._TEMPORARY and tmp.name.startswith(".roofs.gpkg.")
        tmp.write_bytes(b"whole")
    assert tmp not in atomic._TEMPORARY and out.read_bytes() == b"whole"
    folder = atomic.temporary_path(tmp_path / "demo", folder=True)
    (folder / "a.txt").write_text("x")
    assert atomic.remove_temporary() == [folder] and not folder.exists() and not atomic._TEMPORARY


def test_a_signal_waits_for_the_end_of_an_uninterrupted_section():
    import signal

    from rooftrace.io import atomic

    seen = []

    def handler(signum, frame):
        if atomic.hold_signal(signum):
            seen.append(("held", signum))
            return
        seen.append(("acted", signum))

    previous = signal.signal(signal.SIGUSR1, handler)
    try:
        with atomic.uninterrupted():
            with atomic.uninterrupted():
                signal.raise_signal(signal.SIGUSR1)
            assert seen == [("held", signal.SIGUSR1)]  # still inside the outer section
        assert seen == [("held", signal.SIGUSR1), ("acted", signal.SIGUSR1)]
        signal.raise_signal(signal.SIGUSR1)
        assert seen[-1] == ("acted", signal.SIGUSR1) and len(seen) == 3
    finally:
        signal.signal(signal.SIGUSR1, previous)


def test_replace_folder_leaves_nothing_of_the_old_one(tmp_path):
    from rooftrace.io.atomic import _TEMPORARY, replace_folder, temporary_path

    old = tmp_path / "out"
    old.mkdir()
    (old / "image.tif").write_text("old")
    new = temporary_path(old, folder=True)
    (new / "report.html").write_text("new")
    assert replace_folder(new, old) == old
    assert sorted(p.name for p in old.iterdir()) == ["report.html"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"] and new not in _TEMPORARY


def test_outputs_committed_together_or_not_at_all(tmp_path):
    from rooftrace.io.atomic import _TEMPORARY, commit_together

    a, b = tmp_path / "roofs.gpkg", tmp_path / "points.laz"
    a.write_bytes(b"old a")
    b.write_bytes(b"old b")
    with pytest.raises(RuntimeError, match="second writer"), commit_together():
        with atomic_path(a, overwrite=True) as tmp:
            tmp.write_bytes(b"new a")
        assert a.read_bytes() == b"old a"  # written, not yet in place
        with atomic_path(b, overwrite=True) as tmp:
            raise RuntimeError("second writer failed")
    assert (a.read_bytes(), b.read_bytes()) == (b"old a", b"old b")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["points.laz", "roofs.gpkg"] and not _TEMPORARY
    with commit_together():
        for path in (a, b):
            with atomic_path(path, overwrite=True) as tmp:
                tmp.write_bytes(b"new")
    assert a.read_bytes() == b.read_bytes() == b"new" and not _TEMPORARY
