"""Cell-histogram outlier filter (Carrilho et al. 2018; thesis §3.1).

The cloud is cut into square cells; in each cell the heights are binned; the
first and the last bin holding at least ``min_count`` points bound the
accepted height interval, and points outside it are noise (ASPRS class 7).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rooftrace.lidar._kernels import column_min, dense_cells, dense_unique

__all__ = ["OutlierOptions", "histogram_outliers"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OutlierOptions:
    """Options of the outlier filter (TOML table ``[outliers]``).

    Attributes
    ----------
    cell : float, default 50.0
        Cell side D_g (m) (thesis Table 6.1).
    bin_width : float, default 0.15
        Height bin A_H (m) (thesis Table 6.1).
    min_count : int, default 5
        Frequency threshold L_f (points per bin) (thesis Table 6.1).
    enabled : bool, default True
        Set false for clouds already cleaned.
    """

    section: ClassVar[str] = "outliers"
    cell: float = 50.0
    bin_width: float = 0.15
    min_count: int = 5
    enabled: bool = True

    def __post_init__(self) -> None:
        if not self.cell > 0 or not self.bin_width > 0:
            raise ValueError(f"outliers.cell and outliers.bin_width must be > 0, got {self.cell}, {self.bin_width}")
        if self.min_count < 1:
            raise ValueError(f"outliers.min_count must be >= 1, got {self.min_count}")


def histogram_outliers(
    xyz: np.ndarray, options: OutlierOptions | None = None, *, origin: tuple[float, float] | None = None
) -> np.ndarray:
    """Flag points outside their cell's well-populated height interval.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Coordinates (m).
    options : OutlierOptions, optional
    origin : (float, float), optional
        Corner (m) the cell grid is anchored at.  Default: the lowest x and y
        of ``xyz``.  A tiled run passes the corner of the whole input, so a
        tile whose extent follows the same cell lines sees the same cells.

    Returns
    -------
    ndarray of shape (N,), bool
        True for noise.

    Notes
    -----
    Bins are counted from each cell's lowest point.  Points in the bin next
    to the accepted interval are kept too: where a sloped surface crosses a
    bin boundary that bin may hold a thin sliver of fewer than ``min_count``
    points, while real outliers are metres away.  A cell where no bin
    reaches ``min_count`` (a nearly empty corner cell) keeps all its points:
    there is no population to judge them against.  Vectorised over cells
    with one sort; no Python loop.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> p = np.column_stack([rng.uniform(0, 10, (500, 2)), rng.normal(0, 0.05, 500)])
    >>> p = np.vstack([p, [[5, 5, 30.0], [5, 6, -20.0]]])
    >>> np.flatnonzero(histogram_outliers(p)).tolist()
    [500, 501]
    """
    opt = options or OutlierOptions()
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    noise = np.zeros(n, bool)
    if n == 0 or not opt.enabled:
        return noise
    anchor = column_min(xyz[:, :2]) if origin is None else np.asarray(origin, np.float64)
    ij = np.floor((xyz[:, :2] - anchor) / opt.cell).astype(np.int64)
    cell = dense_cells(ij)  # shifted to start at 0: an explicit origin may lie inside the data
    ncell = cell.max() + 1
    zmin = np.full(ncell, np.inf)
    np.minimum.at(zmin, cell, xyz[:, 2])
    b = np.floor((xyz[:, 2] - zmin[cell]) / opt.bin_width).astype(np.int64)
    nbin = int(b.max()) + 1
    key = cell * nbin + b
    ukey, inv = dense_unique(key)
    counts = np.bincount(inv)
    full = counts >= opt.min_count
    kcell, kbin = ukey // nbin, ukey % nbin
    lo = np.full(ncell, np.iinfo(np.int64).max)
    hi = np.full(ncell, -1)
    np.minimum.at(lo, kcell[full], kbin[full])
    np.maximum.at(hi, kcell[full], kbin[full])
    judged = hi[cell] >= 0
    # one bin of margin: the first bin of a sloped surface can be a sliver
    # with fewer than min_count points although nothing is wrong with them
    noise = judged & ((b < lo[cell] - 1) | (b > hi[cell] + 1))
    log.debug("outliers: %d of %d points in %d cells", int(noise.sum()), n, ncell)
    return noise
