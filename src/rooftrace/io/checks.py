"""Input checks shared by the commands: CRS kinds and agreement, image coverage, degenerate clouds.

Each check raises :class:`~rooftrace.errors.InputError` with one message
that says what is wrong, in which file, and what to do (docs/errors.md
lists them); data a command can work around only gets a warning.
"""

from __future__ import annotations

import logging

import numpy as np

from rooftrace.errors import InputError, OptionError

__all__ = ["horizontal_crs", "require_metric_crs", "check_same_crs", "same_plan_crs", "check_image_covers", "check_image_size",
           "check_camera_has_image",
           "check_points", "check_footprints_overlap"]

#: a cloud narrower than this across its main direction (metres) is a line, not an area
_MIN_WIDTH = 0.01

log = logging.getLogger(__name__)


def horizontal_crs(crs):
    """The horizontal part of a CRS: the first member of a compound CRS (e.g. RD New of EPSG:7415), else itself.

    The geometry checks (metres, agreement of two CRSs) look at this part
    only; the vertical one (NAP height) is recorded with the outputs.

    Examples
    --------
    >>> import pyproj
    >>> horizontal_crs(pyproj.CRS("EPSG:7415")).to_epsg()
    28992
    """
    if crs is not None and crs.is_compound and crs.sub_crs_list:
        return crs.sub_crs_list[0]
    return crs


def require_metric_crs(crs, where: str, xy: np.ndarray | None = None) -> None:
    """Refuse geographic CRSs (degrees): every threshold of the method is in metres.

    Parameters
    ----------
    crs : pyproj.CRS or None
        The data's CRS.  ``None`` only gets a warning (outputs will have no
        CRS), unless ``xy`` looks like longitude/latitude.
    where : str
        File name(s) for the message.
    xy : ndarray of shape (N, 2), optional
        Coordinates; without a CRS, a cloud lying within ±180 x ±90 and
        less than 1 unit across is taken for degrees and refused, since a
        building outline of less than a metre is no building.

    Raises
    ------
    InputError
        Geographic CRS (or a compound one whose horizontal part is), a
        vertical CRS alone, or no CRS and coordinates that look like degrees.
    """
    if crs is None:
        if xy is not None and len(xy):
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            if (np.abs(lo) <= [180, 90]).all() and (np.abs(hi) <= [180, 90]).all() and (hi - lo < 1.0).all():
                raise OptionError(f"{where}: no CRS, and the coordinates look like degrees (longitude/latitude, "
                                  f"{lo[0]:.6g}..{hi[0]:.6g}, {lo[1]:.6g}..{hi[1]:.6g}); reproject to a projected "
                                  "CRS in metres, or assign the right one with {crs} if they are metres", "crs")
        log.warning("%s: no CRS; outputs will have none (assign one with --crs)", where)
        return
    if crs.is_vertical and not crs.is_compound:
        raise OptionError(f"{where}: CRS {crs.name} is a height system only; give the horizontal CRS with it, "
                          "e.g. {crs} EPSG:28992+5709 (or EPSG:7415) for RD New + NAP height", "crs")
    if horizontal_crs(crs).is_geographic:
        raise OptionError(f"{where}: CRS {crs.name} is geographic (degrees); reproject to a projected CRS in "
                          "metres or assign the right one with {crs}", "crs")


def check_same_crs(a, b, what_a: str, what_b: str) -> None:
    """Refuse two CRSs that differ; a missing CRS on either side is accepted."""
    if a is None or b is None:
        return
    if not same_plan_crs(a, b):
        raise InputError(f"{what_a} ({a.name}) and {what_b} ({b.name}) have different CRSs; reproject one of them")


def same_plan_crs(a, b) -> bool:
    """Whether two CRSs give the same plan coordinates: equal, equal but for a vertical component
    (e.g. ``EPSG:28992`` and ``EPSG:28992+5709``), or the same projection written differently."""
    if a.equals(b, ignore_axis_order=True):
        return True
    sa, sb = horizontal_crs(a), horizontal_crs(b)
    return sa.equals(sb, ignore_axis_order=True) or _same_coordinates(sa, sb)


def _same_coordinates(a, b, tolerance: float = 0.01) -> bool:
    """Two CRSs written differently that give the same coordinates (within ``tolerance`` m) where they are used.

    GeoTIFFs often carry a projection without its datum (GDAL's "unknown"
    datum on the WGS84 ellipsoid, e.g. IGN orthophotos named "EPSG:2154"):
    the projection parameters are those of the other CRS and no datum shift
    applies, so the coordinates agree; a real difference (another datum with
    a known shift, another projection) moves them by metres.
    """
    import pyproj

    if not (a.is_projected and b.is_projected):
        return False
    try:
        x, y = _a_point_of(a, b)
        x2, y2 = pyproj.Transformer.from_crs(a, b, always_xy=True).transform(x, y)
    except (pyproj.exceptions.ProjError, pyproj.exceptions.CRSError, TypeError, ValueError):
        return False
    return bool(np.isfinite([x2, y2]).all() and np.hypot(x2 - x, y2 - y) < tolerance)


