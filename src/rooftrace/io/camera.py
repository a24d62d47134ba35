"""The camera file (``camera.json``, docs/image.md) read and written.

``"type": "frame"`` gives a :class:`~rooftrace.image.camera.FrameCamera`;
``"type": "orthophoto"`` gives an :class:`~rooftrace.image.camera.OrthoCamera`
whose affine transform comes from the GeoTIFF itself (pass ``image``).
:func:`image_camera` is what the commands call: a georeferenced orthophoto
needs no camera file at all.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pyproj

from rooftrace.errors import InputError, OptionError
from rooftrace.image.camera import FrameCamera, OrthoCamera
from rooftrace.io.atomic import atomic_path

__all__ = ["read_camera", "image_camera", "write_camera", "camera_to_dict", "camera_from_dict"]

_FORMAT_HINT = "fix the camera file (its format is in docs/errors.md, 'Camera file')"
_EXTERIOR = ("X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg")
_DISTORTION = ("k1", "k2", "k3", "p1", "p2")


def _number(obj: dict, key: str, where: str) -> float:
    if key not in obj:
        raise InputError(f"{where}: missing {key!r}")
    try:
        value = float(obj[key])
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key!r} must be a number, got {obj[key]!r}") from None
    if not math.isfinite(value):
        raise InputError(f"{where}: {key!r} must be finite, got {obj[key]!r}")
    return value


def camera_from_dict(data: dict, where: str = "camera", image: str | os.PathLike | None = None):
    """Build a camera from the parsed JSON object; ``where`` names the file in messages."""
    if not isinstance(data, dict):
        raise InputError(f"{where}: expected a JSON object")
    kind = data.get("type", "frame")
    crs = None
    if data.get("crs"):
        try:
            crs = pyproj.CRS.from_user_input(data["crs"])
        except pyproj.exceptions.CRSError:
            raise InputError(f"{where}: 'crs' {data['crs']!r} is not a valid CRS") from None
    if kind == "orthophoto":
        if image is None:
            raise OptionError(f"{where}: an orthophoto camera needs its GeoTIFF ({{image}})", "image")
        from rooftrace.io.raster import read_raster_meta

        meta = read_raster_meta(image)
        if meta.transform is None:
            raise InputError(f"{image}: no georeferencing (affine transform), which an orthophoto camera ({where}) "
                             "needs; give a GeoTIFF orthophoto, or a 'frame' camera for an aerial frame image")
        if crs is not None and meta.crs is not None and not crs.equals(meta.crs, ignore_axis_order=True):
            raise InputError(f"{where} ({crs.name}) and {image} ({meta.crs.name}) have different CRSs; "
                             "drop 'crs' from the camera file or reproject the image")
        sigma = _number(data, "sigma_px", where) if "sigma_px" in data else 0.0
        return OrthoCamera(meta.size, meta.transform, crs or meta.crs, sigma)
    if kind != "frame":
        raise InputError(f"{where}: 'type' must be 'frame' or 'orthophoto', got {kind!r}")
    size = data.get("image_size")
    if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
        raise InputError(f"{where}: 'image_size' must be [width, height] in pixels, got {size!r}")
    ps = _number(data, "pixel_size_mm", where)
    f = _number(data, "focal_length_mm", where)
    if ps <= 0 or f <= 0:
        raise InputError(f"{where}: 'pixel_size_mm' and 'focal_length_mm' must be positive")
    pp = data.get("principal_point_mm", [0.0, 0.0])
    if not (isinstance(pp, (list, tuple)) and len(pp) == 2):
        raise InputError(f"{where}: 'principal_point_mm' must be [x0, y0]")
    pp = [_number({"principal_point_mm": v}, "principal_point_mm", where) for v in pp]
    dist_in = data.get("distortion") or {}
    if not isinstance(dist_in, dict) or set(dist_in) - set(_DISTORTION):
        raise InputError(f"{where}: 'distortion' accepts only {', '.join(_DISTORTION)}")
    distortion = {k: _number(dist_in, k, where + " distortion") for k in dist_in}
    ext = data.get("exterior")
    if not isinstance(ext, dict):
        raise InputError(f"{where}: missing 'exterior' object with {', '.join(_EXTERIOR)}")
    vals = [_number(ext, k, where + " exterior") for k in _EXTERIOR]
    exterior = np.array(vals[:3] + [math.radians(v) for v in vals[3:]])
    cov = data.get("exterior_covariance")
    if cov is not None:
        cov = np.asarray(cov, dtype=float) if _is_matrix(cov) else None
        if cov is None or cov.shape != (6, 6) or not np.isfinite(cov).all():
            raise InputError(f"{where}: 'exterior_covariance' must be a 6 x 6 matrix of numbers")
        if not np.allclose(cov, cov.T, atol=1e-12 * max(1.0, np.abs(cov).max())) or np.linalg.eigvalsh(cov).min() < -1e-12:
            raise InputError(f"{where}: 'exterior_covariance' must be symmetric positive semi-definite")
    return FrameCamera(
        image_size=(int(size[0]), int(size[1])),
        pixel_size_mm=ps,
        focal_length_mm=f,
        exterior=exterior,
        principal_point_mm=(float(pp[0]), float(pp[1])),
        distortion=distortion,
        exterior_covariance=cov,
        crs=crs,
    )


def _is_matrix(obj) -> bool:
    try:
        np.asarray(obj, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def read_camera(path: str | os.PathLike, image: str | os.PathLike | None = None):
    """Read ``camera.json``; for an orthophoto camera the transform is taken from ``image``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such camera file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc}); {_FORMAT_HINT}") from None
    try:
        return camera_from_dict(data, str(path), image)
    except InputError as exc:
        if not str(exc).startswith(str(path)):  # an image error (orthophoto) names its own file first
            raise
        raise InputError(f"{exc}; {_FORMAT_HINT}") from None


