"""LAS/LAZ reading and writing with laspy (lazrs backend).

Reading is chunked so a file is never decoded twice into memory, keeps every
dimension (standard and extra bytes), and takes the CRS from the WKT or
GeoTIFF VLRs/EVLRs (laspy's ``parse_crs``).  Writing keeps the first input's
point format, scales, offsets and extra dimensions, adds ``classification``
values and an int32 extra dimension ``building_id``, and goes through
:func:`rooftrace.io.atomic.atomic_path`: :func:`write_las` writes a cloud held
in memory, :func:`write_las_labels` streams input files to one output with
new labels, chunk by chunk (the classified points of a tiled run).
"""

from __future__ import annotations

import copy
import logging
import os
import struct
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np

from rooftrace.cloud import PointCloud
from rooftrace.errors import InputError, OptionError
from rooftrace.io.atomic import atomic_path

if TYPE_CHECKING:
    import pyproj

__all__ = ["read_las", "las_chunks", "chunk_xyz", "check_finite", "write_las", "write_las_labels", "las_crs",
           "check_point_count", "check_header_bounds", "check_point_formats", "LAS_SUFFIXES"]

log = logging.getLogger(__name__)

LAS_SUFFIXES = (".las", ".laz")
_CHUNK = 2_000_000
_COORDS = {"X", "Y", "Z", "x", "y", "z"}


def laz_backend():
    """The laspy LAZ backend to use (lazrs, in parallel when it can), or None without one."""
    for b in (laspy.LazBackend.LazrsParallel, laspy.LazBackend.Lazrs):
        if b.is_available():
            return b
    return None


def las_crs(header: laspy.LasHeader, path: str = "") -> pyproj.CRS | None:
    """CRS of a LAS header from its WKT or GeoTIFF (E)VLRs, or ``None``."""
    try:
        return header.parse_crs()
    except Exception as exc:  # malformed VLRs are the file's fault, not ours
        log.warning("%s: cannot parse the CRS VLR (%s); treating the file as having no CRS", path, exc)
        return None


