"""Atomic output: write to a temporary file beside the target, then rename.

A crash never leaves a half-written result and never replaces a good one.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from rooftrace.errors import InputError, OutputExistsError

__all__ = ["atomic_path", "check_output"]


def check_output(path: str | os.PathLike, overwrite: bool = False) -> Path:
    """Check that ``path`` can be written; refuse to replace it without ``overwrite``."""
    path = Path(path)
    if path.is_dir():  # even with --overwrite: a file never replaces a folder
        raise InputError(f"{path} is a folder; give a file name for the output")
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path} exists; pass --overwrite to replace it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise InputError(f"folder {parent} does not exist; create it or choose another output path")
    if not os.access(parent, os.W_OK):
        raise InputError(f"folder {parent} is not writable")
    return path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success.

    The temporary name keeps the suffix so that format drivers choosing by
    extension (GDAL, laspy) still see ``.gpkg`` or ``.laz``.
    """
    path = check_output(path, overwrite)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}", dir=path.parent or ".")
    os.close(fd)
    os.unlink(tmp)  # writers (GDAL) refuse to open an existing empty file
    tmp = Path(tmp)
    try:
        yield tmp
        if not tmp.exists():
            raise RuntimeError(f"writer produced no file for {path}")
        if tmp.is_dir() and path.exists():
            shutil.rmtree(path) if path.is_dir() else path.unlink()
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp) if tmp.is_dir() else tmp.unlink()
