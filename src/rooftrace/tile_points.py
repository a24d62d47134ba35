"""The classified points of a tiled run: per-tile labels of the core points, merged and written streaming.

Each tile labels the points of its core (the buffers belong to other
tiles' cores), with the classes of its detection and, for building
points, the building's sort key (its lowest point, the key the merge numbers
buildings by).  The merge gathers the labels by the points' global index
(their order in the input files) and writes one LAS/LAZ chunk by chunk,
copying every input dimension, so memory stays at a few bytes per point
plus one chunk.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rooftrace.errors import InputError

__all__ = ["core_labels", "merge_labels", "check_point_formats", "write_classified"]


def core_labels(gidx: np.ndarray, xy: np.ndarray, core: Sequence[float], classification: np.ndarray,
                building_id: np.ndarray, ids: np.ndarray, keys: np.ndarray) -> dict[str, np.ndarray]:
    """Labels of the points in a tile's core.

    Parameters
    ----------
    gidx : ndarray of shape (N,), int64
        Global index of each tile point.
    xy : ndarray of shape (N, 2)
    core : (xmin, xmax, ymin, ymax)
        Half-open core of the tile.
    classification, building_id : ndarray of shape (N,)
        The tile's detection.
    ids : ndarray of shape (B,), int64
        Sorted building ids present in the tile.
    keys : ndarray of shape (B, 3)
        Their sort keys.

    Returns
    -------
    dict
        ``gidx``, ``classification`` (uint8), ``key_index`` (int32 row of
        ``keys``, -1 for no building) for the core points, and ``keys``.
    """
    x0, x1, y0, y1 = core
    inside = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
    bid = np.asarray(building_id)[inside]
    key_index = np.full(len(bid), -1, np.int32)
    has = bid > 0
    key_index[has] = np.searchsorted(ids, bid[has])
    return {"gidx": np.asarray(gidx)[inside].astype(np.int64), "classification":
            np.asarray(classification)[inside].astype(np.uint8), "key_index": key_index,
            "keys": np.asarray(keys, np.float64).reshape(-1, 3)}


def merge_labels(parts: Sequence[dict], new_id: dict[tuple, int], n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Classes and building ids of every input point from the tiles' core labels.

    ``new_id`` maps a building's sort key (a tuple of three floats) to its
    id in the merged output; a point whose building no tile owns keeps its
    class with id 0.  Points in no core (none, the cores tile the plane)
    would stay class 1.
    """
    classification = np.ones(n_points, np.uint8)
    building_id = np.zeros(n_points, np.int32)
    for part in parts:
        table = np.array([new_id.get(tuple(k), 0) for k in part["keys"].tolist()] + [0], np.int32)
        classification[part["gidx"]] = part["classification"]
        building_id[part["gidx"]] = table[part["key_index"]]  # -1 picks the trailing 0
    return classification, building_id


def check_point_formats(paths: Sequence[Path]) -> None:
    """Refuse inputs of different point formats: one classified file keeps the dimensions of all."""
    import laspy

    formats = {}
    for p in paths:
        with laspy.open(p) as reader:
            formats[p] = reader.header.point_format.id
    if len(set(formats.values())) > 1:
        listing = ", ".join(f"{p.name}: {f}" for p, f in formats.items())
        raise InputError(f"--classified with tiles needs inputs of one LAS point format ({listing}); convert them "
                         "to one format (e.g. las2las -set_point_type) or write the classified points per file "
                         "with 'rooftrace detect'")


def write_classified(paths: Sequence[Path], output: str | os.PathLike, classification: np.ndarray,
                     building_id: np.ndarray, *, crs=None, overwrite: bool = False,
                     chunk_size: int = 1_000_000) -> Path:
    """Write the input points with new classes and a ``building_id`` extra dimension, chunk by chunk.

    Every dimension of the inputs is kept; the first file gives the point
    format, version, scales and offsets (coordinates of the other files are
    re-quantised to them).
    """
    import laspy

    from rooftrace.io.atomic import atomic_path
    from rooftrace.io.las import _backend

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
                        laz_backend=_backend() if compress else None) as writer:
            for p in paths:
                with laspy.open(p, laz_backend=_backend()) as reader:
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
