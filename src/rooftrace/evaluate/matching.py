"""Matching extracted to reference buildings by overlap.

Two rules, both recorded by name in ``metrics.json`` (``matching_rule``):

* ``"one-to-one"``: each extracted polygon is paired with at most one
  reference polygon, maximising the total overlap area (Hungarian assignment
  inside each connected group of overlapping polygons);
* ``"merged-blocks"``: the connected components of the bipartite graph of
  substantial overlaps are evaluated as one unit each, so that terraced
  houses split in the reference but extracted as one block (or the reverse)
  are compared block against block.

An overlap is *substantial* when the intersection covers at least
``min_overlap`` of the smaller polygon's area, i.e. at least that fraction of
the extracted or of the reference polygon. Only substantial overlaps match.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import shapely
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["Matching", "match_buildings", "overlaps", "coverage", "RULES"]

log = logging.getLogger(__name__)

#: matching rule name -> the sentence written into metrics.json
RULES = {
    "one-to-one": "one-to-one: maximum total overlap (Hungarian assignment) among pairs whose "
                  "intersection covers >= {t:.0%} of the extracted or of the reference polygon",
    "merged-blocks": "merged blocks: connected components of the graph of extracted/reference pairs whose "
                     "intersection covers >= {t:.0%} of either polygon; each component evaluated as one unit",
}


@dataclass(frozen=True)
class Matching:
    """The evaluation units of a scene.

    Attributes
    ----------
    units : list of (tuple of int, tuple of int)
        One entry per unit: indices into the extracted and the reference
        sequences. A unit with an empty reference side is a false detection,
        one with an empty extracted side a missed building. Sorted by the
        smallest reference index, then by the smallest extracted index.
    rule : {'one-to-one', 'merged-blocks'}
    description : str
        The rule in words, with the threshold.
    pairs : ndarray of shape (K, 2) int64
        All intersecting (extracted, reference) index pairs.
    inter : ndarray of shape (K,) float64
        Their intersection areas.
    """

    units: list[tuple[tuple[int, ...], tuple[int, ...]]]
    rule: str
    description: str
    pairs: np.ndarray = field(repr=False)
    inter: np.ndarray = field(repr=False)

    @property
    def matched(self) -> list[tuple[tuple[int, ...], tuple[int, ...]]]:
        """Units with both an extracted and a reference side."""
        return [u for u in self.units if u[0] and u[1]]


def _areas(geoms: np.ndarray) -> np.ndarray:
    return shapely.area(geoms) if len(geoms) else np.empty(0)


def overlaps(extracted, reference) -> tuple[np.ndarray, np.ndarray]:
    """Intersecting pairs and their intersection areas.

    Parameters
    ----------
    extracted, reference : sequence of Polygon/MultiPolygon

    Returns
    -------
    pairs : ndarray of shape (K, 2) int64
        (extracted index, reference index), sorted lexicographically.
    inter : ndarray of shape (K,) float64
        Planimetric intersection area of each pair (> 0).
    """
    ext = np.asarray(extracted, dtype=object)
    ref = np.asarray(reference, dtype=object)
    if len(ext) == 0 or len(ref) == 0:
        return np.empty((0, 2), dtype=np.int64), np.empty(0)
    tree = shapely.STRtree(ref)
    idx = tree.query(ext, predicate="intersects").T.astype(np.int64)
    order = np.lexsort((idx[:, 1], idx[:, 0]))
    idx = idx[order]
    inter = shapely.area(shapely.intersection(ext[idx[:, 0]], ref[idx[:, 1]])) if len(idx) else np.empty(0)
    keep = inter > 0  # touching along an edge or a corner is no overlap
    return idx[keep], inter[keep]


def coverage(geoms, others, pairs: np.ndarray, inter: np.ndarray, side: int) -> np.ndarray:
    """Fraction of each polygon's area covered by the union of the others.

    Parameters
    ----------
    geoms, others : sequence of Polygon/MultiPolygon
    pairs, inter : from :func:`overlaps`
    side : {0, 1}
        Column of ``pairs`` indexing ``geoms`` (0 extracted, 1 reference).

    Returns
    -------
    ndarray of shape (len(geoms),) float64 in [0, 1]; NaN for zero-area polygons.
    """
    geoms = np.asarray(geoms, dtype=object)
    others = np.asarray(others, dtype=object)
    areas = _areas(geoms)
    covered = np.bincount(pairs[:, side], weights=inter, minlength=len(geoms)) if len(pairs) else np.zeros(len(geoms))
    counts = np.bincount(pairs[:, side], minlength=len(geoms)) if len(pairs) else np.zeros(len(geoms), int)
    # the sum of pairwise overlaps counts twice where the others overlap each other
    for i in np.flatnonzero(counts > 1):
        nb = pairs[pairs[:, side] == i, 1 - side]
        covered[i] = shapely.intersection(geoms[i], shapely.union_all(others[nb])).area
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(areas > 0, np.minimum(covered / np.where(areas > 0, areas, 1.0), 1.0), np.nan)


def match_buildings(extracted, reference, *, min_overlap: float = 0.5, merge_blocks: bool = True) -> Matching:
    """Match extracted to reference buildings.

    Parameters
    ----------
    extracted, reference : sequence of Polygon/MultiPolygon
        Valid polygons; z is ignored (planimetric overlap). None or empty
        entries never match: each becomes a unit of its own.
    min_overlap : float, default 0.5
        Fraction in (0, 1] of the smaller polygon that the intersection must
        cover for a pair to match (see the module notes).
    merge_blocks : bool, default True
        True: connected components of substantial overlaps are units
        (``'merged-blocks'``). False: ``'one-to-one'``.

    Returns
    -------
    Matching

    Examples
    --------
    >>> from shapely import box
    >>> m = match_buildings([box(0, 0, 20, 10)], [box(0, 0, 10, 10), box(10, 0, 20, 10)])
    >>> m.units
    [((0,), (0, 1))]
    >>> match_buildings([box(0, 0, 20, 10)], [box(0, 0, 10, 10), box(10, 0, 20, 10)],
    ...                 merge_blocks=False).units
    [((0,), (0,)), ((), (1,))]
    """
    if isinstance(min_overlap, bool) or not isinstance(min_overlap, (int, float)):
        raise TypeError(f"min_overlap must be a number, not {min_overlap!r}")
    if not 0 < min_overlap <= 1:
        raise ValueError(f"min_overlap must be in (0, 1], not {min_overlap}")
    ext = np.asarray(extracted, dtype=object)
    ref = np.asarray(reference, dtype=object)
    n_e, n_r = len(ext), len(ref)
    pairs, inter = overlaps(ext, ref)
    if len(pairs):
        smaller = np.minimum(_areas(ext)[pairs[:, 0]], _areas(ref)[pairs[:, 1]])
        strong = inter >= min_overlap * smaller * (1 - 1e-12)
    else:
        strong = np.zeros(0, dtype=bool)
    sp, si = pairs[strong], inter[strong]

    # nodes 0..n_e-1 extracted, n_e..n_e+n_r-1 reference
    n = n_e + n_r
    graph = coo_matrix((np.ones(len(sp)), (sp[:, 0], sp[:, 1] + n_e)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    groups: dict[int, tuple[list[int], list[int]]] = {}
    for node, lab in enumerate(labels):
        side = groups.setdefault(int(lab), ([], []))
        (side[0].append(node) if node < n_e else side[1].append(node - n_e))

    units: list[tuple[tuple[int, ...], tuple[int, ...]]] = []
    for e_ids, r_ids in groups.values():
        if merge_blocks or len(e_ids) + len(r_ids) <= 2:
            units.append((tuple(e_ids), tuple(r_ids)))
        else:
            units.extend(_assign(e_ids, r_ids, sp, si))
    units.sort(key=lambda u: (min(u[1]) if u[1] else n_r, min(u[0]) if u[0] else n_e))
    rule = "merged-blocks" if merge_blocks else "one-to-one"
    m = Matching(units, rule, RULES[rule].format(t=min_overlap), pairs, inter)
    log.debug("matched %d units (%s) from %d extracted, %d reference", len(m.matched), rule, n_e, n_r)
    return m


def _assign(e_ids: list[int], r_ids: list[int], sp: np.ndarray, si: np.ndarray):
    """Hungarian assignment maximising overlap inside one component; leftovers stay single."""
    e_pos = {e: k for k, e in enumerate(e_ids)}
    r_pos = {r: k for k, r in enumerate(r_ids)}
    weight = np.zeros((len(e_ids), len(r_ids)))
    sel = np.isin(sp[:, 0], e_ids) & np.isin(sp[:, 1], r_ids)
    for (e, r), a in zip(sp[sel], si[sel]):
        weight[e_pos[e], r_pos[r]] = a
    rows, cols = linear_sum_assignment(weight, maximize=True)
    out, used_e, used_r = [], set(), set()
    for i, j in zip(rows, cols):
        if weight[i, j] > 0:
            out.append(((e_ids[i],), (r_ids[j],)))
            used_e.add(e_ids[i])
            used_r.add(r_ids[j])
    out += [((e,), ()) for e in e_ids if e not in used_e]
    out += [((), (r,)) for r in r_ids if r not in used_r]
    return out
