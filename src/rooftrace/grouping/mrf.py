"""The MRF energy of Marcato & Dal Poz (eq. 6-13) for grouping image lines into a roof.

Every side or ridge ``s`` of the projected roof has candidate image lines
(``K_s >= 1``); a labelling picks exactly one per side (the uniqueness rule
of §2.3), so a configuration is an integer vector ``c`` of length M and the
binary ``x_i`` of the paper are its one-hot expansion.  The energy

    U(c) = a1 U1 + a2 U2 + a3 U3 + a4 U4 + a5 U5

is a sum of a unary term (U1) and pairwise terms over adjacent sides (U2-U5),
so it is stored as one vector per side and one ``(K_s, K_t)`` table per
adjacent pair, computed once; a whole GA population is then evaluated with
two fancy-indexing sums (:meth:`GroupingProblem.energy`).

Interpretations of the seed (stated here, tested in tests/grouping):

- ``Σ_i Σ_{j∈N_i}`` runs over ordered pairs, so each unordered adjacent pair
  counts twice in U2-U5, as written in eq. 7, 9, 11, 12.
- Distances ``d`` (eq. 8) are from a candidate's end points to the *infinite*
  projected reference line of its side, in pixels.
- ``θ_i`` (eq. 10) is the acute angle (radians, [0, π/2]) between candidate
  and reference, so the paper's optimum "0° or 180°" is ``θ0 = 0``.
- U5 (eq. 12): ``D_ij`` is the distance (px) from the intersection of the two
  candidate lines to the nearest Harris corner, capped at
  ``corner_max_distance_px`` (no corner nearby, or near-parallel lines whose
  intersection is meaningless, give the cap).  The paper weights it by
  ``cos λ_ij`` with λ "the angle between the edges at the corner" and wants
  to favour *right-angle* corners; read literally cos 90° = 0 would switch
  the term off exactly there, so λ is taken as the corner angle's deviation
  from 90°, i.e. the weight is ``|sin(angle between the lines)|``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "MRFOptions",
    "GroupingProblem",
    "length_term",
    "proximity_term",
    "orientation_term",
    "rectangularity_term",
    "corner_term",
    "build_problem",
]

TERMS = ("length", "proximity", "orientation", "rectangularity", "corner")


@dataclass(frozen=True)
class MRFOptions:
    """Weights and constants of the energy (Marcato & Dal Poz, eq. 6-13 and §3).

    Attributes
    ----------
    w_length, w_proximity, w_orientation, w_rectangularity, w_corner : float, default 0.2
        α1..α5 of eq. 13; Marcato & Dal Poz §3 uses equal weights 0.2 (summing to 1).
    beta : float, default 20
        Shape of the orientation sigmoid, eq. 10 (Marcato & Dal Poz §3), θ in radians.
    theta0_deg : float, default 0
        Optimum of θ = θ_i + θ_j (degrees), eq. 10.
    corner_max_distance_px : float, default 10
        Cap of D_ij in U5 (px); ours, see the module notes.
    """

    section = "mrf"

    w_length: float = 0.2
    w_proximity: float = 0.2
    w_orientation: float = 0.2
    w_rectangularity: float = 0.2
    w_corner: float = 0.2
    beta: float = 20.0
    theta0_deg: float = 0.0
    corner_max_distance_px: float = 10.0

    def __post_init__(self) -> None:
        for name in ("w_length", "w_proximity", "w_orientation", "w_rectangularity", "w_corner"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise ValueError(f"mrf.{name} must be a finite weight >= 0, got {getattr(self, name)!r}")
        if not self.beta > 0:
            raise ValueError(f"mrf.beta must be > 0, got {self.beta!r}")
        if not self.corner_max_distance_px > 0:
            raise ValueError(f"mrf.corner_max_distance_px must be > 0, got {self.corner_max_distance_px!r}")

    @property
    def weights(self) -> np.ndarray:
        return np.array([self.w_length, self.w_proximity, self.w_orientation, self.w_rectangularity, self.w_corner])


# ----------------------------------------------------------------- geometry
def _direction(lines: np.ndarray) -> np.ndarray:
    """Unit directions (K, 2) of lines (K, 2, 2)."""
    d = lines[:, 1] - lines[:, 0]
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def _end_distances(lines: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Distances (K, 2) of the end points of lines (K, 2, 2) to the infinite reference line (2, 2)."""
    u = _direction(reference[None])[0]
    normal = np.array([-u[1], u[0]])
    return np.abs((lines - reference[0]) @ normal)


