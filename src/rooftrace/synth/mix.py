"""The default building mix of a synthetic scene: one building (or a terraced row) per 30 m slot.

Random choices come from ``numpy.random.default_rng([seed, 7])``, so the mix
depends only on the seed and the scene's size and origin.  Re-exported by
:mod:`rooftrace.synth.scene`.
"""

from __future__ import annotations

import math

import numpy as np
import shapely

from rooftrace.synth.buildings import Building

__all__ = ["default_buildings", "ROOF_PALETTE", "WALL_PALETTE"]

#: roof albedos (RGB): dark tiles, slate, red tiles, light gravel, white membrane, brown, copper green
ROOF_PALETTE = (
    (0.16, 0.15, 0.16), (0.24, 0.25, 0.29), (0.78, 0.36, 0.24), (0.62, 0.61, 0.57), (0.82, 0.82, 0.80),
    (0.45, 0.30, 0.22), (0.40, 0.58, 0.50),
)
WALL_PALETTE = ((0.85, 0.82, 0.74), (0.70, 0.55, 0.45), (0.90, 0.90, 0.88), (0.62, 0.60, 0.58))


def _fits(b: Building, slot: tuple[float, float, float, float]) -> bool:
    return shapely.box(*slot).contains(b.roof_outline)


def _template(i: int, bid: int, c: np.ndarray, rng: np.random.Generator, ang: float) -> list[Building]:
    """The i-th building of the default mix centred at ``c`` (fits a 22 m square)."""
    u = rng.uniform
    e = float(u(5.5, 7.0))
    kinds = [
        lambda: [Building.l_shape(bid, c, u(16, 19), 8.0, u(5, 7), angle_deg=ang, kind="gable", eave_height=e,
                                  ridge_height=e + 3.5, overhang=0.5, ridge_cap=True)],
        lambda: [Building.rectangle(bid, c, u(13, 17), u(8, 10), angle_deg=ang, kind="hip", eave_height=e,
                                    ridge_height=e + 3.2, overhang=0.6)],
        lambda: [Building.courtyard(bid, c, u(19, 21), u(17, 19), 6.5, angle_deg=ang, eave_height=u(9, 11))],
        lambda: [Building.round(bid, c, u(6, 8), eave_height=u(7, 12))],
        lambda: Building.terrace(bid, c, [5.0, 5.0, 5.5, 4.5], 9.0, angle_deg=ang, eave_heights=[6.0, 6.0, 6.6, 5.6],
                                 ridge_heights=[9.8, 9.8, 10.6, 9.2], overhang=0.4),
        lambda: [Building.rectangle(bid, c, u(13, 16), 9.0, angle_deg=ang, kind="gable", eave_height=e,
                                    ridge_height=e + 4.0, overhang=0.5).with_dormers([-3.2, 3.2])],
        lambda: [Building.rectangle(bid, c, u(10, 14), u(7, 9), angle_deg=ang, kind="shed", eave_height=e - 1.5,
                                    ridge_height=e + 0.5, overhang=0.4)],
        lambda: [Building.t_shape(bid, c, u(17, 20), 8.0, u(5, 7), angle_deg=ang, kind="hip", eave_height=e,
                                  ridge_height=e + 3.2, overhang=0.5)],
        lambda: [Building.stadium(bid, c, u(18, 21), u(8, 10), angle_deg=ang, eave_height=u(6, 9))],
        lambda: [Building.rectangle(bid, c, u(12, 15), u(8, 10), angle_deg=ang, kind="split", eave_height=e,
                                    ridge_height=e + 3.5, overhang=0.4, ridge_cap=True)],
        lambda: [Building.rectangle(bid, c, u(11, 13), u(10, 12), angle_deg=ang, kind="flat", eave_height=u(24, 30),
                                    overhang=0.0)],
        lambda: [Building.u_shape(bid, c, u(19, 21), 7.5, u(5, 6), angle_deg=ang, kind="gable", eave_height=e,
                                  ridge_height=e + 3.2, overhang=0.5, ridge_cap=True)],
        lambda: [_annexed(bid, c, ang, e, u)],
        lambda: [_arc(bid, c, u)],
        lambda: [Building.rectangle(bid, c, 10.0, 10.0, angle_deg=ang, kind="pyramid", eave_height=e,
                                    ridge_height=e + 3.0, overhang=0.5, ridge_cap=True)],
        lambda: [Building.l_shape(bid, c, u(16, 19), 8.0, u(5, 7), angle_deg=ang, kind="hip", eave_height=e,
                                  ridge_height=e + 3.2, overhang=0.5)],
    ]
    if i < len(kinds):
        return kinds[i]()
    kind = ("gable", "hip", "flat", "gable")[i % 4]
    return [Building.rectangle(bid, c, u(10, 16), u(7, 10), angle_deg=ang, kind=kind, eave_height=e,
                               ridge_height=e + u(2.5, 4.0), overhang=0.0 if kind == "flat" else 0.5,
                               ridge_cap=bool(rng.random() < 0.4))]


