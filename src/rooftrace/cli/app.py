"""The typer application every command module registers on, and shared helpers."""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import Any

import typer

__all__ = ["app", "setup_logging", "emit_json", "RichReporter", "reporter_for"]

app = typer.Typer(
    name="rooftrace",
    help="3D building roof outlines and ridges from airborne LiDAR (and an aerial image).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)

#: set by the global -v flag; main() shows tracebacks of internal errors only then
STATE = {"verbose": False}


def setup_logging(quiet: bool = False, verbose: bool = False) -> None:
    """Logs go to stderr; --quiet keeps warnings and errors only."""
    from rich.console import Console
    from rich.logging import RichHandler

    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    root = logging.getLogger("rooftrace")
    root.handlers.clear()
    handler = RichHandler(console=Console(stderr=True), show_path=False, show_time=False)
    handler.setFormatter(logging.Formatter("%(message)s"))
    root.addHandler(handler)
    root.setLevel(level)
    root.propagate = False


def emit_json(summary: dict[str, Any]) -> None:
    """One JSON object on stdout (the ``--json`` summary)."""
    sys.stdout.write(json.dumps(summary, default=_jsonable, sort_keys=False) + "\n")
    sys.stdout.flush()


def _jsonable(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


class RichReporter:
    """A rich progress bar per stage on stderr; silent when --quiet or stderr is not a terminal."""

    def __init__(self, enabled: bool = True) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self._console = Console(stderr=True)
        self._enabled = enabled and self._console.is_terminal
        self._progress = Progress(
            TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(), console=self._console, transient=True
        )
        self._task = None
        self.timings: dict[str, float] = {}
        self._t0 = 0.0
        self._name = ""

    def start(self, name: str, total: float | None = None) -> None:
        self._name, self._t0 = name, time.perf_counter()
        if self._enabled:
            if not self._progress.live.is_started:
                self._progress.start()
            self._task = self._progress.add_task(name, total=total)

    def advance(self, amount: float = 1.0) -> None:
        if self._enabled and self._task is not None:
            self._progress.advance(self._task, amount)

    def finish(self) -> None:
        self.timings[self._name] = self.timings.get(self._name, 0.0) + time.perf_counter() - self._t0
        if self._enabled and self._task is not None:
            self._progress.remove_task(self._task)
            self._task = None

    def close(self) -> None:
        if self._enabled and self._progress.live.is_started:
            self._progress.stop()

    def stage(self, name: str, total: float | None = None):
        from rooftrace.progress import Reporter

        return Reporter.stage(self, name, total)  # type: ignore[arg-type]


def reporter_for(quiet: bool) -> RichReporter:
    return RichReporter(enabled=not quiet)
