"""The typer application every command module registers on, and shared helpers."""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import Any

import typer

__all__ = ["app", "setup_logging", "emit_json", "rounded", "RichReporter", "reporter_for"]

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
    """One JSON object on stdout (the ``--json`` summary), its numbers :func:`rounded`."""
    sys.stdout.write(json.dumps(rounded(summary), default=_jsonable, sort_keys=False) + "\n")
    sys.stdout.flush()


def rounded(value: Any, decimals: int = 3, digits: int = 4) -> Any:
    """Floats rounded to ``decimals`` places or ``digits`` significant digits, whichever keeps more.

    Three decimals keep map coordinates to the millimetre (85000.001) and
    seconds to the millisecond; four significant digits keep small
    quantities (a height precision of 0.02252 m, a variance of 1.2e-08)
    and drop binary noise (-0.5680000000000001 -> -0.568).  Containers are
    rounded item by item; keys, ints, bools, None and strings pass through.

    Examples
    --------
    >>> rounded({"z": -0.5680000000000001, "density": 14.073153819610031, "x": [85000.0012, 1.234567e-08]})
    {'z': -0.568, 'density': 14.073, 'x': [85000.001, 1.235e-08]}
    """
    import math

    import numpy as np

    if isinstance(value, dict):
        return {k: rounded(v, decimals, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [rounded(v, decimals, digits) for v in value]
    if isinstance(value, np.ndarray):
        return rounded(value.tolist(), decimals, digits)
    if isinstance(value, (float, np.floating)) and not isinstance(value, bool):
        value = float(value)
        if value == 0.0 or not math.isfinite(value):
            return value
        places = max(decimals, digits - 1 - math.floor(math.log10(abs(value))))
        return round(value, places)
    if isinstance(value, np.integer):
        return int(value)
    return value


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
