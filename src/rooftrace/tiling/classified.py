"""The classified points of a tiled run: per-tile labels of the core points, merged and written streaming.

Each tile labels the points of its core (the buffers belong to other
tiles' cores), with the classes of its detection and, for building
points, the building's sort key (its lowest point, the key the merge numbers
buildings by).  The merge gathers the labels by the points' global index
(their order in the input files); :func:`rooftrace.io.las.write_las_labels`
writes them with every input dimension, chunk by chunk, so memory stays at
a few bytes per point plus one chunk.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["core_labels", "merge_labels"]


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
