"""Progress reporting that stages can call without knowing about terminals.

The pipeline calls ``reporter.stage(name, total)`` and ``advance``; the CLI
supplies a rich progress bar on stderr, library users get the silent default.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

__all__ = ["Reporter", "NullReporter"]


class Reporter:
    """Silent reporter; subclass and override :meth:`start`, :meth:`advance`, :meth:`finish`."""

    def start(self, name: str, total: float | None = None) -> None:  # pragma: no cover - trivial
        pass

    def advance(self, amount: float = 1.0) -> None:  # pragma: no cover - trivial
        pass

    def finish(self) -> None:  # pragma: no cover - trivial
        pass

    @contextlib.contextmanager
    def stage(self, name: str, total: float | None = None) -> Iterator[Reporter]:
        self.start(name, total)
        try:
            yield self
        finally:
            self.finish()


NullReporter = Reporter
