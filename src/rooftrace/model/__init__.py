"""3D building models: LoD 1.2 / 1.3 / 2.2 solids with semantic surfaces.

The types here are what the model builders produce and what the CityJSON,
OBJ and GeoPackage writers consume; they hold plain numpy arrays in the
input's CRS (metres), no I/O.

>>> from rooftrace.model import build_model, prism_solid, solid_errors
"""

from rooftrace.model.attributes import building_attributes
from rooftrace.model.build import ModelOptions, build_model, ground_height
from rooftrace.model.measure import roof_height_at, vertical_rmse
from rooftrace.model.solid import horizontal_plane, prism_solid
from rooftrace.model.types import LODS, SURFACE_KINDS, BuildingModel, PartModel, Solid, Surface
from rooftrace.model.validity import is_valid_solid, solid_errors, solid_volume

__all__ = ["SURFACE_KINDS", "LODS", "BuildingModel", "PartModel", "Solid", "Surface", "ModelOptions", "build_model",
           "ground_height", "building_attributes", "prism_solid", "horizontal_plane", "solid_errors",
           "is_valid_solid", "solid_volume", "roof_height_at", "vertical_rmse"]
