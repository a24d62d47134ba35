"""City blocks: terraced houses around inner courtyards, blocks joined by low garages (``--scene blocks``).

Central-city LiDAR shows what the default mix of detached houses does not:
closed blocks 60-280 m across whose houses share walls and differ in height,
trees in the courtyards, and low buildings (sheds against the courtyard
walls, garage rows across the streets) that join neighbouring blocks into
one connected cloud of tens of thousands of points.  Every house, shed and
garage row is a building of its own in the truth.

Random choices come from ``numpy.random.default_rng([seed, 11])``; the
layout depends only on the seed and the scene's size and origin.
"""

from __future__ import annotations

import numpy as np

from rooftrace.synth.buildings import Building
from rooftrace.synth.mix import ROOF_PALETTE, WALL_PALETTE

__all__ = ["block_buildings", "BLOCK_SIZES"]

#: smallest and largest side of a block (m)
BLOCK_SIZES = (60.0, 280.0)
_STREET = (10.0, 14.0)  # street width between blocks (m)
_MARGIN = 4.0  # free edge of the scene (m)


def _sides(total: float, rng: np.random.Generator) -> list[tuple[float, float]]:
    """(start, length) of the blocks along one axis of ``total`` metres, streets between them."""
    lo, hi = BLOCK_SIZES
    out, at = [], 0.0
    while total - at >= lo:
        rest = total - at
        length = float(rng.uniform(lo, min(hi, rest)))
        street = float(rng.uniform(*_STREET))
        if rest - length - street < lo:  # no room for another block: this one takes the rest
            length = min(rest, hi)
        out.append((at, length))
        at += length + street
    return out


def _houses(bid: int, x0: float, y0: float, width: float, height: float, depth: float,
            rng: np.random.Generator) -> list[Building]:
    """Terraced houses along the four sides of a block (south and north rows run the full width)."""
    u = rng.uniform
    rows = [  # (start, run length, fixed coordinate of the row's centre line, along x?)
        (x0, width, y0 + depth / 2, True),
        (x0, width, y0 + height - depth / 2, True),
        (y0 + depth, height - 2 * depth, x0 + depth / 2, False),
        (y0 + depth, height - 2 * depth, x0 + width - depth / 2, False),
    ]
    out = []
    for start, run, fixed, along_x in rows:
        at = 0.0
        while run - at > 1e-6:
            w = float(u(5.0, 10.0))
            if run - at - w < 5.0:
                w = run - at  # the last house takes the rest
            mid = start + at + w / 2
            centre = (mid, fixed) if along_x else (fixed, mid)
            eave = float(u(6.0, 15.0))
            kind = "gable" if rng.random() < 0.6 else "flat"
            out.append(Building.rectangle(bid + len(out), centre, w, depth, angle_deg=0.0 if along_x else 90.0,
                                          kind=kind, eave_height=eave, ridge_height=eave + float(u(3.0, 5.0)),
                                          overhang_sides=(0.0, 0.0, 0.0, 0.0)))
            out[-1].kind = "terrace"
            at += w
    return out


def _sheds(bid: int, x0: float, y0: float, width: float, height: float, depth: float,
           rng: np.random.Generator) -> list[Building]:
    """Low flat sheds against the courtyard's south and north walls."""
    out = []
    inner = width - 2 * depth
    for side in (0, 1):
        for _ in range(int(rng.integers(1, 4))):
            w, d = float(rng.uniform(3.0, 6.0)), float(rng.uniform(2.5, 4.0))
            x = float(rng.uniform(x0 + depth + w / 2 + 1.0, x0 + depth + inner - w / 2 - 1.0))
            y = y0 + depth + d / 2 if side == 0 else y0 + height - depth - d / 2
            shed = Building.rectangle(bid + len(out), (x, y), w, d, kind="flat", eave_height=float(rng.uniform(2.2, 3.0)),
                                      overhang_sides=(0.0, 0.0, 0.0, 0.0))
            if any(shed.footprint.intersection(o.footprint).area > 0 for o in out):
                continue
            shed.kind = "shed"
            out.append(shed)
    return out


def block_buildings(seed: int = 1, size: float = 160.0, origin: tuple[float, float] = (85000.0, 447000.0),
                    ) -> list[Building]:
    """City blocks filling a square scene: terraced houses around courtyards, sheds, garage rows across streets.

    Blocks are 60-280 m across (:data:`BLOCK_SIZES`), 10-14 m streets apart;
    their houses (flat or gable, eaves 6-15 m, 5-10 m wide, rows 9-14 m
    deep) share walls.  One to three sheds (2.2-3 m high) stand against
    the south and north courtyard walls; a garage row 3 m wide and
    2.5-3 m high spans every street between two blocks, so all blocks of
    the scene touch through low buildings.  Trees come with the scene
    (``SceneOptions.trees``), on open ground: streets and courtyards.

    Parameters
    ----------
    seed : int
    size : float
        Side of the scene (m); at least 68 m for one block.
    origin : (float, float)
        South-west corner of the scene (m).

    Returns
    -------
    list of Building
        Ids from 1; ``kind`` is ``terrace``, ``shed`` or ``garage``.

    Examples
    --------
    >>> b = block_buildings(1, 150.0)
    >>> sorted({x.kind for x in b}), len(b) > 40
    (['garage', 'shed', 'terrace'], True)
    """
    rng = np.random.default_rng([int(seed), 11])
    span = size - 2 * _MARGIN
    xs, ys = _sides(span, rng), _sides(span, rng)
    ox, oy = origin[0] + _MARGIN, origin[1] + _MARGIN
    out: list[Building] = []
    for i, (sx, w) in enumerate(xs):
        for j, (sy, h) in enumerate(ys):
            depth = float(rng.uniform(9.0, min(14.0, (min(w, h) - 10.0) / 2)))
            x0, y0 = ox + sx, oy + sy
            out += _houses(len(out) + 1, x0, y0, w, h, depth, rng)
            out += _sheds(len(out) + 1, x0, y0, w, h, depth, rng)
            # garage rows to the east and north neighbours, across the street
            if i + 1 < len(xs):
                gap = xs[i + 1][0] - (sx + w)
                y = y0 + float(rng.uniform(depth, h - depth))
                out.append(Building.rectangle(len(out) + 1, (x0 + w + gap / 2, y), gap, 3.0, kind="flat",
                                              eave_height=float(rng.uniform(2.5, 3.0)),
                                              overhang_sides=(0.0, 0.0, 0.0, 0.0)))
                out[-1].kind = "garage"
            if j + 1 < len(ys):
                gap = ys[j + 1][0] - (sy + h)
                x = x0 + float(rng.uniform(depth, w - depth))
                out.append(Building.rectangle(len(out) + 1, (x, y0 + h + gap / 2), gap, 3.0, angle_deg=90.0,
                                              kind="flat", eave_height=float(rng.uniform(2.5, 3.0)),
                                              overhang_sides=(0.0, 0.0, 0.0, 0.0)))
                out[-1].kind = "garage"
    for b in out:
        b.roof_colour = tuple(ROOF_PALETTE[int(rng.integers(len(ROOF_PALETTE)))])
        b.wall_colour = tuple(WALL_PALETTE[int(rng.integers(len(WALL_PALETTE)))])
    return out
