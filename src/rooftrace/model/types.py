"""The data a 3D building model is made of.

A :class:`BuildingModel` is one building (one cadastral footprint, or one
LiDAR building) made of one or more :class:`PartModel` (CityJSON
``BuildingPart``\\ s when there are several).  Each part holds, per level of
detail, one closed :class:`Solid`: an outer shell of planar
:class:`Surface`\\ s whose rings are oriented counter-clockwise seen from
outside (the right-hand rule gives the outward normal), as CityJSON and
val3dity expect.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["SURFACE_KINDS", "Surface", "Solid", "PartModel", "BuildingModel", "LODS"]

#: semantic surface types written to CityJSON (``semantics.surfaces[*].type``)
SURFACE_KINDS = ("RoofSurface", "WallSurface", "GroundSurface")

#: the levels of detail built per part, as CityJSON writes them
LODS = ("1.2", "1.3", "2.2")


@dataclass
class Surface:
    """One planar face of a solid.

    Attributes
    ----------
    rings : list of ndarray of shape (K, 3) float64
        Outer ring first, then holes; metres in the input CRS.  Rings are
        open (the first vertex is not repeated), the outer ring
        counter-clockwise seen from outside the solid, holes clockwise.
    kind : {'RoofSurface', 'WallSurface', 'GroundSurface'}
    """

    rings: list[np.ndarray]
    kind: str

    def __post_init__(self) -> None:
        if self.kind not in SURFACE_KINDS:
            raise ValueError(f"Surface: kind must be one of {SURFACE_KINDS}, not {self.kind!r}")


@dataclass
class Solid:
    """A closed 2-manifold shell of outward-oriented planar surfaces (no inner shells)."""

    surfaces: list[Surface]


@dataclass
class PartModel:
    """One building part: its footprint in plan view and one solid per level of detail.

    Attributes
    ----------
    part_id : int
        1, 2, ... within the building.
    footprint : shapely.Polygon
        2D outline of the part's ground surface.
    lods : dict of str to Solid
        Keys from :data:`LODS`; a level that could not be built is absent.
    attributes : dict of str to Any
        Per-part values (roof height of the part, ...), JSON-serialisable.
    """

    part_id: int
    footprint: Any
    lods: dict[str, Solid] = field(default_factory=dict)
    attributes: dict[str, Any] = field(default_factory=dict)


@dataclass
class BuildingModel:
    """One building: its parts and its attributes (JSON-serialisable scalars and strings)."""

    building_id: int
    parts: list[PartModel] = field(default_factory=list)
    attributes: dict[str, Any] = field(default_factory=dict)