def las_chunks(path: str | os.PathLike, chunk_size: int = _CHUNK) -> Iterator[tuple[laspy.LasHeader, laspy.ScaleAwarePointRecord]]:
    """The points of a LAS/LAZ file, chunk by chunk, for reading files larger than memory.

    Yields ``(header, chunk)``; a file without points yields one empty
    chunk, so its dimensions are still known.  Coordinates are not checked
    here (see :func:`read_las`).

    Raises
    ------
    InputError
        Missing, unreadable, truncated or non-LAS files, and files holding
        more or fewer points than their header announces.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    n = start = 0
    try:
        with laspy.open(path, laz_backend=laz_backend()) as reader:
            header = reader.header
            n = int(header.point_count)
            check_point_count(path, header)
            if n == 0:
                yield header, laspy.ScaleAwarePointRecord.zeros(0, header=header)
            for chunk in reader.chunk_iterator(chunk_size):
                if start + len(chunk) > n:
                    raise InputError(f"{path}: holds more points than its header says ({n}); the header is wrong")
                start += len(chunk)
                yield header, chunk
    except InputError:
        raise
    except laspy.errors.LaspyException as exc:
        if path.stat().st_size == 0:
            raise InputError(f"{path}: the file is empty (0 bytes); re-download or re-export it") from None
        raise InputError(f"{path}: not a readable LAS/LAZ file ({exc}); check that it is LAS/LAZ, "
                         "or re-export it") from None
    except (OSError, ValueError, RuntimeError, EOFError, struct.error, IndexError, KeyError, OverflowError) as exc:
        # laspy parses a damaged header or VLR with whatever exception the bytes lead to
        raise InputError(f"{path}: cannot read the point cloud, the file may be truncated or corrupt ({exc}); "
                         "re-download or re-export it") from None
    if start < n:
        raise InputError(
            f"{path}: truncated, the header announces {n} points but only {start} could be read; re-download or re-export the file"
        )


def chunk_xyz(chunk: laspy.ScaleAwarePointRecord) -> np.ndarray:
    """Scaled coordinates of a chunk, (M, 3) float64."""
    return np.column_stack([np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)]).astype(np.float64, copy=False)


def check_finite(path: str | os.PathLike, xyz: np.ndarray) -> None:
    """Refuse NaN or infinite coordinates, naming the file."""
    # the flat test first: the per-row one reduces (N, 3) along its short axis, 20 times slower
    bad = 0 if np.isfinite(xyz).all() else int((~np.isfinite(xyz).all(axis=1)).sum())
    if bad:
        raise InputError(f"{path}: {bad} points have NaN or infinite coordinates; remove them (e.g. with a filter) and retry")


def read_las(path: str | os.PathLike, chunk_size: int = _CHUNK) -> PointCloud:
    """Read a LAS or LAZ file (1.0-1.4, any point format) into a :class:`PointCloud`.

    Parameters
    ----------
    path : path-like
        The file.
    chunk_size : int, default 2 000 000
        Points decoded at once.

    Returns
    -------
    PointCloud
        Coordinates scaled to float64; every other dimension in ``fields``;
        ``crs`` from the file or ``None``.

    Raises
    ------
    InputError
        Missing, unreadable, truncated or non-LAS files, and non-finite
        coordinates.
    """
    path = Path(path)
    header = xyz = None
    fields: dict[str, np.ndarray] = {}
    start = 0
    for header, chunk in las_chunks(path, chunk_size):
        if xyz is None:
            n = int(header.point_count)
            names = [d for d in header.point_format.dimension_names if d not in _COORDS]
            xyz = np.empty((n, 3), np.float64)
        m = len(chunk)
        xyz[start:start + m] = chunk_xyz(chunk)
        for name in names:
            values = np.asarray(chunk[name])
            if name not in fields:
                fields[name] = np.empty(n, values.dtype)
            fields[name][start:start + m] = values
        start += m
    check_finite(path, xyz)
    if len(xyz):
        check_header_bounds(path, header, xyz)
    tmpl = copy.deepcopy(header)
    return PointCloud(xyz, fields, crs=las_crs(header, str(path)), template=tmpl, sources=[str(path)])


def check_point_count(path: str | os.PathLike, header: laspy.LasHeader) -> None:
    """Refuse an uncompressed LAS file that holds more points than its header announces.

    laspy reads exactly the announced count, so such a header would silently
    drop the rest.  (A LAZ file's point data cannot be sized without
    decompressing it; announcing more points than stored is caught as a
    truncation by the readers.)

    Raises
    ------
    InputError
        The file size or the first EVLR's offset leave room for more points,
        or for fewer (a truncated file).
    """
    path = Path(path)
    if header.are_points_compressed:
        return
    n = int(header.point_count)
    end = int(header.offset_to_point_data) + n * int(header.point_format.size)
    stop = path.stat().st_size
    if getattr(header, "number_of_evlrs", 0) and getattr(header, "start_of_first_evlr", 0):
        stop = int(header.start_of_first_evlr)
    size = int(header.point_format.size)
    if stop < end:  # checked before allocating: a corrupt count can announce terabytes
        held = max(0, (stop - int(header.offset_to_point_data)) // size)
        raise InputError(f"{path}: truncated, the header announces {n} points but the file holds only {held}; "
                         "re-download or re-export the file")
    extra = (stop - end) // size
    if extra > 0:
        raise InputError(
            f"{path}: the header announces {n} points but the file holds {n + extra}; the header is wrong, "
            "rewrite the file with a LAS tool (e.g. las2las) to repair it"
        )


def check_header_bounds(path: str | os.PathLike, header: laspy.LasHeader, xyz: np.ndarray) -> None:
    """Refuse points outside the header's bounds (tolerance: two scale steps).

    Tiling trusts the header bounds; a file whose points lie outside them
    was edited without updating its header.

    Raises
    ------
    InputError
        Some of ``xyz`` (N, 3) lie outside ``header.mins`` .. ``header.maxs``.
    """
    if not len(xyz):
        return
    tol = 2 * np.abs(np.asarray(header.scales, float)) + 1e-6
    # column by column: numpy reduces (N, 3) along axis 0 row by row (22 ms a million points)
    lo = np.array([xyz[:, j].min() for j in range(3)])
    hi = np.array([xyz[:, j].max() for j in range(3)])
    if np.any(lo < np.asarray(header.mins) - tol) or np.any(hi > np.asarray(header.maxs) + tol):
        raise InputError(
            f"{path}: points lie outside the header bounds (header {np.round(header.mins, 3).tolist()} .. "
            f"{np.round(header.maxs, 3).tolist()}, points {np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}); "
            "the header is wrong, rewrite the file with a LAS tool (e.g. las2las) to repair it"
        )


def _new_header(cloud: PointCloud) -> laspy.LasHeader:
    if cloud.template is not None:
        t = cloud.template
        header = laspy.LasHeader(version=t.version, point_format=copy.deepcopy(t.point_format))
        header.scales = np.array(t.scales)
        header.offsets = np.array(t.offsets)
        for vlr in t.vlrs:
            if type(vlr).__name__ not in ("WktCoordinateSystemVlr", "GeoKeyDirectoryVlr", "GeoAsciiParamsVlr",
                                          "GeoDoubleParamsVlr", "ExtraBytesVlr", "LasZipVlr"):
                header.vlrs.append(vlr)
    else:
        header = laspy.LasHeader(version="1.4", point_format=6)
        header.scales = np.array([0.001, 0.001, 0.001])
        lo = cloud.xyz.min(axis=0) if len(cloud) else np.zeros(3)
        header.offsets = np.floor(lo)
    return header


def write_las(
    path: str | os.PathLike,
    cloud: PointCloud,
    *,
    classification: np.ndarray | None = None,
    building_id: np.ndarray | None = None,
    extra: dict[str, np.ndarray] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a cloud as LAS or LAZ (by the suffix), keeping every input dimension.

    Parameters
    ----------
    path : path-like
        ``.las`` or ``.laz`` output.
    cloud : PointCloud
        Points; ``cloud.template`` gives the point format, scales and offsets.
    classification : ndarray of shape (N,), optional
        ASPRS classes replacing the input classification.
    building_id : ndarray of shape (N,), optional
        Written as the int32 extra dimension ``building_id`` (0 = none).
    extra : dict of str to ndarray, optional
        Further extra dimensions (float64 or int32 ...) to add.
    overwrite : bool, default False
        Replace an existing file.

    Returns
    -------
    Path
        The written file (replaced atomically).

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from rooftrace.io.points import read_points
    >>> xyz = np.array([[0.0, 0.0, 10.0], [4.0, 0.0, 10.0], [0.0, 3.0, 11.0]])
    >>> path = write_las(pathlib.Path(tempfile.mkdtemp()) / "roof.laz", PointCloud(xyz),
    ...                  classification=np.array([6, 6, 2]), building_id=np.array([1, 1, 0]))
    >>> read_points(path).fields["building_id"].tolist()
    [1, 1, 0]
    """
    path = Path(path)
    if path.suffix.lower() not in LAS_SUFFIXES:
        raise InputError(f"{path}: output must end in .las or .laz")
    header = _new_header(cloud)
    dims = set(header.point_format.dimension_names)
    added = dict(extra or {})
    if building_id is not None:
        added["building_id"] = np.asarray(building_id, np.int32)
    for name, values in added.items():
        if name not in dims:
            header.add_extra_dims([laspy.ExtraBytesParams(name=name, type=np.asarray(values).dtype)])
    if cloud.crs is not None:
        header.add_crs(cloud.crs)
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.x, cloud.y, cloud.z
    dims = set(header.point_format.dimension_names)
    for name, values in cloud.fields.items():
        if name in dims and name not in added and name != "classification":
            las[name] = values
    if classification is not None:
        cls = np.asarray(classification)
        if header.point_format.id < 6 and cls.max(initial=0) > 31:
            raise InputError(f"{path}: class values above 31 need point format 6 or higher")
        las.classification = cls.astype(np.uint8)
    elif "classification" in cloud.fields:
        las.classification = cloud.fields["classification"]
    for name, values in added.items():
        las[name] = values
    with atomic_path(path, overwrite) as tmp:
        las.write(tmp, laz_backend=laz_backend() if path.suffix.lower() == ".laz" else None)
    return path