def _acute_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Acute angle (radians, [0, π/2]) between directions a (K, 2) and b (L, 2), shape (K, L)."""
    cos = np.abs(a @ b.T)
    return np.arccos(np.clip(cos, 0.0, 1.0))


# -------------------------------------------------------------------- terms
def length_term(reference: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """U1 per candidate (eq. 6): ``L_ref / L_i``, shape (K,); long candidates score low."""
    l_ref = np.linalg.norm(reference[1] - reference[0])
    l_cand = np.linalg.norm(candidates[:, 1] - candidates[:, 0], axis=1)
    return l_ref / np.maximum(l_cand, 1e-9)


def proximity_term(ref_i: np.ndarray, cand_i: np.ndarray, ref_j: np.ndarray, cand_j: np.ndarray) -> np.ndarray:
    """P(i, j) of eq. 8, shape (K_i, K_j): half the sum of the four end-point distances (px)."""
    di = _end_distances(cand_i, ref_i).sum(axis=1)
    dj = _end_distances(cand_j, ref_j).sum(axis=1)
    return 0.5 * (di[:, None] + dj[None, :])


def orientation_term(ref_i: np.ndarray, cand_i: np.ndarray, ref_j: np.ndarray, cand_j: np.ndarray,
                     beta: float = 20.0, theta0: float = 0.0) -> np.ndarray:
    """s_θ of eq. 10, shape (K_i, K_j), with θ = θ_i + θ_j in radians; in [0, 1)."""
    ti = _acute_angle(_direction(cand_i), _direction(ref_i[None]))[:, 0]
    tj = _acute_angle(_direction(cand_j), _direction(ref_j[None]))[:, 0]
    theta = ti[:, None] + tj[None, :]
    return 2.0 / (1.0 + np.exp(-beta * (theta - theta0) ** 2)) - 1.0


def rectangularity_term(cand_i: np.ndarray, cand_j: np.ndarray) -> np.ndarray:
    """|sin 2α_ij| of eq. 11, shape (K_i, K_j): zero for parallel or orthogonal pairs."""
    di, dj = _direction(cand_i), _direction(cand_j)
    cos = di @ dj.T
    sin = di[:, None, 0] * dj[None, :, 1] - di[:, None, 1] * dj[None, :, 0]
    return np.abs(2.0 * sin * cos)


def _intersections(cand_i: np.ndarray, cand_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intersections (K_i, K_j, 2) of the infinite lines and |sin| of their angle (K_i, K_j)."""
    p, r = cand_i[:, 0], cand_i[:, 1] - cand_i[:, 0]
    q, s = cand_j[:, 0], cand_j[:, 1] - cand_j[:, 0]
    cross = r[:, None, 0] * s[None, :, 1] - r[:, None, 1] * s[None, :, 0]
    qp = q[None, :, :] - p[:, None, :]
    num = qp[..., 0] * s[None, :, 1] - qp[..., 1] * s[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / cross
        x = p[:, None, :] + t[..., None] * r[:, None, :]
    norms = np.linalg.norm(r, axis=1)[:, None] * np.linalg.norm(s, axis=1)[None, :]
    return x, np.abs(cross) / np.maximum(norms, 1e-12)


def corner_term(cand_i: np.ndarray, cand_j: np.ndarray, corners: np.ndarray | cKDTree | None,
                max_distance: float = 10.0) -> np.ndarray:
    """U5 pair values ``D_ij · |sin(angle)|`` of eq. 12 (see module notes), shape (K_i, K_j).

    ``corners`` are Harris corners (C, 2) (col, row) or a KD-tree over them;
    D_ij is capped at ``max_distance`` px.
    """
    x, sin = _intersections(cand_i, cand_j)
    dist = np.full(sin.shape, float(max_distance))
    tree = corners if isinstance(corners, cKDTree) else (
        cKDTree(np.asarray(corners, float).reshape(-1, 2)) if corners is not None and len(corners) else None)
    ok = np.isfinite(x).all(axis=-1) & (sin > np.sin(np.radians(5.0)))
    if tree is not None and tree.n > 0 and ok.any():
        d, _ = tree.query(x[ok], distance_upper_bound=max_distance)
        dist[ok] = np.minimum(d, max_distance)
    return dist * sin


# ------------------------------------------------------------------ problem
@dataclass(frozen=True)
class GroupingProblem:
    """The energy of one roof as lookup tables (built by :func:`build_problem`).

    Attributes
    ----------
    n_candidates : ndarray of shape (M,) int
        Candidates per side/ridge.
    unary : list of ndarray (K_s,)
        Weighted unary energy α1·U1 per candidate of each side.
    pairs : ndarray of shape (P, 2) int
        Adjacent sides (s, t), s < t.
    pair_tables : list of ndarray (K_s, K_t)
        Weighted pairwise energy of each adjacent pair (both orders summed).
    terms : dict of str to list of ndarray
        Unweighted term values, for reporting: 'length' per side (K_s,), the
        others per pair (K_s, K_t), each already counting both orders.
    """

    n_candidates: np.ndarray
    unary: list
    pairs: np.ndarray
    pair_tables: list
    terms: dict

    def __post_init__(self) -> None:
        k = np.asarray(self.n_candidates, int)
        object.__setattr__(self, "_u_off", np.concatenate([[0], np.cumsum(k)]))
        object.__setattr__(self, "_u_flat", np.concatenate([np.asarray(u, float) for u in self.unary])
                           if len(self.unary) else np.zeros(0))
        sizes = [t.size for t in self.pair_tables]
        object.__setattr__(self, "_p_off", np.concatenate([[0], np.cumsum(sizes)]).astype(int))
        object.__setattr__(self, "_p_flat", np.concatenate([t.ravel() for t in self.pair_tables])
                           if sizes else np.zeros(0))

    @property
    def n_sides(self) -> int:
        return len(self.n_candidates)

    @property
    def n_configurations(self) -> float:
        return float(np.prod(np.asarray(self.n_candidates, float)))

    def energy(self, choice: np.ndarray) -> np.ndarray | float:
        """U for one labelling (M,) -> float, or a population (N, M) -> (N,)."""
        c = np.asarray(choice, int)
        single = c.ndim == 1
        c = np.atleast_2d(c)
        u = self._u_flat[self._u_off[:-1][None, :] + c].sum(axis=1)
        if len(self.pairs):
            s, t = self.pairs[:, 0], self.pairs[:, 1]
            kt = np.asarray(self.n_candidates)[t]
            u = u + self._p_flat[self._p_off[:-1][None, :] + c[:, s] * kt[None, :] + c[:, t]].sum(axis=1)
        return float(u[0]) if single else u

    def term_values(self, choice: np.ndarray) -> dict[str, float]:
        """Unweighted U1..U5 of one labelling (M,)."""
        c = np.asarray(choice, int)
        out = {"length": float(sum(u[c[s]] for s, u in enumerate(self.terms["length"])))}
        for name in TERMS[1:]:
            out[name] = float(sum(tab[c[s], c[t]] for (s, t), tab in zip(self.pairs, self.terms[name])))
        return out


def build_problem(references: np.ndarray, candidates, pairs: np.ndarray, corners: np.ndarray | None = None,
                  options: MRFOptions | None = None, *, penalties=None) -> GroupingProblem:
    """Precompute the energy tables of one roof.

    Parameters
    ----------
    references : ndarray of shape (M, 2, 2)
        Projected reference line of each side/ridge, pixel (col, row).
    candidates : sequence of M ndarrays (K_s, 2, 2)
        Candidate image lines per side, K_s >= 1.
    pairs : ndarray of shape (P, 2) int
        Adjacent sides (the MRF neighbourhood), e.g. ``RoofTopology.pairs``.
    corners : ndarray of shape (C, 2), optional
        Harris corners (col, row); none makes U5 a constant.
    options : MRFOptions, optional
    penalties : sequence of M ndarrays (K_s,), optional
        Extra unary energy per candidate, added as is (not one of seed
        000's terms: e.g. the wall-foot penalty of
        :class:`~rooftrace.refine.building.RefineOptions`).

    Returns
    -------
    GroupingProblem

    Examples
    --------
    >>> import numpy as np
    >>> refs = np.array([[[0, 0], [10, 0]], [[10, 0], [10, 10]]], float)
    >>> cands = [refs[:1] + [0, 1], np.concatenate([refs[1:], refs[1:] + [3, 0]])]
    >>> p = build_problem(refs, cands, np.array([[0, 1]]))
    >>> p.n_candidates.tolist(), p.energy([0, 0]) < p.energy([0, 1])
    ([1, 2], True)
    """
    options = options or MRFOptions()
    references = np.asarray(references, float).reshape(-1, 2, 2)
    cands = [np.asarray(c, float).reshape(-1, 2, 2) for c in candidates]
    if len(cands) != len(references):
        raise ValueError(f"candidates: {len(cands)} sets for {len(references)} reference lines")
    if any(len(c) == 0 for c in cands):
        raise ValueError("candidates: every side needs at least one candidate (use its projected line)")
    pairs = np.asarray(pairs, int).reshape(-1, 2)
    if len(pairs) and (pairs.min() < 0 or pairs.max() >= len(cands) or (pairs[:, 0] == pairs[:, 1]).any()):
        raise ValueError("pairs: indices must name two different sides")
    pairs = np.sort(pairs, axis=1)
    w = options.weights
    tree = cKDTree(np.asarray(corners, float).reshape(-1, 2)) if corners is not None and len(corners) else None
    theta0 = np.radians(options.theta0_deg)
    terms: dict[str, list] = {name: [] for name in TERMS}
    terms["length"] = [length_term(r, c) for r, c in zip(references, cands)]
    tables = []
    for s, t in pairs:
        # factor 2: Σ_i Σ_{j∈N_i} visits the pair once from each side
        vals = {
            "proximity": 2 * proximity_term(references[s], cands[s], references[t], cands[t]),
            "orientation": 2 * orientation_term(references[s], cands[s], references[t], cands[t],
                                                options.beta, theta0),
            "rectangularity": 2 * rectangularity_term(cands[s], cands[t]),
            "corner": 2 * corner_term(cands[s], cands[t], tree, options.corner_max_distance_px),
        }
        for name, v in vals.items():
            terms[name].append(v)
        tables.append(sum(w[k] * vals[name] for k, name in enumerate(TERMS) if k > 0))
    unary = [w[0] * u for u in terms["length"]]
    if penalties is not None:
        if len(penalties) != len(cands) or any(np.shape(p) != (len(c),) for p, c in zip(penalties, cands)):
            raise ValueError("penalties: one array (K_s,) per side is needed")
        unary = [u + np.asarray(p, float) for u, p in zip(unary, penalties)]
    return GroupingProblem(np.array([len(c) for c in cands], int), unary, pairs, tables, terms)
