"""Stage options as frozen dataclasses: built from defaults, a config's table and overrides.

Each stage declares its options once, as a frozen dataclass (field = option,
``None`` = derived from the data) with a ``section`` class attribute naming
its TOML table.  :func:`make_options` builds one from a parsed config;
:func:`optional` declares a field whose ``None`` a config file can still
ask for.  Which table belongs to which dataclass, and the reading and
checking of a config file, are in :mod:`rooftrace.config`.
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from typing import Any, TypeVar

from rooftrace.errors import InputError

__all__ = ["make_options", "optional", "options_dict", "table_keys", "check_table"]

T = TypeVar("T")


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


def table_keys(cls: type) -> list[str]:
    """The keys a config table of ``cls`` may hold: its fields, less the options of other tables nested in it."""
    return [f.name for f in dataclasses.fields(cls) if f.init and not (
        f.default_factory is not dataclasses.MISSING and dataclasses.is_dataclass(f.default_factory))]


#: options of earlier releases a config may still carry, and what replaced them
RETIRED_KEYS: dict[tuple[str, str], str] = {
    ("planes", "hold_step_boundaries"): 'face_boundaries = "held" (was true) or "each" (was false, the default)',
}


def check_table(cls: type, section: str, table: dict[str, Any], where: str) -> None:
    """Refuse unknown keys and values of the wrong type or range in one config table, naming the file.

    The options dataclass is also built from the table, so that its own
    range checks (``__post_init__``) run before any data is read.

    Raises
    ------
    InputError
        An unknown key, a value of the wrong type, or one the dataclass refuses.
    """
    own = table_keys(cls)
    unknown = sorted(set(table) - set(own))
    for key in unknown:
        if (section, key) in RETIRED_KEYS:
            raise InputError(f"{where}: [{section}] {key} is no longer an option; use "
                             f"{RETIRED_KEYS[section, key]}")
    if unknown:
        raise InputError(f"{where}: [{section}] has unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(own))}")
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # an annotation that does not resolve: leave the checks to the dataclass
        hints = {}
    spellings = _none_spellings(cls)
    for key in sorted(table):
        if key in spellings and _spells_none(table[key], spellings[key]):
            continue
        if key in hints and not _type_ok(table[key], hints[key]):
            spelled = f" or {json.dumps(spellings[key])}" if key in spellings else ""
            raise InputError(f"{where}: [{section}] {key} must be {_type_name(hints[key])}{spelled}, "
                             f"got {table[key]!r}")
    try:
        cls(**_resolve_none(cls, dict(table)))
    except (TypeError, ValueError) as exc:
        message = str(exc)
        if "required" in message and "argument" in message:
            return  # a dataclass that cannot be built from its table alone
        # the dataclass names its field as the API spells it (``classify.neighbours``); the table names the section
        message = message.removeprefix(f"{where}: ").removeprefix(f"{section}.")
        raise InputError(f"{where}: [{section}] {message}") from None