def check_point_formats(paths: Sequence[Path]) -> None:
    """Refuse inputs of different point formats: one classified file keeps the dimensions of all."""
    formats = {}
    for p in paths:
        with laspy.open(p) as reader:
            formats[p] = reader.header.point_format.id
    if len(set(formats.values())) > 1:
        listing = ", ".join(f"{p.name}: {f}" for p, f in formats.items())
        raise OptionError(f"{{classified}} with tiles needs inputs of one LAS point format ({listing}); convert them "
                         "to one format (e.g. las2las -set_point_type) or write the classified points per file "
                         "with 'rooftrace detect'", "classified")


def write_las_labels(paths: Sequence[Path], output: str | os.PathLike, classification: np.ndarray,
                     building_id: np.ndarray, *, crs=None, overwrite: bool = False,
                     chunk_size: int = 1_000_000) -> Path:
    """Write the input points with new classes and a ``building_id`` extra dimension, chunk by chunk.

    Every dimension of the inputs is kept; the first file gives the point
    format, version, scales and offsets (coordinates of the other files are
    re-quantised to them).
    """
    output = Path(output)
    with laspy.open(paths[0]) as first:
        # the first header as it is: its VLRs carry the extra dimensions' descriptions
        header = copy.deepcopy(first.header)
    header.point_count = 0
    if "building_id" not in header.point_format.dimension_names:
        header.add_extra_dims([laspy.ExtraBytesParams(name="building_id", type=np.int32)])
    if crs is not None:
        header.add_crs(crs)
    names = [d for d in header.point_format.dimension_names
             if d not in ("X", "Y", "Z", "classification", "building_id")]
    start = 0
    with atomic_path(output, overwrite) as tmp:
        compress = output.suffix.lower() == ".laz"
        with laspy.open(tmp, mode="w", header=header, do_compress=compress,
                        laz_backend=laz_backend() if compress else None) as writer:
            for p in paths:
                with laspy.open(p, laz_backend=laz_backend()) as reader:
                    for chunk in reader.chunk_iterator(chunk_size):
                        n = len(chunk)
                        out = laspy.ScaleAwarePointRecord.zeros(n, header=header)
                        have = set(chunk.point_format.dimension_names)
                        for name in names:
                            if name in have:
                                out[name] = chunk[name]
                        out.x, out.y, out.z = chunk.x, chunk.y, chunk.z
                        out.classification = classification[start:start + n]
                        out["building_id"] = building_id[start:start + n]
                        writer.write_points(out)
                        start += n
    return output
