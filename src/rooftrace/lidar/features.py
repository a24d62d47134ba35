"""Eigen-features of point neighbourhoods: linearity, planarity, sphericity, entropy and normals.

For each point the covariance of its neighbourhood gives eigenvalues
lambda1 >= lambda2 >= lambda3; linearity L = (l1 - l2)/l1, planarity
P = (l2 - l3)/l1, sphericity S = l3/l1 and the dimensionality entropy
E = -L ln L - P ln P - S ln S (thesis §3.4, eq. 3.6-3.9).

Two neighbourhoods:

- *fixed* (the thesis): the N nearest points, N = Ar_min·d_avg;
- *adaptive* (Demantké et al. 2011; Weinmann et al. 2015): for each point
  the k in ``min_neighbours, min_neighbours + step, ..., N`` whose
  neighbourhood has the lowest entropy E, i.e. the scale at which the point
  looks most clearly one-, two- or three-dimensional.  A fixed N of about
  4 m² reaches over the edge of a small low roof (a garden shed, a rear
  extension) into the wall above it and the crown beside it, so its points
  look volumetric; at a smaller k they are planar.  A crown is scattered at
  every scale and stays volumetric.  On Delft (AHN3) this moved the per-point
  building F1 from 0.933 to 0.950 (docs/design-notes.md).

The neighbours are those of ``cKDTree.query``, in its order: an exact search
on a plan grid finds them (:class:`rooftrace.lidar.neighbours.GridKnn`, about
twice as fast at N = 60) and the KD-tree answers the rows where two distances
tie, whose order is its traversal's.

References
----------
Demantké, J., Mallet, C., David, N., Vallet, B. (2011). Dimensionality based
scale selection in 3D lidar point clouds. IAPRS 38(5/W12), 97-102.
https://doi.org/10.5194/isprsarchives-XXXVIII-5-W12-97-2011

Weinmann, M., Jutzi, B., Hinz, S., Mallet, C. (2015). Semantic point cloud
interpretation based on optimal neighborhoods, relevant features and
efficient classifiers. ISPRS J. Photogramm. Remote Sens. 105, 286-304.
https://doi.org/10.1016/j.isprsjprs.2015.01.016
"""

from __future__ import annotations

import llvmlite.binding as llvm
import numba
import numpy as np
from numba import types
from numba.extending import get_cython_function_address
from scipy.spatial import cKDTree

from rooftrace.lidar.neighbours import GridKnn

__all__ = ["eigen_features", "scatter_sums"]


