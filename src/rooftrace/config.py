"""The config file: which TOML table holds which options, reading it and checking it.

Each stage declares its options once, as a frozen dataclass (field = option,
``None`` = derived from the data; see :mod:`rooftrace.options`).  A TOML
file has one table per stage, named by the dataclass's ``section``::

    [ground]
    iteration_distance = 1.2

    [alpha]
    strategy = "point"

    [classify]
    max_penetration = false     # an optional test switched off

:data:`SECTIONS` lists every table and its dataclass.  Unknown tables or
keys are an error, so a typo never silently does nothing.  TOML has no null,
so an option whose ``None`` is meaningful and which defaults to a value is
declared with :func:`rooftrace.options.optional`: ``false`` in the file
switches off a test, ``"auto"`` asks for the value derived from the data.
:class:`RunOptions` holds the options of a whole run.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from rooftrace.contour.alpha_shape import STRATEGIES, AlphaOptions
from rooftrace.contour.cdspline import CDSplineOptions
from rooftrace.contour.corners import CornerOptions
from rooftrace.contour.outline import OutlineOptions
from rooftrace.contour.regularize import RegularizeOptions
from rooftrace.contour.surface import SurfaceOptions
from rooftrace.errors import InputError
from rooftrace.grouping.ga import GAOptions
from rooftrace.grouping.mrf import MRFOptions
from rooftrace.image.candidates import CandidateOptions
from rooftrace.image.corners import HarrisOptions
from rooftrace.image.resection import ResectionOptions
from rooftrace.lidar.classify import ClassifyOptions
from rooftrace.lidar.detect import DetectOptions
from rooftrace.lidar.ground import GroundOptions
from rooftrace.lidar.outliers import OutlierOptions
from rooftrace.lidar.segment import SegmentOptions
from rooftrace.model.build import ModelOptions
from rooftrace.options import check_table, make_options
from rooftrace.refine.options import RefineOptions
from rooftrace.roof.structure import RoofOptions
from rooftrace.snake.snake import SnakeOptions
from rooftrace.synth.scene import SceneOptions
from rooftrace.tiling.split import TileOptions

__all__ = ["SECTIONS", "RunOptions", "load_config", "validate_config", "check_sections"]


@dataclass(frozen=True)
class RunOptions:
    """Options of a whole run (``rooftrace run``, :func:`rooftrace.run_pipeline`).

    Its own table ``[run]`` holds what the command line also sets; the
    options of every stage the run goes through come from their tables.

    Attributes
    ----------
    alpha : {'global', 'building', 'point'} or None
        Alpha-shape strategy (thesis S1, S2, S3), replacing ``[alpha]
        strategy``; ``--alpha``.  None: the ``[alpha]`` table's.
    planes : bool
        Segment roof planes and derive ridges and faces; ``--no-planes``
        sets it false.
    detect : DetectOptions
        ``[outliers]``, ``[ground]``, ``[segment]``, ``[classify]``.
    outline : OutlineOptions
        ``[surface]``, ``[alpha]``, ``[corners]``, ``[cdspline]``, ``[regularize]``.
    roof : RoofOptions
        ``[planes]``.
    refine : RefineOptions
        ``[refine]``, ``[mrf]``, ``[ga]``, ``[candidates]``, ``[harris]``.
    model : ModelOptions
        ``[model]``: the 3D models.
    """

    section: ClassVar[str] = "run"

    alpha: str | None = None
    planes: bool = True
    detect: DetectOptions = field(default_factory=DetectOptions)
    outline: OutlineOptions = field(default_factory=OutlineOptions)
    roof: RoofOptions = field(default_factory=RoofOptions)
    refine: RefineOptions = field(default_factory=RefineOptions)
    model: ModelOptions = field(default_factory=ModelOptions)

    def __post_init__(self) -> None:
        if self.alpha is not None and self.alpha not in STRATEGIES:
            raise ValueError(f"alpha must be {', '.join(STRATEGIES[:-1])} or {STRATEGIES[-1]}, got {self.alpha!r}")

    @classmethod
    def from_config(cls, config: dict | None = None, *, alpha: str | None = None,
                    planes: bool | None = None) -> RunOptions:
        """Options of a run from a parsed config (checked whole first) and the command line's flags.

        Parameters
        ----------
        config : dict, optional
            Parsed TOML config (:func:`load_config`), one table per stage.
        alpha, planes : optional
            The flags ``--alpha`` and ``--no-planes``; None leaves the config's value.

        Returns
        -------
        RunOptions

        Examples
        --------
        >>> options = RunOptions.from_config({"alpha": {"strategy": "building"}, "run": {"planes": False}})
        >>> options.outline.alpha.strategy, options.planes
        ('building', False)
        """
        config = config or {}
        validate_config(config)
        own = make_options(cls, config, alpha=alpha, planes=planes)
        strategy = own.alpha
        return cls(alpha=own.alpha, planes=own.planes, detect=DetectOptions.from_config(config),
                   outline=OutlineOptions.from_config(config, strategy=strategy),
                   roof=make_options(RoofOptions, config), refine=RefineOptions.from_config(config),
                   model=make_options(ModelOptions, config))


#: every table of a config file and the options dataclass that reads it
SECTIONS: dict[str, type] = {
    "run": RunOptions,
    # detection
    "outliers": OutlierOptions, "ground": GroundOptions, "segment": SegmentOptions, "classify": ClassifyOptions,
    # outlines
    "surface": SurfaceOptions, "alpha": AlphaOptions, "corners": CornerOptions, "cdspline": CDSplineOptions,
    "regularize": RegularizeOptions,
    # roof planes and ridges
    "planes": RoofOptions,
    # 3D models
    "model": ModelOptions,
    # image refinement
    "refine": RefineOptions, "mrf": MRFOptions, "ga": GAOptions, "candidates": CandidateOptions,
    "harris": HarrisOptions,
    # the other commands
    "resection": ResectionOptions, "snake": SnakeOptions, "simulate": SceneOptions, "tiling": TileOptions,
}


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


def validate_config(config: dict[str, Any]) -> None:
    """Refuse unknown tables, unknown keys and values of the wrong type or range, naming the file.

    Every table of :data:`SECTIONS` is checked, not only those of the
    running command, so one config file can serve every command and a typo
    in any table fails at once.  Each options dataclass is also built from
    its table, so its own range checks (``__post_init__``) run before any
    data is read.

    Examples
    --------
    >>> validate_config({"run": {"typo_key": 1}})
    Traceback (most recent call last):
    ...
    rooftrace.errors.InputError: config: [run] has unknown key(s) typo_key; known: alpha, planes
    """
    where = config.get("__path__", "config")
    check_sections(config, set(SECTIONS))
    for section, table in config.items():
        if section != "__path__":
            check_table(SECTIONS[section], section, table, where)


def check_sections(config: dict[str, Any], known: set[str]) -> None:
    """Refuse tables that no stage reads."""
    where = config.get("__path__", "config")
    unknown = sorted(set(config) - known - {"__path__"})
    if unknown:
        raise InputError(f"{where}: unknown section(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")


