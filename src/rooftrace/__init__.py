"""rooftrace: 3D building roof outlines and ridges from airborne LiDAR.

The method follows Santos (2019), Marcato & Dal Poz and Dal Poz & Fazan; see
``DESIGN.md`` in the project's shared folder for the stages.
"""

from rooftrace.cloud import PointCloud

__all__ = ["PointCloud", "__version__"]
__version__ = "0.1.0"