def _annexed(bid, c, ang, e, u):
    b = Building.rectangle(bid, c, 14.0, 9.0, angle_deg=ang, kind="hip", eave_height=e, ridge_height=e + 3.0,
                           overhang=0.5)
    a = math.radians(ang)
    uu, vv = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
    return b.with_annex(c + 2.0 * uu - (4.5 + 2.5) * vv, 7.0, 5.0, angle_deg=ang, eave_height=u(2.8, 3.4),
                        wall_side="+v")


def _arc(bid, c, u):
    radius, sweep = 55.0, 20.0
    start = 250.0  # the arc's middle points south-east of its centre -> a gentle curve
    mid = math.radians(start + sweep / 2)
    center = c - radius * np.array([math.cos(mid), math.sin(mid)])
    return Building.arc(bid, center, radius, 8.5, sweep, start_deg=start, eave_height=u(7, 10))


def default_buildings(seed: int = 1, size: float = 160.0, origin: tuple[float, float] = (85000.0, 447000.0),
                      ) -> list[Building]:
    """The default building mix on a grid of 30 m slots (five by five for a 160 m scene).

    The first slots hold, in this order: a gable L with ridge caps, a hip
    rectangle, a flat courtyard block (hole), a round building, four
    terraced houses sharing walls, a gable with dormers, a shed, a hip T,
    a stadium (semicircular ends), a split-level roof (step at the ridge),
    a 24-30 m tower (occludes its neighbours), a gable U, a hip with a lower
    annex, a gently curved arc, a pyramid and a hip L; further slots get
    simple houses, one in three left open.  Small scenes get the first ones.

    Returns
    -------
    list of Building
        Ids from 1, in map coordinates; ``base_height`` unset.
    """
    rng = np.random.default_rng([int(seed), 7])
    slot = 30.0
    n = max(1, int(size // slot))
    margin = (size - n * slot) / 2.0
    x0, y0 = origin[0] + margin, origin[1] + margin
    out: list[Building] = []
    bid = 1
    order = [(r, c) for r in range(n) for c in range(n)]
    for i, (r, col) in enumerate(order):
        if i >= 16 and (i - 16) % 3 == 2:
            continue
        box = (max(x0 + col * slot + 3.0, origin[0] + 1.0), max(y0 + r * slot + 3.0, origin[1] + 1.0),
               min(x0 + (col + 1) * slot - 3.0, origin[0] + size - 1.0),
               min(y0 + (r + 1) * slot - 3.0, origin[1] + size - 1.0))
        c = np.array([(box[0] + box[2]) / 2, (box[1] + box[3]) / 2]) + rng.uniform(-1.0, 1.0, 2)
        ang = float(rng.choice([0.0, 0.0, rng.uniform(-25, 25), 90.0 + rng.uniform(-10, 10)]))
        state = rng.bit_generator.state
        made = _template(i, bid, c, rng, ang)
        if not all(_fits(b, box) for b in made):
            rng.bit_generator.state = state
            made = _template(i, bid, c, rng, 0.0)
        if not all(_fits(b, box) for b in made):  # a small scene: a small house
            c = np.array([(box[0] + box[2]) / 2, (box[1] + box[3]) / 2])
            made = [Building.rectangle(bid, c, min(10.0, 0.6 * (box[2] - box[0])), min(7.0, 0.45 * (box[3] - box[1])),
                                       kind="gable", eave_height=5.0, ridge_height=8.0, overhang=0.4, ridge_cap=True)]
        if not all(_fits(b, box) for b in made):
            continue
        for b in made:
            b.roof_colour = tuple(ROOF_PALETTE[int(rng.integers(len(ROOF_PALETTE)))])
            b.wall_colour = tuple(WALL_PALETTE[int(rng.integers(len(WALL_PALETTE)))])
        out.extend(made)
        bid += len(made)
    return out
