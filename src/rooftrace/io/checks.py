"""Input checks shared by the commands: CRS kinds and agreement, image coverage."""

from __future__ import annotations

import logging

import numpy as np

from rooftrace.errors import InputError

__all__ = ["require_metric_crs", "check_same_crs", "check_image_covers"]

log = logging.getLogger(__name__)


def require_metric_crs(crs, where: str) -> None:
    """Refuse geographic CRSs (degrees): every threshold of the method is in metres."""
    if crs is None:
        log.warning("%s: no CRS; outputs will have none (assign one with --crs)", where)
        return
    if crs.is_geographic:
        raise InputError(f"{where}: CRS {crs.name} is geographic (degrees); reproject to a projected CRS in metres "
                         "or assign the right one with --crs")


def check_same_crs(a, b, what_a: str, what_b: str) -> None:
    """Refuse two CRSs that differ; a missing CRS on either side is accepted."""
    if a is None or b is None:
        return
    if not a.equals(b, ignore_axis_order=True):
        # a vertical component (e.g. EPSG:28992+5709) does not change planimetry
        sa = a.sub_crs_list[0] if a.is_compound else a
        sb = b.sub_crs_list[0] if b.is_compound else b
        if not sa.equals(sb, ignore_axis_order=True):
            raise InputError(f"{what_a} ({a.name}) and {what_b} ({b.name}) have different CRSs; reproject one of them")


def check_image_covers(camera, xyz: np.ndarray, where: str, min_fraction: float = 0.01) -> float:
    """Fraction of points whose projection falls inside the image; refuse when (almost) none do."""
    if len(xyz) == 0:
        return 0.0
    sample = xyz[:: max(1, len(xyz) // 20000)]
    cr = camera.project(sample)
    w, h = camera.image_size
    inside = np.isfinite(cr).all(axis=1) & (cr[:, 0] >= -0.5) & (cr[:, 0] <= w - 0.5) & (cr[:, 1] >= -0.5) & (cr[:, 1] <= h - 0.5)
    fraction = float(inside.mean())
    if fraction < min_fraction:
        raise InputError(f"{where}: the image does not cover the data ({100 * fraction:.1f} % of it projects "
                         "inside the image); check the image, the camera file and the CRS")
    return fraction
