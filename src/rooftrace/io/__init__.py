"""Reading and writing: point clouds, vectors, rasters and camera files.

Only this package (and the CLI) touches files; the stages work on arrays.
"""
