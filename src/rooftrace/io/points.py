"""Read any supported point cloud: LAS/LAZ, PLY, or plain text ``x y z``.

:func:`read_points` dispatches on the suffix, applies ``--crs`` (assign or
override) and joins several files into one cloud, refusing CRS mismatches.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pyproj

from rooftrace.cloud import PointCloud
from rooftrace.errors import InputError, OptionError
from rooftrace.io.checks import horizontal_crs, same_plan_crs
from rooftrace.io.las import (
    LAS_SUFFIXES,
    check_finite,
    check_header_bounds,
    chunk_xyz,
    las_chunks,
    las_crs,
    read_las,
)

__all__ = ["read_points", "read_ply", "read_text", "parse_crs", "common_crs", "summarise_las", "POINT_SUFFIXES"]

log = logging.getLogger(__name__)

TEXT_SUFFIXES = (".txt", ".xyz", ".csv", ".pts")
POINT_SUFFIXES = LAS_SUFFIXES + (".ply",) + TEXT_SUFFIXES


def parse_crs(text: str | None) -> pyproj.CRS | None:
    """Parse a user CRS (``EPSG:28992``, WKT, PROJ string); ``None`` passes through."""
    if text is None or text == "":
        return None
    try:
        return pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError:
        raise OptionError(f"{{crs}} {text!r} is not a CRS pyproj understands; use e.g. EPSG:28992", "crs") from None


def read_ply(path: str | os.PathLike) -> PointCloud:
    """Read the ``vertex`` element of an ASCII or binary PLY file (plyfile)."""
    import plyfile

    path = Path(path)
    try:
        ply = plyfile.PlyData.read(str(path))
        vertex = ply["vertex"].data
    except KeyError:
        raise InputError(f"{path}: PLY file has no 'vertex' element") from None
    except Exception as exc:
        raise InputError(f"{path}: not a readable PLY file ({exc})") from None
    names = vertex.dtype.names or ()
    if not {"x", "y", "z"} <= set(names):
        raise InputError(f"{path}: PLY vertices lack x, y, z properties (found {', '.join(names)})")
    xyz = np.column_stack([vertex["x"], vertex["y"], vertex["z"]]).astype(np.float64)
    fields = {n: np.asarray(vertex[n]) for n in names if n not in ("x", "y", "z")}
    return PointCloud(xyz, fields, sources=[str(path)])


def read_text(path: str | os.PathLike) -> PointCloud:
    """Read whitespace- or comma-separated ``x y z [...]`` text; header lines are skipped."""
    path = Path(path)
    rows: list[str] = []
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    for line in text.splitlines():
        line = line.replace(",", " ").replace(";", " ").strip()  # strip last: ";" alone is an empty line
        if not line or line[0] in "#/":
            continue
        rows.append(line)
    had_rows = bool(rows)
    # a header line is any leading row whose first token is not a number
    while rows and not _is_number(rows[0].split()[0]):
        rows.pop(0)
    if had_rows and not rows:
        raise InputError(f"{path}: not a text point cloud, no line starts with a number; "
                         "give x y z columns (one point per line) or a LAS/LAZ/PLY file")
    try:
        data = np.loadtxt(rows, ndmin=2) if rows else np.empty((0, 3))
    except ValueError as exc:
        raise InputError(f"{path}: not a text point cloud of numeric 'x y z' columns ({exc})") from None
    if data.shape[1] < 3:
        raise InputError(f"{path}: needs at least 3 numeric columns (x y z), found {data.shape[1]}")
    return PointCloud(data[:, :3], sources=[str(path)])


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _read_one(path: Path) -> PointCloud:
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a point cloud file")
    suffix = path.suffix.lower()
    if suffix in LAS_SUFFIXES:
        return read_las(path)
    if suffix in TEXT_SUFFIXES or suffix == ".ply":
        cloud = read_ply(path) if suffix == ".ply" else read_text(path)
        bad = int((~np.isfinite(cloud.xyz).all(axis=1)).sum())
        if bad:
            raise InputError(f"{path}: {bad} points have NaN or infinite coordinates; remove them and retry")
        return cloud
    raise InputError(f"{path}: unknown point cloud format {suffix!r}; use .las, .laz, .ply or text (.txt, .xyz, .csv)")


def read_points(
    paths: str | os.PathLike | Iterable[str | os.PathLike],
    crs: str | pyproj.CRS | None = None,
    *,
    require_points: bool = True,
) -> PointCloud:
    """Read and join point cloud files.

    Parameters
    ----------
    paths : path-like or iterable of path-like
        LAS/LAZ, PLY or text files.
    crs : str or pyproj.CRS, optional
        Assigned to files without a CRS and overriding the others (``--crs``).
    require_points : bool, default True
        Raise :class:`InputError` for an empty result.

    Returns
    -------
    PointCloud
        All points, with a ``source_index`` field telling which file each
        point came from.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "roof.txt"
    >>> np.savetxt(path, [[0, 0, 10], [4, 0, 10], [0, 3, 11], [4, 3, 11]])
    >>> cloud = read_points(path, "EPSG:28992")
    >>> len(cloud), cloud.crs.to_epsg()
    (4, 28992)
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("no input files given")
    user_crs = parse_crs(crs) if isinstance(crs, str) else crs
    clouds = []
    for i, p in enumerate(paths):
        c = _read_one(p)
        if user_crs is not None:
            if c.crs is not None and not c.crs.equals(user_crs, ignore_axis_order=True):
                if user_crs.is_compound and c.crs.equals(horizontal_crs(user_crs), ignore_axis_order=True):
                    # the file's CRS with its height system: nothing moves, the outputs record both
                    log.info("%s: --crs %s adds the height system %s to the file's CRS", p, user_crs.name,
                             user_crs.sub_crs_list[-1].name)
                else:
                    log.warning("%s: file CRS %s overridden by --crs %s", p, c.crs.name, user_crs.name)
            c.crs = user_crs
        c.fields["source_index"] = np.full(len(c), i, np.uint16)
        clouds.append(c)
    common_crs(paths, [c.crs for c in clouds])
    cloud = PointCloud.concatenate(clouds)
    if require_points and len(cloud) == 0:
        raise InputError(f"{', '.join(map(str, paths))}: the point cloud is empty")
    return cloud


