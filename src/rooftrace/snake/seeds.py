"""Seeds clicked in the image: pixel (column, row) to object (X, Y) on the LiDAR roof surface.

Why our own: the camera gives each pixel's ray, but where the ray meets a
roof needs the LiDAR surface and care at the roof edge (see the Notes of
:func:`pixel_seeds_to_object`); no library intersects rays with a TIN DSM.
"""

from __future__ import annotations

import numpy as np

from rooftrace.errors import GeometryError, InputError
from rooftrace.snake.surface import Tin, roof_surface

__all__ = ["pixel_seeds_to_object"]


def pixel_seeds_to_object(cr: np.ndarray, camera, xyz: np.ndarray, step: float = 0.05) -> np.ndarray:
    """Object (X, Y) of seeds given as pixels: the first hit of their rays on the LiDAR roof surface.

    Parameters
    ----------
    cr : ndarray of shape (n, 2)
        Pixel (column, row), centres at integers.
    camera : FrameCamera or OrthoCamera
    xyz : ndarray of shape (N, 3)
        LiDAR points (m).
    step : float, default 0.05
        Height step (m) of the march down each ray.

    Returns
    -------
    ndarray of shape (n, 2)

    Notes
    -----
    A ray is marched from the highest to the lowest surface height and stops
    where it first meets the dilated TIN (:func:`.tin.roof_surface`), as a
    ray cast through a DSM: a fixed-point iteration Z -> (X, Y) -> Z would
    slide off a roof edge onto the ground behind it on the side facing away
    from the camera.
    """
    cr = np.atleast_2d(np.asarray(cr, float))
    xyz = np.asarray(xyz, float)
    origin, direction = camera.ray(cr)

    def at(z):  # (n, L) heights -> (n, L, 2) positions on the rays
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (z - origin[:, 2:3]) / direction[:, 2:3]
        return origin[:, None, :2] + t[..., None] * direction[:, None, :2]

    zmin, zmax = float(xyz[:, 2].min()), float(xyz[:, 2].max())
    span = at(np.array([[zmin, zmax]] * len(cr))).reshape(-1, 2)
    if not np.isfinite(span).all():
        raise InputError("a seed's ray does not reach the ground; check the camera")
    lo, hi = span.min(axis=0) - 5.0, span.max(axis=0) + 5.0
    near = xyz[np.all((xyz[:, :2] >= lo) & (xyz[:, :2] <= hi), axis=1)]
    if len(near) < 3:
        raise InputError("no LiDAR points under the pixel seeds; check the seeds, the camera and the cloud")
    try:
        tin = Tin(near)
    except GeometryError as exc:
        raise InputError(f"the LiDAR points under the pixel seeds cannot be triangulated ({exc})") from None
    surface = roof_surface(tin, (*lo, *hi), cell=0.1, radius=2.5 * tin.spacing())
    zmax = float(surface.grid.max())
    levels = np.arange(zmax, float(surface.grid.min()) - step, -step)
    pos = at(np.broadcast_to(levels, (len(cr), len(levels))))
    above = surface(pos) >= levels[None, :]
    first = np.where(above.any(axis=1), above.argmax(axis=1), len(levels) - 1)
    return pos[np.arange(len(cr)), first]
