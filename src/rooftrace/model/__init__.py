"""3D building models: LoD 1.2 / 1.3 / 2.2 solids with semantic surfaces.

The types here are what the model builders produce and what the CityJSON,
OBJ and GeoPackage writers consume; they hold plain numpy arrays in the
input's CRS (metres), no I/O.
"""

from rooftrace.model.types import SURFACE_KINDS, BuildingModel, PartModel, Solid, Surface

__all__ = ["SURFACE_KINDS", "BuildingModel", "PartModel", "Solid", "Surface"]