def summarise_las(paths: Iterable[str | os.PathLike], crs: str | pyproj.CRS | None = None, *,
                  chunk_size: int = 2_000_000) -> dict:
    """Points, CRS, bounds, dimensions and class counts of LAS/LAZ files, read chunk by chunk.

    Memory stays that of one chunk whatever the files' size, and the files
    get the checks of :func:`read_points` (truncation, header counts and
    bounds, finite coordinates, one CRS).

    Returns
    -------
    dict
        ``points``, ``crs`` (a pyproj.CRS or None), ``bounds`` (xmin, ymin,
        zmin, xmax, ymax, zmax; zeros without points), ``dimensions`` (sorted
        names besides x, y, z) and ``classes`` ({class: count}, only when
        every file has a classification).
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("no input files given")
    user_crs = parse_crs(crs) if isinstance(crs, str) else crs
    crss, dims, n = [], set(), 0
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    classes = np.zeros(256, np.int64)
    classified = True
    for p in paths:
        if p.is_dir():
            raise InputError(f"{p}: is a folder, expected a point cloud file")
        first = True
        for header, chunk in las_chunks(p, chunk_size):
            if first:
                names = set(header.point_format.dimension_names) - {"X", "Y", "Z"}
                dims |= names
                classified &= "classification" in names
                crss.append(user_crs or las_crs(header, str(p)))
                first = False
            xyz = chunk_xyz(chunk)
            check_finite(p, xyz)
            if len(xyz):
                check_header_bounds(p, header, xyz)
                lo, hi = np.minimum(lo, xyz.min(axis=0)), np.maximum(hi, xyz.max(axis=0))
                if "classification" in names:
                    classes += np.bincount(np.asarray(chunk.classification, np.int64), minlength=256)[:256]
            n += len(xyz)
    out = {"points": n, "crs": common_crs(paths, crss),
           "bounds": [float(v) for v in (*lo, *hi)] if n else [0.0] * 6, "dimensions": sorted(dims)}
    if classified:
        out["classes"] = {int(c): int(k) for c, k in enumerate(classes) if k}
    return out


def common_crs(paths: list[Path], crss: list) -> pyproj.CRS | None:
    """The one CRS of several files (after any ``--crs``): the first file's.

    CRSs that give the same plan coordinates are one CRS
    (:func:`rooftrace.io.checks.same_plan_crs`: a vertical component on some
    files only, or the same projection written differently); a warning names
    the file.  The tiled and untiled runs both decide by this function.

    Raises
    ------
    OptionError
        A file whose CRS differs in plan from the first file's, or a file
        with a CRS beside one without, naming both files.
    """
    first = crss[0]
    for p, c in zip(paths[1:], crss[1:]):
        if first is None and c is None:
            continue
        if first is None or c is None or not same_plan_crs(first, c):
            raise OptionError(
                f"{p}: CRS ({_crs_name(c)}) differs from {paths[0]} ({_crs_name(first)}); "
                "reproject one of them or assign one with {crs}", "crs"
            )
        if not first.equals(c, ignore_axis_order=True):
            log.warning("%s: CRS %s taken as %s of %s (same plan coordinates)", p, c.name, first.name, paths[0])
    return first


def _crs_name(crs) -> str:
    return "none" if crs is None else crs.name
