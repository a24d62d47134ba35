"""Atomic output: write to a temporary file beside the target, then rename.

A crash never leaves a half-written result and never replaces a good one.

The temporary paths of the writes under way are recorded, so that a process
ending on a signal can remove them (:func:`remove_temporary`) before it
exits; and a few steps that must not be cut in two (creating and recording a
temporary path, renaming it into place) run in an :func:`uninterrupted`
section, during which a signal handler that asks :func:`hold_signal` waits
for the section's end.  The library installs no handler itself: the command
line does (:mod:`rooftrace.cli.interrupt`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import tempfile
from collections.abc import Iterator
from pathlib import Path

from rooftrace.errors import InputError, OutputExistsError

__all__ = ["atomic_path", "check_output", "commit_together", "hold_signal", "remove_temporary", "replace_folder",
           "temporary_path", "track", "uninterrupted", "untrack"]

#: temporary files and folders of the writes under way, removed on an interrupt
_TEMPORARY: set[Path] = set()
#: depth of nested uninterrupted sections, and the signals that arrived in them
_HOLD = [0]
_HELD: list[int] = []
#: open commit_together blocks, innermost last: the finished writes waiting to be renamed into place
_BATCHES: list[list[tuple[Path, Path]]] = []


def check_output(path: str | os.PathLike, overwrite: bool = False) -> Path:
    """Check that ``path`` can be written; refuse to replace it without ``overwrite``."""
    path = Path(path)
    if path.is_dir():  # even with --overwrite: a file never replaces a folder
        raise InputError(f"{path} is a folder; give a file name for the output")
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path} exists; pass {{overwrite}} to replace it", "overwrite")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise InputError(f"folder {parent} does not exist; create it or choose another output path")
    if not os.access(parent, os.W_OK):
        raise InputError(f"folder {parent} is not writable")
    return path


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """A section an interrupt must not cut: a held signal is raised again at its end.

    Only signals whose handler calls :func:`hold_signal` wait; without such a
    handler (library use) this is a plain block.
    """
    _HOLD[0] += 1
    try:
        yield
    finally:
        _HOLD[0] -= 1
        if _HOLD[0] == 0 and _HELD:
            signum = _HELD.pop(0)
            _HELD.clear()
            signal.raise_signal(signum)


def hold_signal(signum: int) -> bool:
    """For a signal handler: inside an :func:`uninterrupted` section, keep ``signum`` for its end.

    Returns True when the signal was held (the handler returns at once),
    False when the handler may act now.
    """
    if _HOLD[0] > 0:
        _HELD.append(signum)
        return True
    return False


def track(path: str | os.PathLike) -> Path:
    """Record a temporary file or folder for :func:`remove_temporary`."""
    path = Path(path)
    _TEMPORARY.add(path)
    return path


def untrack(path: str | os.PathLike) -> None:
    """Forget a temporary path (renamed into place, or removed)."""
    _TEMPORARY.discard(Path(path))


def remove_temporary() -> list[Path]:
    """Remove every recorded temporary path that still exists; returns those removed.

    Safe to call from a signal handler: it never raises.
    """
    removed = []
    for path in list(_TEMPORARY):
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink()
            removed.append(path)
        except OSError:
            pass
        _TEMPORARY.discard(path)
    return removed


def temporary_path(path: Path, *, folder: bool = False) -> Path:
    """A new, recorded temporary name beside ``path`` (hidden, keeping its suffix).

    With ``folder`` the folder is created; otherwise the name is free (writers
    such as GDAL refuse to open an existing empty file).
    """
    parent = path.parent if str(path.parent) else Path(".")
    with uninterrupted():  # created and recorded together, or neither
        if folder:
            return track(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=parent))
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}", dir=parent)
        os.close(fd)
        track(tmp)
        os.unlink(tmp)
        return Path(tmp)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success.

    The temporary name keeps the suffix so that format drivers choosing by
    extension (GDAL, laspy) still see ``.gpkg`` or ``.laz``.  Inside a
    :func:`commit_together` block the rename waits for the block's end.
    """
    path = check_output(path, overwrite)
    tmp = temporary_path(path)
    waiting = False
    try:
        yield tmp
        if not tmp.exists():
            raise RuntimeError(f"writer produced no file for {path}")
        if _BATCHES:
            _BATCHES[-1].append((tmp, path))
            waiting = True
        else:
            _commit([(tmp, path)])
    finally:
        if not waiting:
            _discard(tmp)


@contextlib.contextmanager
def commit_together() -> Iterator[None]:
    """The outputs written in the block are renamed into place together, at its end, or none of them.

    A command with several outputs (``run -o roofs.gpkg --classified
    points.laz``) so never leaves one new and one old: an error or an
    interrupt while the second is written leaves both as they were.
    Nested blocks commit with the outermost one.  Code in the block must not
    read an output it wrote (it is not in place yet).
    """
    batch: list[tuple[Path, Path]] = []
    _BATCHES.append(batch)
    try:
        yield
    except BaseException:
        _BATCHES.pop()
        for tmp, _ in batch:
            _discard(tmp)
        raise
    _BATCHES.pop()
    if _BATCHES:
        _BATCHES[-1].extend(batch)
    else:
        _commit(batch)


def _commit(batch: list[tuple[Path, Path]]) -> None:
    with uninterrupted():  # an interrupt leaves the old outputs or all the new ones
        for tmp, path in batch:
            if tmp.is_dir() and path.exists():
                shutil.rmtree(path) if path.is_dir() else path.unlink()
            os.replace(tmp, path)
            untrack(tmp)


def _discard(tmp: Path) -> None:
    if tmp.exists():
        shutil.rmtree(tmp) if tmp.is_dir() else tmp.unlink()
    untrack(tmp)

def replace_folder(built: str | os.PathLike, path: str | os.PathLike) -> Path:
    """Put the folder ``built`` (made by :func:`temporary_path` beside ``path``) in the place of ``path``.

    The earlier folder, if any, is first renamed aside and removed only once
    the new one is in place, so no file of it survives among the new ones and
    an interrupt leaves one whole folder, the old or the new.
    """
    built, path = Path(built), Path(path)
    with uninterrupted():
        aside = None
        if path.exists():
            aside = temporary_path(path.with_name(path.name + ".old"))
            os.replace(path, aside)
        os.replace(built, path)
        untrack(built)
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)
            untrack(aside)
    return path
