"""Raster images via rasterio: reading bands and georeferencing, writing GeoTIFFs atomically."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rooftrace.errors import InputError
from rooftrace.io.atomic import atomic_path

__all__ = ["RasterMeta", "read_raster_meta", "read_image", "write_geotiff"]


@dataclass(frozen=True)
class RasterMeta:
    size: tuple[int, int]  # width, height
    count: int
    transform: tuple[float, float, float, float, float, float] | None
    crs: object


def _open(path: Path):
    import rasterio

    if not path.is_file():
        raise InputError(f"{path}: no such image file")
    try:
        with warnings.catch_warnings():
            # a frame image has no georeference by nature: the camera file is its orientation
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            return rasterio.open(path)
    except rasterio.errors.RasterioIOError as exc:
        raise InputError(f"{path}: not a readable image ({exc})") from None


def read_raster_meta(path: str | os.PathLike) -> RasterMeta:
    """Size, band count, affine transform (a, b, c, d, e, f) and CRS of an image."""
    import pyproj

    path = Path(path)
    with _open(path) as ds:
        t = ds.transform
        transform = None if t.is_identity else (t.a, t.b, t.c, t.d, t.e, t.f)
        crs = None
        if ds.crs is not None:
            try:
                crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
            except pyproj.exceptions.CRSError:
                crs = None
        return RasterMeta((ds.width, ds.height), ds.count, transform, crs)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as float64 grey values (H, W) in [0, 1] for 8-bit data (mean of RGB bands)."""
    path = Path(path)
    with _open(path) as ds:
        data = ds.read()
        dtype = data.dtype
    if data.ndim != 3 or data.shape[1] == 0 or data.shape[2] == 0:
        raise InputError(f"{path}: image has no pixels")
    grey = data[: min(3, data.shape[0])].astype(np.float64).mean(axis=0)
    if np.issubdtype(dtype, np.integer):
        grey /= float(np.iinfo(dtype).max)
    return grey


def write_geotiff(
    path: str | os.PathLike,
    array: np.ndarray,
    *,
    transform: tuple[float, float, float, float, float, float] | None = None,
    crs=None,
    overwrite: bool = False,
) -> Path:
    """Write an (H, W) or (B, H, W) array as a (Geo)TIFF, atomically."""
    import rasterio
    from affine import Affine

    arr = np.asarray(array)
    if arr.ndim == 2:
        arr = arr[None]
    profile = dict(driver="GTiff", width=arr.shape[2], height=arr.shape[1], count=arr.shape[0], dtype=arr.dtype,
                   compress="deflate")
    if transform is not None:
        profile["transform"] = Affine(*transform)
    if crs is not None:
        profile["crs"] = rasterio.crs.CRS.from_wkt(crs.to_wkt())
    with atomic_path(path, overwrite) as tmp:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(tmp, "w", **profile) as ds:
                ds.write(arr)
    return Path(path)
