"""Stage options from dataclass defaults, a TOML config file and command-line flags.

Each stage declares its options once, as a frozen dataclass (field = option,
``None`` = derived from the data).  A TOML file has one table per stage,
named by the dataclass's ``section`` class attribute::

    [ground]
    iteration_distance = 1.2

    [alpha]
    strategy = "point"

Unknown tables or keys are an error, so a typo never silently does nothing.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from pathlib import Path
from typing import Any, TypeVar

from rooftrace.errors import InputError

__all__ = ["load_config", "make_options", "options_dict"]

T = TypeVar("T")

#: sections accepted in a config file; stages register themselves here
KNOWN_SECTIONS: set[str] = {"run"}


def load_config(path: str | os.PathLike | None) -> dict[str, dict[str, Any]]:
    """Read a TOML config; ``None`` gives an empty config."""
    if path is None:
        return {}
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such config file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    for key, value in data.items():
        if not isinstance(value, dict):
            raise InputError(f"{path}: top-level key {key!r} must be a [table] of stage options")
    data["__path__"] = str(path)  # type: ignore[assignment]
    return data


def check_sections(config: dict[str, Any], known: set[str]) -> None:
    """Refuse tables that no stage reads."""
    where = config.get("__path__", "config")
    unknown = sorted(set(config) - known - {"__path__"})
    if unknown:
        raise InputError(f"{where}: unknown section(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")


def make_options(cls: type[T], config: dict[str, Any] | None = None, **overrides: Any) -> T:
    """Build a stage's options: dataclass defaults < config table < explicit overrides.

    Overrides equal to ``None`` are ignored (an unset CLI flag).  Types are
    checked against the defaults' types loosely: ints are accepted for floats.
    """
    section = getattr(cls, "section", cls.__name__.lower())
    where = (config or {}).get("__path__", "config")
    table = dict((config or {}).get(section, {}))
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(names))
    if unknown:
        raise InputError(f"{where}: [{section}] has unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}")
    table.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return cls(**table)
    except (TypeError, ValueError) as exc:
        raise InputError(f"[{section}] {exc}") from None


def options_dict(options: Any) -> dict[str, Any]:
    """Options as a plain dict, for run metadata and ``--json`` output."""
    return dataclasses.asdict(options)