def image_camera(image: str | os.PathLike, camera: str | os.PathLike | None = None):
    """The camera of ``--image``: read from ``camera`` when given, else the orthophoto's georeference.

    Parameters
    ----------
    image : path-like
        The aerial frame image or the orthophoto (GeoTIFF).
    camera : path-like, optional
        Its ``camera.json``.  Without it the image must be a georeferenced
        orthophoto: its affine transform and CRS are the camera
        (``{"type": "orthophoto"}`` in a file gives the same).

    Returns
    -------
    FrameCamera or OrthoCamera

    Raises
    ------
    InputError
        No camera file and an image without georeference (a frame image),
        or a camera file that does not fit the image.
    """
    if camera is not None:
        return read_camera(camera, image)
    from rooftrace.io.raster import read_raster_meta

    meta = read_raster_meta(image)
    if meta.transform is None:
        raise OptionError(f"{image}: no georeference, so the image needs its orientation: give {{camera}} camera.json "
                         "(a frame camera, see docs/image.md), or give a georeferenced orthophoto (GeoTIFF), "
                         "which needs no camera file", "camera")
    return OrthoCamera(meta.size, meta.transform, meta.crs, 0.0)


def camera_to_dict(camera: FrameCamera) -> dict:
    """The JSON object of a frame camera (angles in degrees)."""
    e = np.asarray(camera.exterior, float)
    out = {
        "type": "frame",
        "crs": camera.crs.to_string() if camera.crs is not None else None,
        "image_size": [int(camera.image_size[0]), int(camera.image_size[1])],
        "pixel_size_mm": float(camera.pixel_size_mm),
        "focal_length_mm": float(camera.focal_length_mm),
        "principal_point_mm": [float(v) for v in camera.principal_point_mm],
        "distortion": {k: float(camera.distortion.get(k, 0.0)) for k in _DISTORTION},
        "exterior": dict(zip(_EXTERIOR, [float(e[0]), float(e[1]), float(e[2])] + [math.degrees(v) for v in e[3:6]])),
    }
    if camera.exterior_covariance is not None:
        out["exterior_covariance"] = np.asarray(camera.exterior_covariance, float).tolist()
    return out


def write_camera(path: str | os.PathLike, camera: FrameCamera, *, overwrite: bool = False) -> Path:
    """Write a frame camera as ``camera.json`` atomically."""
    with atomic_path(path, overwrite) as tmp:
        tmp.write_text(json.dumps(camera_to_dict(camera), indent=2) + "\n", encoding="utf-8")
    return Path(path)