@numba.njit(cache=True)
def _dimensionality(a: float, b: float, c: float, d: float, e: float, f: float) -> tuple:  # pragma: no cover
    """L, P, S of the symmetric 3x3 scatter matrix [[a d e] [d b f] [e f c]] (trigonometric eigenvalues)."""
    q = (a + b + c) / 3.0
    p1 = d * d + e * e + f * f
    p2 = (a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2.0 * p1
    if p2 <= 1e-30 * max(q * q, 1e-300):
        l1 = l2 = l3 = q
    else:
        pp = np.sqrt(p2 / 6.0)
        ba = (a - q) / pp
        bb = (b - q) / pp
        bc = (c - q) / pp
        bd = d / pp
        be = e / pp
        bf = f / pp
        r = (ba * (bb * bc - bf * bf) - bd * (bd * bc - bf * be) + be * (bd * bf - bb * be)) / 2.0
        r = min(max(r, -1.0), 1.0)
        phi = np.arccos(r) / 3.0
        l1 = q + 2.0 * pp * np.cos(phi)
        l3 = q + 2.0 * pp * np.cos(phi + 2.0 * np.pi / 3.0)
        l2 = 3.0 * q - l1 - l3
    if l1 <= 0.0:
        return 0.0, 0.0, 1.0
    l3 = max(l3, 0.0)
    l2 = min(max(l2, l3), l1)
    return (l1 - l2) / l1, (l2 - l3) / l1, l3 / l1


@numba.njit(cache=True)
def _entropy(lin: float, pla: float, sph: float) -> float:  # pragma: no cover - compiled
    e = 0.0
    for v in (lin, pla, sph):
        if v > 0.0:
            e -= v * np.log(v)
    return e


@numba.njit(cache=True)
def scatter_sums(xyz: np.ndarray, row: np.ndarray, k: int) -> tuple:  # pragma: no cover - compiled
    """Scatter matrix entries (a, b, c, d, e, f) = (xx, yy, zz, xy, xz, yz) (m²) of the points ``row[:k]`` about their mean.

    The mean and each product summed in ``row``'s order (also the roof
    segmentation's neighbourhood covariances, :mod:`rooftrace.roof.plane_kernels`).
    """
    mx = my = mz = 0.0
    for j in range(k):
        p = row[j]
        mx += xyz[p, 0]
        my += xyz[p, 1]
        mz += xyz[p, 2]
    mx /= k
    my /= k
    mz /= k
    a = b = c = d = e = f = 0.0
    for j in range(k):
        p = row[j]
        dx = xyz[p, 0] - mx
        dy = xyz[p, 1] - my
        dz = xyz[p, 2] - mz
        a += dx * dx
        b += dy * dy
        c += dz * dz
        d += dx * dy
        e += dx * dz
        f += dy * dz
    return a, b, c, d, e, f


@numba.njit(cache=True)
def _fixed_row(xyz, row, k, out_row):  # pragma: no cover - compiled
    a, b, c, d, e, f = scatter_sums(xyz, row, k)
    out_row[0], out_row[1], out_row[2] = _dimensionality(a, b, c, d, e, f)


@numba.njit(cache=True)
def _min_entropy_row(xyz, row, ks, out_row, lin_n, i):  # pragma: no cover - compiled
    """L, P, S at the k of ``ks`` (ascending) with the lowest entropy, and L at the last k; row sorted by distance."""
    kmax = len(row)
    # moments about the nearest point (the point itself; small numbers),
    # accumulated as the neighbourhood grows
    o = row[0]
    sx = sy = sz = sxx = syy = szz = sxy = sxz = syz = 0.0
    best = np.inf
    c = 0
    for j in range(kmax):
        p = row[j]
        x = xyz[p, 0] - xyz[o, 0]
        y = xyz[p, 1] - xyz[o, 1]
        z = xyz[p, 2] - xyz[o, 2]
        sx += x
        sy += y
        sz += z
        sxx += x * x
        syy += y * y
        szz += z * z
        sxy += x * y
        sxz += x * z
        syz += y * z
        if c < len(ks) and j + 1 == ks[c]:
            m = j + 1.0
            lin, pla, sph = _dimensionality(sxx - sx * sx / m, syy - sy * sy / m, szz - sz * sz / m,
                                            sxy - sx * sy / m, sxz - sx * sz / m, syz - sy * sz / m)
            e = _entropy(lin, pla, sph)
            lin_n[i] = lin
            if e < best:
                best = e
                out_row[0] = lin
                out_row[1] = pla
                out_row[2] = sph
            c += 1


# LAPACK's dsyevd from scipy, the routine numba's np.linalg.eigh calls, under
# a symbol of its own: called with a workspace kept per thread, without
# eigh's workspace query and four allocations per call (0.4 of its 1.2 µs
# for a 3 x 3 matrix), with the same arguments, so the same bits
llvm.add_symbol("rooftrace_lapack_dsyevd", get_cython_function_address("scipy.linalg.cython_lapack", "dsyevd"))
# (jobz, uplo, n, a, lda, w, work, lwork, iwork, liwork, info), all by reference
_dsyevd = types.ExternalFunction("rooftrace_lapack_dsyevd", types.void(*([types.voidptr] * 11)))


@numba.njit(cache=True)
def _eigh_workspace():  # pragma: no cover - compiled
    """Arguments of :func:`_eigh3`: (chars, ints, a, w, work, iwork) for dsyevd('V', 'L') of order 3.

    ``chars`` holds jobz, uplo; ``ints`` n, lda, lwork, liwork, info; the
    work sizes are LAPACK's answer to a workspace query, as in numba's eigh.
    """
    chars = np.array([ord("V"), ord("L")], np.uint8)
    ints = np.array([3, 3, -1, -1, 0], np.int32)
    a = np.zeros(9)
    w = np.empty(3)
    size = np.empty(1)
    isize = np.empty(1, np.int32)
    _dsyevd(chars[0:].ctypes, chars[1:].ctypes, ints[0:].ctypes, a.ctypes, ints[1:].ctypes, w.ctypes, size.ctypes,
            ints[2:].ctypes, isize.ctypes, ints[3:].ctypes, ints[4:].ctypes)
    ints[2] = np.int32(size[0])
    ints[3] = isize[0]
    return chars, ints, a, w, np.empty(ints[2]), np.empty(ints[3], np.int32)


@numba.njit(cache=True, inline="always")
def _eigh3(a, b, c, d, e, f, ws):  # pragma: no cover - compiled
    """``np.linalg.eigh`` of [[a d e] [d b f] [e f c]]: the eigenvalues (ascending) into ``ws[3]``, the
    eigenvectors into the columns of ``ws[2]`` (column-major: vector j is ``ws[2][3 j:3 j + 3]``)."""
    chars, ints, m, w, work, iwork = ws
    if not (np.isfinite(a) and np.isfinite(b) and np.isfinite(c) and np.isfinite(d) and np.isfinite(e)
            and np.isfinite(f)):
        raise np.linalg.LinAlgError("Array must not contain infs or NaNs.")
    # the column-major copy numba's eigh makes
    m[0], m[1], m[2] = a, d, e
    m[3], m[4], m[5] = d, b, f
    m[6], m[7], m[8] = e, f, c
    _dsyevd(chars[0:].ctypes, chars[1:].ctypes, ints[0:].ctypes, m.ctypes, ints[1:].ctypes, w.ctypes, work.ctypes,
            ints[2:].ctypes, iwork.ctypes, ints[3:].ctypes, ints[4:].ctypes)
    if ints[4] != 0:
        raise np.linalg.LinAlgError("Eigenvalues did not converge")


@numba.njit(cache=True)
def _normal_row(xyz, row, kn, out_row, ws):  # pragma: no cover - compiled
    a, b, c, d, e, f = scatter_sums(xyz, row, kn)
    _eigh3(a, b, c, d, e, f, ws)
    v, w = ws[2], ws[3]
    nx, ny, nz = v[0], v[1], v[2]
    if nz < 0:
        nx, ny, nz = -nx, -ny, -nz
    out_row[0] = nx
    out_row[1] = ny
    out_row[2] = nz
    # RMS distance of the points to their plane
    out_row[3] = np.sqrt(max(w[0], 0.0) / kn)


#: rows per thread's share of :func:`_chunk_features` (each share has its own LAPACK workspace)
_SHARE = 256


@numba.njit(cache=True, parallel=True)
def _chunk_features(xyz, idx, ks, kn, lps, lin_n, normals):  # pragma: no cover - compiled
    """Features of each row of ``idx`` (one pass; rows are independent, so threads give the serial result).

    ``ks`` empty: the fixed size ``idx.shape[1]``; ``kn`` 0: no normals.
    """
    n, k = idx.shape
    for share in numba.prange((n + _SHARE - 1) // _SHARE):
        ws = _eigh_workspace()
        for i in range(share * _SHARE, min(n, (share + 1) * _SHARE)):
            row = idx[i]
            if len(ks) == 0:
                _fixed_row(xyz, row, k, lps[i])
                lin_n[i] = lps[i, 0]
            else:
                _min_entropy_row(xyz, row, ks, lps[i], lin_n, i)
            if kn > 0:
                _normal_row(xyz, row, kn, normals[i], ws)


def eigen_features(
    xyz: np.ndarray,
    neighbours: int,
    *,
    min_neighbours: int | None = None,
    neighbour_step: int = 5,
    normal_neighbours: int | None = None,
    return_linearity: bool = False,
    chunk: int = 100_000,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Linearity, planarity, sphericity and entropy of each point's neighbourhood.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m); neighbours are searched among these points.
    neighbours : int
        N, the neighbourhood size (the point itself included); with
        ``min_neighbours`` the largest size tried.
    min_neighbours : int, optional
        When given, the neighbourhood is adaptive: of the sizes
        ``min_neighbours, min_neighbours + neighbour_step, ..., neighbours``
        each point takes the one with the lowest entropy E (Demantké et al.
        2011, Weinmann et al. 2015; see the module notes).  ``None``: every
        point uses N (thesis §3.4).
    neighbour_step : int, default 5
        Step between the adaptive sizes.
    normal_neighbours : int, optional
        When given, the unit normal (upward) of the plane fitted to the
        ``normal_neighbours`` nearest points is returned too (a smaller
        neighbourhood than N keeps roof ridges sharp), and the RMS distance
        of those points to that plane (m): about sigma_H on a roof face,
        tenths of a metre in a crown, whatever the scan pattern once the
        neighbourhood spans two scan lines.
    return_linearity : bool, default False
        Also return the linearity of the N-point neighbourhood.  With the
        adaptive size it differs: where the sampling is anisotropic (scan
        lines farther apart than the points along them) the smallest sizes
        look linear, so a roof's points may take a linear size (low entropy
        either way), while a wire is linear at N too.
    chunk : int, default 100000
        Points per neighbour query, to bound memory.

    Returns
    -------
    ndarray of shape (N, 4) or (N, 8), float64
        Columns L, P, S (each in [0, 1], summing to 1), E (in [0, ln 3]),
        then nx, ny, nz and the plane residual (m) when
        ``normal_neighbours`` is given.
    linearity : ndarray of shape (N,), float64
        With ``return_linearity``: L of the N-point neighbourhood.

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
    >>> f = eigen_features(np.column_stack([g, np.zeros(100)]), 9)
    >>> bool(np.all(f[:, 2] < 1e-9))
    True
    >>> f = eigen_features(np.column_stack([g, np.zeros(100)]), 30, min_neighbours=10)
    >>> bool(np.all(f[:, 2] < 1e-9))
    True
    """
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    if min_neighbours is not None and not 3 <= min_neighbours <= neighbours:
        raise ValueError(f"min_neighbours must be in [3, neighbours = {neighbours}], got {min_neighbours}")
    if neighbour_step < 1:
        raise ValueError(f"neighbour_step must be >= 1, got {neighbour_step}")
    n = len(xyz)
    out = np.zeros((n, 4 if normal_neighbours is None else 8))
    if n == 0:
        return (out, np.zeros(0)) if return_linearity else out
    k = int(min(neighbours, n))
    ks = None
    if min_neighbours is not None:
        ks = np.arange(min(min_neighbours, k), k + 1, neighbour_step, dtype=np.int64)
        ks = np.unique(np.append(ks, k))  # the largest size is always tried
    local = xyz - xyz.mean(axis=0)
    lps = np.empty((n, 3))
    lin_n = np.empty(n)
    ks = np.empty(0, np.int64) if ks is None else ks
    kn = 0 if normal_neighbours is None else int(min(max(normal_neighbours, 3), k))
    normals = np.empty((n if kn else 0, 4))
    # the grid search gives cKDTree's neighbours in cKDTree's order, twice
    # as fast; the rows where distances tie (their order is the tree's
    # traversal) are redone from the tree once the grid is freed
    redo = [np.arange(n)]
    if n > k:
        grid = GridKnn(local, k)
        redo = []
        for start in range(0, n, chunk):
            stop = min(start + chunk, n)
            idx, tie = grid.query(np.arange(start, stop))
            _chunk_features(local, idx, ks, kn, lps[start:stop], lin_n[start:stop], normals[start:stop])
            redo.append(start + np.flatnonzero(tie))
        del grid
    redo = np.concatenate(redo)
    if len(redo):
        tree = cKDTree(local)
        for start in range(0, len(redo), chunk):
            rows = redo[start:start + chunk]
            _, idx = tree.query(local[rows], k=k, workers=-1)
            idx = np.ascontiguousarray(np.asarray(idx, np.int64).reshape(len(rows), k))
            part = np.empty((len(rows), 3)), np.empty(len(rows)), np.empty((len(rows) if kn else 0, 4))
            _chunk_features(local, idx, ks, kn, *part)
            lps[rows], lin_n[rows] = part[0], part[1]
            if kn:
                normals[rows] = part[2]
    if normal_neighbours is not None:
        out[:, 4:] = normals
    out[:, :3] = lps
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(lps > 0, -lps * np.log(lps), 0.0)
    out[:, 3] = terms.sum(axis=1)
    return (out, lin_n) if return_linearity else out