def _a_point_of(a, b) -> tuple[float, float]:
    """Projected coordinates (in ``a``) of a place where the CRSs are used: their area, else ``a``'s origin."""
    import pyproj

    area = a.area_of_use or b.area_of_use
    if area is not None:
        lon, lat = (area.west + area.east) / 2, (area.south + area.north) / 2
    else:
        # WKT without an authority carries no area: use the projection's own origin (lon, lat parameters)
        params = {p.name.lower(): p.value for p in a.coordinate_operation.params}
        lon = next((v for k, v in params.items() if k.startswith("longitude of")), 0.0)
        lat = next((v for k, v in params.items() if k.startswith("latitude of")), 0.0)
    return pyproj.Transformer.from_crs(a.geodetic_crs, a, always_xy=True).transform(lon, lat)


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


def check_camera_has_image(image, camera) -> None:
    """Refuse a camera file given without the image it describes (an orthophoto alone needs no camera file)."""
    if camera is not None and image is None:
        raise OptionError("{camera} needs {image}: give the image the camera file describes", "camera", "image")


def check_image_size(size: tuple[int, int], camera, image: str, camera_file: str) -> None:
    """Refuse an image whose (width, height) in pixels is not the one its camera file gives."""
    if tuple(int(v) for v in size) != tuple(int(v) for v in camera.image_size):
        raise InputError(f"{image}: image is {size[0]} x {size[1]} px but {camera_file} says "
                         f"{camera.image_size[0]} x {camera.image_size[1]}")


def check_points(xyz: np.ndarray, where: str, what: str = "the point cloud") -> None:
    """Refuse a cloud whose points are all identical or all on one line in plan view.

    Every stage of the method works on an area (ground TIN, alpha shape,
    roof planes); such a cloud is a wrong file or a wrong export, not data
    to work around.  An empty cloud passes: commands treat it as "no
    buildings" and write an empty result with a warning.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3) or (N, 2)
        Coordinates, metres.
    where : str
        File name(s) for the message.
    what : str
        What the points are, for the message.

    Raises
    ------
    InputError
        All points identical in plan, or the cloud is narrower than 1 cm
        across its main direction (collinear).

    Examples
    --------
    >>> import numpy as np
    >>> check_points(np.random.default_rng(0).uniform(0, 10, (20, 3)), "ok.las")
    >>> check_points(np.zeros((5, 3)), "one.las")
    Traceback (most recent call last):
    ...
    rooftrace.errors.InputError: one.las: all 5 points of the point cloud have the same x, y; ...
    """
    xy = np.asarray(xyz, dtype=np.float64)[:, :2]
    if len(xy) == 0:
        return
    # a strided sample of at most 1M points keeps the test cheap on city-sized clouds; only a
    # degenerate-looking sample is confirmed on every point
    sample = xy[:: max(1, len(xy) // 1_000_000)]
    if not _degenerate(sample) or (len(sample) < len(xy) and not _degenerate(xy)):
        return
    centred = xy - xy.mean(axis=0)
    if not np.any(centred):
        raise InputError(f"{where}: all {len(xy)} points of {what} have the same x, y; "
                         "this is not a LiDAR cloud of an area, check the file and its export")
    # the smallest singular value over sqrt(N) is the spread across the main direction
    width = np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(len(xy))
    if len(xy) < 3 or width < _MIN_WIDTH:
        raise InputError(f"{where}: all {len(xy)} points of {what} lie on one line in plan view "
                         f"(spread across it {width:.3g} m); the method needs points over an area, "
                         "check the file and its export")


def _degenerate(xy: np.ndarray) -> bool:
    centred = xy - xy.mean(axis=0)
    return len(xy) < 3 or np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(len(xy)) < _MIN_WIDTH


def check_footprints_overlap(footprints, xyz: np.ndarray, path: str, where: str) -> int:
    """Refuse footprints none of which lies over the cloud (wrong file, wrong CRS); return how many do.

    A footprint counts when it intersects the plan bounding box of the
    points; footprints outside it stay (status ``"no_points"``), one
    warning says how many.
    """
    import shapely

    if len(xyz) == 0 or len(footprints) == 0:
        return 0
    lo, hi = xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)
    box = shapely.box(lo[0], lo[1], hi[0], hi[1])
    over = shapely.intersects(np.asarray(footprints.polygons, dtype=object), box)
    n = int(over.sum())
    if n == 0:
        fb = shapely.total_bounds(np.asarray(footprints.polygons, dtype=object))
        raise InputError(f"{path}: no footprint lies over the point cloud {where} (footprints "
                         f"{fb[0]:.1f}..{fb[2]:.1f}, {fb[1]:.1f}..{fb[3]:.1f}; cloud {lo[0]:.1f}..{hi[0]:.1f}, "
                         f"{lo[1]:.1f}..{hi[1]:.1f}); check that both are the same area and the footprints' CRS")
    if n < len(footprints):
        log.warning("%s: %d of %d footprints lie outside the point cloud; they get status no_points",
                    path, len(footprints) - n, len(footprints))
    return n
