"""Roof planes, ridges and the 3D roof polyhedron from LiDAR (DESIGN.md stage 8).

>>> from rooftrace.roof import RoofOptions, RoofStructure, roof_structure, faces_layer, ridges_layer
"""

from rooftrace.roof.layers import faces_layer, ridges_layer
from rooftrace.roof.structure import RoofOptions, RoofStructure, roof_structure

__all__ = ["RoofOptions", "RoofStructure", "roof_structure", "faces_layer", "ridges_layer"]
