"""Stage options from dataclass defaults, a TOML config file and command-line flags.

Each stage declares its options once, as a frozen dataclass (field = option,
``None`` = derived from the data).  A TOML file has one table per stage,
named by the dataclass's ``section`` class attribute::

    [ground]
    iteration_distance = 1.2

    [alpha]
    strategy = "point"

    [classify]
    max_penetration = false     # an optional test switched off

Unknown tables or keys are an error, so a typo never silently does nothing.
TOML has no null, so an option whose ``None`` is meaningful and which
defaults to a value is declared with :func:`optional`: ``false`` in the file
switches off a test, ``"auto"`` asks for the value derived from the data.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
import sys
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from rooftrace.errors import InputError

__all__ = ["load_config", "make_options", "optional", "options_dict", "validate_config"]

T = TypeVar("T")

#: sections accepted in a config file; stages register themselves here
KNOWN_SECTIONS: set[str] = {"run"}


#: modules whose import registers every section and its options dataclass(es)
_STAGE_MODULES = (
    "rooftrace.lidar.detect", "rooftrace.contour.outline", "rooftrace.roof", "rooftrace.refine",
    "rooftrace.refine.building", "rooftrace.image.candidates", "rooftrace.image.corners",
    "rooftrace.image.resection", "rooftrace.snake", "rooftrace.synth",
)


#: how a config file writes ``None`` for an :func:`optional` field, by meaning
_NONE_SPELLING = {"off": False, "auto": "auto"}


def optional(default: Any, *, none: str = "off") -> Any:
    """A dataclass field with a default whose ``None`` a config file can still ask for.

    Parameters
    ----------
    default
        The default value (not None).
    none : {'off', 'auto'}
        What ``None`` means: the test is switched off (written ``false``
        in TOML) or the value is derived from the data (written ``"auto"``).
    """
    if none not in _NONE_SPELLING:
        raise ValueError(f"none must be one of {sorted(_NONE_SPELLING)}, not {none!r}")
    return dataclasses.field(default=default, metadata={"none": none})


def _none_spellings(cls: type) -> dict[str, Any]:
    """``{field: its TOML spelling of None}`` for the :func:`optional` fields of an options dataclass."""
    return {f.name: _NONE_SPELLING[f.metadata["none"]] for f in dataclasses.fields(cls) if "none" in f.metadata}


def _spells_none(value: Any, spelling: Any) -> bool:
    # `False == 0` in Python: compare types too, so that 0 stays a number
    return type(value) is type(spelling) and value == spelling


def _resolve_none(cls: type, table: dict[str, Any]) -> dict[str, Any]:
    """The table with ``false`` / ``"auto"`` of optional fields turned into ``None``."""
    spellings = _none_spellings(cls)
    return {k: None if k in spellings and _spells_none(v, spellings[k]) else v for k, v in table.items()}


def load_config(path: str | os.PathLike | None, *, validate: bool = True) -> dict[str, dict[str, Any]]:
    """Read a TOML config; ``None`` gives an empty config.

    Parameters
    ----------
    path : path-like or None
        The TOML file.
    validate : bool, default True
        Check every table, key and value type against the stages' options
        (:func:`validate_config`) before any data is read, so a typo fails
        at once and not after minutes of work, whichever command reads it.

    Raises
    ------
    InputError
        Missing file, invalid TOML, a top-level key that is not a table,
        an unknown table or key, or a value of the wrong type; the message
        names the file.
    """
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
    if validate:
        validate_config(data)
    return data


def _section_classes() -> dict[str, list[type]]:
    """Options dataclasses by config section, found in the imported stage modules.

    One dataclass per section; a list, so that two stages claiming one table
    are reported by :func:`validate_config`'s checks instead of one hiding
    the other.
    """
    for name in _STAGE_MODULES:
        importlib.import_module(name)
    found: dict[str, list[type]] = {}
    for mod_name, mod in list(sys.modules.items()):
        if not mod_name.startswith("rooftrace.") or mod is None:
            continue
        for obj in list(vars(mod).values()):
            section = getattr(obj, "section", None) if isinstance(obj, type) else None
            if (isinstance(section, str) and dataclasses.is_dataclass(obj) and obj.__module__ == mod_name
                    and obj not in found.get(section, [])):
                found.setdefault(section, []).append(obj)
    return found


def _type_ok(value: Any, hint: Any) -> bool:
    """Loose check of a TOML value against a field annotation (ints pass for floats)."""
    if hint is Any or hint is object:
        return True
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, h) for h in typing.get_args(hint) if h is not type(None))
    if origin is typing.Literal:
        return value in typing.get_args(hint)
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if origin in (tuple, list) or hint in (tuple, list):
        return isinstance(value, list)
    return True  # nested options, arrays ...: left to the dataclass


def _type_name(hint: Any) -> str:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(h) for h in typing.get_args(hint) if h is not type(None))
    if origin is typing.Literal:
        return "one of " + ", ".join(map(repr, typing.get_args(hint)))
    if origin in (tuple, list) or hint in (tuple, list):
        return "an array"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(hint, str(hint))


def validate_config(config: dict[str, Any]) -> None:
    """Refuse unknown tables, unknown keys and values of the wrong type or range, naming the file.

    Every table a stage reads is checked, not only those of the running
    command, so one config file can serve every command and a typo in any
    table fails at once.  Each options dataclass is also built from its
    table, so its own range checks (``__post_init__``) run before any data
    is read.
    """
    where = config.get("__path__", "config")
    classes = _section_classes()
    check_sections(config, KNOWN_SECTIONS)
    for section, table in config.items():
        if section == "__path__" or section not in classes:
            continue
        owners = classes[section]
        fields = {f.name: f for c in owners for f in dataclasses.fields(c) if f.init}
        unknown = sorted(set(table) - set(fields))
        if unknown:
            raise InputError(f"{where}: [{section}] has unknown key(s) {', '.join(unknown)}; "
                             f"known: {', '.join(sorted(fields))}")
        for cls in owners:
            try:
                hints = typing.get_type_hints(cls)
            except Exception:  # an annotation that does not resolve: leave the checks to the dataclass
                hints = {}
            own = {f.name for f in dataclasses.fields(cls) if f.init}
            spellings = _none_spellings(cls)
            for key in sorted(set(table) & own):
                if key in spellings and _spells_none(table[key], spellings[key]):
                    continue
                if key in hints and not _type_ok(table[key], hints[key]):
                    spelled = f" or {json.dumps(spellings[key])}" if key in spellings else ""
                    raise InputError(f"{where}: [{section}] {key} must be {_type_name(hints[key])}{spelled}, "
                                     f"got {table[key]!r}")
            try:
                cls(**_resolve_none(cls, {k: v for k, v in table.items() if k in own}))
            except (TypeError, ValueError) as exc:
                message = str(exc)
                if "required" in message and "argument" in message:
                    continue  # a dataclass that cannot be built from its table alone
                raise InputError(f"{where}: [{section}] {message.removeprefix(f'{where}: ')}") from None


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
    table = _resolve_none(cls, dict((config or {}).get(section, {})))
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(names))
    if unknown:
        raise InputError(f"{where}: [{section}] has unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}")
    table.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return cls(**table)
    except (TypeError, ValueError) as exc:
        # the message names the file only when a config value (not a CLI flag) is involved
        prefix = f"{where}: " if (config or {}).get(section) and where not in str(exc) else ""
        raise InputError(f"{prefix}[{section}] {exc}") from None


def options_dict(options: Any) -> dict[str, Any]:
    """Options as a plain dict, for run metadata and ``--json`` output."""
    return dataclasses.asdict(options)
