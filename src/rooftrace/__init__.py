"""rooftrace: 3D building roof outlines and ridges from airborne LiDAR.

The method follows Santos (2019), Marcato & Dal Poz and Dal Poz & Fazan; see
``DESIGN.md`` in the project's shared folder for the stages.
"""

__all__ = ["PointCloud", "__version__"]
__version__ = "0.1.0"


def __getattr__(name: str):
    # imported on first use: the command line installs its signal handlers
    # before numpy and the stages load (rooftrace.cli.entry)
    if name == "PointCloud":
        from rooftrace.cloud import PointCloud

        return PointCloud
    raise AttributeError(f"module 'rooftrace' has no attribute {name!r}")
