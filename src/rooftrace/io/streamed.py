"""Outputs written one building at a time into a temporary file, renamed into place when closed.

The model writers (:mod:`rooftrace.io.cityjson`, :mod:`rooftrace.io.obj`)
share this: the atomic rename (inside :func:`rooftrace.io.atomic.commit_together`
it waits for the block's end), the context-manager protocol (an error
discards everything), and the translation of the coordinates, taken from the
first building so that it depends only on the models and their order.
"""

from __future__ import annotations

import os
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from rooftrace.io.atomic import atomic_path

__all__ = ["StreamedOutput"]


class StreamedOutput:
    """Base of the streamed model writers; subclasses write into ``self._final`` and call ``close``."""

    def __init__(self, path: str | os.PathLike, overwrite: bool = False):
        self.path = Path(path)
        self.translate: np.ndarray | None = None
        self.count = 0
        self._stack = ExitStack()
        self._final = self._stack.enter_context(atomic_path(self.path, overwrite))

    def _origin(self, solids) -> None:
        """Fix the translation on the first building: its lowest corner rounded down to 100 m."""
        if self.translate is None:
            rings = [r for s in solids for surface in s.surfaces for r in surface.rings]
            low = np.vstack(rings).min(axis=0) if rings else np.zeros(3)
            self.translate = np.floor(low / 100.0) * 100.0

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self._stack.__exit__(exc_type, exc, tb)
        return False

    def close(self) -> Path:
        """Finish the file and rename it onto the output."""
        self._stack.close()
        return self.path
