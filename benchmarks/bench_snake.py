"""Benchmark of ``rooftrace snake`` (issue 8): PoLiS of snake outlines from perturbed seeds, and time per building.

Scenes come from the simulator (``rooftrace.synth``): isolated rectangles and
L-shapes with flat, gable and hip roofs (overhangs included, sloping terrain,
ALS ray casting, rendered frame image with shading), seeds = the true roof
corners moved by up to ``--perturb`` m in a random direction.  A second set
shows the paper's known weakness: buildings a metre or two from a neighbour,
and roofs under overhanging tree crowns (``--weak``).

    .venv/bin/python benchmarks/bench_snake.py [--scenes 2] [--density 8] [--perturb 1.0] [--weak]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import shapely

from rooftrace.evaluate.metrics import polis
from rooftrace.snake import SnakeOptions, snake_outline
from rooftrace.synth import Building, SceneOptions, simulate_scene

ORIGIN = (85000.0, 447000.0)


def isolated_buildings(seed: int, n_side: int = 4, slot: float = 30.0) -> list[Building]:
    """One building per 30 m slot, well apart: rectangles and Ls, flat / gable / hip, random angles."""
    rng = np.random.default_rng([seed, 8])
    out = []
    for i in range(n_side * n_side):
        r, c = divmod(i, n_side)
        centre = (ORIGIN[0] + 15.0 + slot * (c + 0.5), ORIGIN[1] + 15.0 + slot * (r + 0.5))
        kind = ["flat", "gable", "hip"][i % 3]
        angle = float(rng.uniform(-40, 40))
        eave = float(rng.uniform(4, 9))
        ridge = eave + (0.0 if kind == "flat" else float(rng.uniform(2, 4)))
        if i % 2 == 0:
            b = Building.rectangle(i + 1, centre, float(rng.uniform(10, 18)), float(rng.uniform(7, 10)),
                                   angle_deg=angle, kind=kind, eave_height=eave, ridge_height=ridge, overhang=0.4)
        else:
            b = Building.l_shape(i + 1, centre, float(rng.uniform(12, 16)), float(rng.uniform(6, 8)),
                                 float(rng.uniform(4, 7)), angle_deg=angle, kind=kind, eave_height=eave,
                                 ridge_height=ridge, overhang=0.4)
        out.append(b)
    return out


def weak_buildings(seed: int) -> list[Building]:
    """Pairs of flat/gable houses 1-2 m apart with similar roof colours (trees come from the scene)."""
    rng = np.random.default_rng([seed, 9])
    out = []
    for i in range(4):
        cx, cy = ORIGIN[0] + 30.0 + 30.0 * (i % 2) * 2, ORIGIN[1] + 30.0 + 60.0 * (i // 2)
        gap = float(rng.uniform(1.0, 2.0))
        kind = "flat" if i % 2 == 0 else "gable"
        half = 4.0 + 0.3 + gap / 2  # half width + overhang + half the gap between the roofs
        for k, dx in enumerate((-half, half)):
            out.append(Building.rectangle(2 * i + k + 1, (cx + dx, cy), 10.0, 8.0, angle_deg=90.0, kind=kind,
                                          eave_height=6.0 + k, ridge_height=9.0 + k, overhang=0.3,
                                          roof_colour=(0.55, 0.35, 0.3)))
    return out


def corners(poly) -> np.ndarray:
    """Open ring (n, 3) of the plan corners of a truth roof outline.

    Repeated vertices and vertices collinear in plan go (a gable end's apex
    is a vertex of the 3D outline but no corner an operator would click).
    """
    ring = np.asarray(poly.exterior.coords)[:-1]
    ring = ring[np.linalg.norm(ring[:, :2] - np.roll(ring[:, :2], 1, axis=0), axis=1) > 1e-6]
    while True:
        a, c = np.roll(ring[:, :2], 1, axis=0), np.roll(ring[:, :2], -1, axis=0)
        u, w = ring[:, :2] - a, c - ring[:, :2]
        cross = np.abs(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])
        straight = cross <= 1e-3 * np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1)
        if not straight.any():
            return ring
        ring = np.delete(ring, np.flatnonzero(straight)[0], axis=0)


def run_scene(opts: SceneOptions, buildings, perturb: float, rng, snake_opts: SnakeOptions, tag: str = ""):
    scene = simulate_scene(opts, buildings=buildings)
    grey = scene.image.astype(float).mean(axis=0) / 255.0
    truth = scene.truth["roof_outlines"]
    veg = scene.cloud.xyz[scene.cloud.fields["truth_class"] == 5, :2]
    rows = []
    for geom, bid in zip(truth.geometries, truth.attributes["building_id"]):
        t = corners(geom)
        ang = rng.uniform(0, 2 * np.pi, len(t))
        r = perturb * np.sqrt(rng.uniform(0, 1, len(t)))
        seeds = t[:, :2] + np.column_stack([r * np.cos(ang), r * np.sin(ang)])
        t0 = time.perf_counter()
        res = snake_outline(seeds, grey, scene.camera, scene.cloud.xyz, snake_opts)
        dt = time.perf_counter() - t0
        truth_poly = geom  # the full 3D outline, gable apexes included
        ring2d = shapely.Polygon(t[:, :2])
        others = [g for g, b in zip(truth.geometries, truth.attributes["building_id"]) if b != bid]
        gap = min((shapely.distance(ring2d, shapely.Polygon(np.asarray(g.exterior.coords)[:, :2])) for g in others),
                  default=np.inf)
        near_veg = int(shapely.contains_xy(ring2d.buffer(1.5), veg[:, 0], veg[:, 1]).sum()) if len(veg) else 0
        rows.append({
            "tag": tag, "id": int(bid), "n": len(t),
            "kind": next(b.kind for b in scene.buildings if b.building_id == bid),
            "polis_seeds": polis(shapely.Polygon(seeds), ring2d), "polis": polis(shapely.Polygon(res.xyz), truth_poly),
            "polis3d": polis(shapely.Polygon(res.xyz), truth_poly, dim=3),
            "dz": float(np.abs(res.xyz[:, 2] - t[:, 2]).mean()), "time": dt, "iters": res.iterations,
            "gap": gap, "veg": near_veg, "draw": _drawing(grey, scene.camera, t, seeds, res.xyz),
        })
    return rows


def _drawing(grey, camera, truth, seeds, result, pad: int = 20):
    """Image crop around a building and the three rings in crop pixels, for the figure."""
    tc = camera.project(truth)
    sc = camera.project(np.column_stack([seeds, truth[:, 2]]))
    rc = camera.project(result)
    c0, r0 = np.floor(np.vstack([tc, sc, rc]).min(axis=0)).astype(int) - pad
    c1, r1 = np.ceil(np.vstack([tc, sc, rc]).max(axis=0)).astype(int) + pad
    c0, r0 = max(c0, 0), max(r0, 0)
    off = np.array([c0, r0])
    return grey[r0:r1, c0:c1], tc - off, sc - off, rc - off


def figure(rows, path: str) -> None:
    """Three panels: the median isolated case, the worst neighbour case, the worst tree case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    iso = sorted((r for r in rows if r["tag"] == "isolated"), key=lambda r: r["polis"])
    picks = [("isolated", iso[len(iso) // 2] if iso else None)]
    for name, f in (("neighbour 1-2 m away", lambda r: r["tag"] == "weak" and r["veg"] == 0),
                    ("tree over the roof edge", lambda r: r["tag"] == "weak" and r["veg"] >= 20)):
        sel = [r for r in rows if f(r)]
        picks.append((name, max(sel, key=lambda r: r["polis"]) if sel else None))
    picks = [(n, r) for n, r in picks if r is not None]
    fig, axes = plt.subplots(1, len(picks), figsize=(3.3 * len(picks), 3.3))
    for ax, (name, r) in zip(np.atleast_1d(axes), picks):
        img, tc, sc, rc = r["draw"]
        ax.imshow(img, cmap="gray", vmin=0, vmax=1)
        for ring, style, label in ((tc, "g-", "truth"), (sc, "y--", "seeds"), (rc, "r-", "snake")):
            q = np.vstack([ring, ring[:1]])
            ax.plot(q[:, 0], q[:, 1], style, lw=1.2, label=label)
        ax.set_title(f"{name}\nPoLiS {r['polis']:.2f} m", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=2)
    ap.add_argument("--density", type=float, default=8.0)
    ap.add_argument("--gsd", type=float, default=0.2)
    ap.add_argument("--perturb", type=float, default=1.0)
    ap.add_argument("--weak", action="store_true", help="also run the adjacent-buildings / trees scenes")
    ap.add_argument("--grid", type=int, default=SnakeOptions.grid)
    ap.add_argument("--fine-grid", type=int, default=SnakeOptions.fine_grid)
    ap.add_argument("--figure", help="write a PNG of one isolated and the worst weak cases")
    ap.add_argument("--w-height", type=float, default=SnakeOptions.w_height,
                    help="0 gives the paper's image-only external energy")
    args = ap.parse_args()
    rng = np.random.default_rng(2024)
    sopt = SnakeOptions(grid=args.grid, fine_grid=args.fine_grid, w_height=args.w_height)
    # warm the numba caches so times are per building, not per compile
    warm = simulate_scene(SceneOptions(seed=99, size=40, density=4, gsd=args.gsd, trees=False))
    t = corners(warm.truth["roof_outlines"].geometries[0])
    snake_outline(t[:, :2], warm.image.astype(float).mean(axis=0) / 255, warm.camera, warm.cloud.xyz, sopt)
    rows = []
    for s in range(args.scenes):
        opts = SceneOptions(seed=s + 1, size=150.0, density=args.density, gsd=args.gsd, trees=False, origin=ORIGIN)
        rows += run_scene(opts, isolated_buildings(s + 1), args.perturb, rng, sopt, "isolated")
    if args.weak:
        for s in range(args.scenes):
            opts = SceneOptions(seed=s + 11, size=150.0, density=args.density, gsd=args.gsd, trees=False,
                                origin=ORIGIN)
            rows += run_scene(opts, weak_buildings(s + 1), args.perturb, rng, sopt, "weak")
            opts = SceneOptions(seed=s + 21, size=150.0, density=args.density, gsd=args.gsd, trees=True,
                                tree_density=40.0, origin=ORIGIN)
            rows += [r for r in run_scene(opts, isolated_buildings(s + 21), args.perturb, rng, sopt, "weak")
                     if r["veg"] >= 20]  # crowns reaching over the roof edge
    print(f"density {args.density} pts/m2, GSD {args.gsd} m, seeds moved <= {args.perturb} m, "
          f"grid {args.grid}/{args.fine_grid}, w_height {args.w_height}")
    print("| set | shape | buildings | PoLiS seeds (m) | PoLiS snake mean / max (m) | PoLiS 3D (m) | mean abs dZ (m) "
          "| time mean / max (s) |")
    print("|---|---|---|---|---|---|---|---|")
    groups = [("isolated", "rectangle", lambda r: r["tag"] == "isolated" and r["kind"] != "l_shape"),
              ("isolated", "L", lambda r: r["tag"] == "isolated" and r["kind"] == "l_shape"),
              ("weak", "neighbour <= 2 m", lambda r: r["tag"] == "weak" and r["gap"] <= 2.0 and r["veg"] == 0),
              ("weak", "tree over roof edge", lambda r: r["tag"] == "weak" and r["veg"] >= 20)]
    for tag, name, f in groups:
        sel = [r for r in rows if f(r)]
        if not sel:
            continue
        p = np.array([r["polis"] for r in sel])
        tm = np.array([r["time"] for r in sel])
        print(f"| {tag} | {name} | {len(sel)} | {np.mean([r['polis_seeds'] for r in sel]):.3f} | "
              f"{p.mean():.3f} / {p.max():.3f} | {np.mean([r['polis3d'] for r in sel]):.3f} | "
              f"{np.mean([r['dz'] for r in sel]):.3f} | {tm.mean():.2f} / {tm.max():.2f} |")
    if args.figure:
        figure(rows, args.figure)
    for r in rows:
        print(f"  {r['tag']:8s} id {r['id']:3d} {r['kind']:9s} n={r['n']} seeds {r['polis_seeds']:.2f} -> "
              f"{r['polis']:.3f} m, dz {r['dz']:.2f}, {r['time']:.2f} s, {r['iters']} it, gap {r['gap']:.1f}, "
              f"veg {r['veg']}")


if __name__ == "__main__":
    main()
