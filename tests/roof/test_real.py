"""Roof structure on real clouds (skipped when ../shared/data is absent)."""

import functools

import numpy as np
import pytest
import shapely

from rooftrace.roof import faces_layer, ridges_layer, roof_structure
from tests.conftest import DELFT, IGN, need


@pytest.fixture(scope="module")
def delft_hip_roof():
    from rooftrace.io.points import read_points
    from rooftrace.io.vector import read_layer

    pc = read_points([need(DELFT / "ahn3_cropped_1.laz")], crs="EPSG:28992")
    b = pc.xyz[pc.fields["classification"] == 6]
    # BGT feature 77: a detached hip roof (checked in docs/images by eye).
    fp = shapely.force_2d(read_layer(need(DELFT / "bgt_pand.geojson")).geometries[77])
    outline = fp.buffer(0.5, join_style="mitre")
    return b[shapely.contains_xy(outline, b[:, 0], b[:, 1])], outline


def test_delft_hip_roof(delft_hip_roof):
    xyz, outline = delft_hip_roof
    roof = roof_structure(xyz, outline, building_id=77)
    assert roof.status == "ok"
    kinds = sorted(roof.ridge_kind)
    assert kinds.count("ridge") == 1 and kinds.count("hip") == 4
    # Four pitched planes of 40-50°, about 6-12 cm RMSE (tiles); a low lean-to
    # in the south corner may come as a fifth, flat plane.
    pitched = roof.slope_deg > 20
    assert pitched.sum() == 4 and np.all((roof.slope_deg[pitched] > 40) & (roof.slope_deg[pitched] < 50))
    # (the main planes: a flat block on the roof, a chimney's top, spans up to 0.5 m)
    assert np.all(roof.plane_sigma[~roof.plane_detail] < 0.15)
    # The ridge is horizontal and above every eave.
    (ridge,) = [g for g, k in zip(roof.ridges, roof.ridge_kind) if k == "ridge"]
    z = np.asarray(ridge.coords)[:, 2]
    assert abs(z[0] - z[1]) < 0.2 and z.min() > np.percentile(xyz[:, 2], 95) - 0.2
    # Faces tile the outline; the layers are well formed.
    assert shapely.union_all([shapely.force_2d(f) for f in roof.faces]).area == pytest.approx(outline.area, rel=1e-6)
    assert len(faces_layer([roof])) == len(roof.faces) and len(ridges_layer([roof])) == len(roof.ridges)


def test_ign_pitched_roof_without_outline():
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    from rooftrace.io.points import read_points

    pc = read_points([need(IGN / "test_data_77055_627760_LA93_IGN69.laz")])
    b = pc.xyz[pc.fields["classification"] == 6]
    ij = cKDTree(b[:, :2]).query_pairs(1.0, output_type="ndarray")
    _, comp = connected_components(coo_matrix((np.ones(len(ij)), (ij[:, 0], ij[:, 1])), shape=(len(b),) * 2), directed=False)
    found = 0
    for c in np.flatnonzero(np.bincount(comp) >= 2000):
        roof = roof_structure(b[comp == c])
        assert roof.status == "ok"
        pitched = (roof.slope_deg > 15) & (roof.plane_n * roof.spacing**2 > 10)
        if pitched.sum() >= 2:
            found += any(k in ("ridge", "hip", "valley") for k in roof.ridge_kind)
            assert shapely.union_all([shapely.force_2d(f) for f in roof.faces]).area == pytest.approx(roof.outline.area, rel=1e-6)
    assert found >= 1


@functools.lru_cache(maxsize=1)
def _delft_class6():
    """The AHN3 class-6 points of the first Delft tile and the BGT footprints (read once for the tests here)."""
    from rooftrace.io.points import read_points
    from rooftrace.io.vector import read_layer

    pc = read_points([need(DELFT / "ahn3_cropped_1.laz")], crs="EPSG:28992")
    return pc.xyz[pc.fields["classification"] == 6], read_layer(need(DELFT / "bgt_pand.geojson")).geometries


def _bgt_building(index: int):
    """The AHN3 class-6 points of the first Delft tile within BGT feature ``index`` grown by 0.5 m, and that outline."""
    b, footprints = _delft_class6()
    outline = shapely.force_2d(footprints[index]).buffer(0.5, join_style="mitre")
    return b[shapely.contains_xy(outline, b[:, 0], b[:, 1])], outline


def test_delft_step_edges_hold_their_levels_points(monkeypatch):
    """Delft BGT feature 80 (roof levels in steps): every labelled point with a face of its own plane within
    the point spacing lies under a face of its plane or of one within 0.1 m of it; without the claim of
    ``roof.faces.claim_points`` the raster and the sliver merging leave a dozen of them under another level."""
    import rooftrace.roof.structure as structure
    from rooftrace.model import build_model
    from rooftrace.model.measure import points_off_their_roof
    from rooftrace.roof.faces import points_off_their_faces, points_on_their_faces

    xyz, outline = _bgt_building(80)

    def breaks():
        roof = roof_structure(xyz, outline, building_id=80)
        faces = [shapely.force_2d(f) for f in roof.faces]
        assert shapely.union_all(faces).area == pytest.approx(outline.area, rel=1e-6)
        return int(points_off_their_faces(faces, roof.face_plane, xyz, roof.labels, roof.planes,
                                          radius=roof.spacing).sum())

    assert breaks() == 0
    # and the LoD 2.2 solid keeps every point the faces hold more than the lattice's step inside its face
    roof = roof_structure(xyz, outline, building_id=80)
    faces = [shapely.force_2d(f) for f in roof.faces]
    solids = [p.lods["2.2"] for p in build_model(outline, roof, xyz, float(xyz[:, 2].min()) - 3.0).parts]
    placed = points_on_their_faces(faces, roof.face_plane, xyz, roof.labels, roof.planes)
    assert placed.sum() > 0.9 * (roof.labels >= 0).sum()
    assert not (placed & points_off_their_roof(solids, xyz, roof.labels, roof.planes, max_dz=0.11)).any()
    monkeypatch.setattr(structure, "claim_points", lambda polys, ids, *a, **k: (polys, ids))
    assert breaks() > 5  # measured: 15


def test_delft_superstructures_are_blocks(delft_hip_roof):
    """The hip roof's chimneys and dormer tops (25 points on no plane more than 0.5 m above the LoD 2.2 roof
    without blocks, the top points' RMSE 0.39 m) are flat blocks: from one point up none is left; at the default
    two points with no boxes (``box_height = 0``) only lone returns (3) are left, and with the default boxes none:
    the invariant (every top point on no plane within 0.5 m of the LoD 2.2 roof unless a named reason holds)
    with no exception here.  The top points' RMSE is under 0.15 m (measured 0.134 m without the boxes, 0.096 m
    with them), the solids are valid."""
    from rooftrace.model import build_model, solid_errors
    from rooftrace.model.measure import roof_height_at
    from rooftrace.roof.structure import RoofOptions
    from tests.roof.test_structure import _top, _tops_off

    xyz, outline = delft_hip_roof
    ground = float(xyz[:, 2].min() - 3.0)
    rmse, off = {}, {}
    for points, boxes in ((0, 10.0), (1, 0.0), (2, 0.0), (2, 10.0)):
        roof = roof_structure(xyz, outline, RoofOptions(min_block_points=points, box_height=boxes), building_id=77)
        solids = [p.lods["2.2"] for p in build_model(outline, roof, xyz, ground).parts]
        assert all(solid_errors(s) == [] for s in solids)
        off[points, boxes] = _tops_off(roof, xyz, solids, 0.5)
        dz = xyz[:, 2] - roof_height_at(solids, xyz[:, :2])
        top = _top(xyz, roof.spacing, 0.5) & np.isfinite(dz)
        rmse[points, boxes] = np.sqrt(np.mean(dz[top] ** 2))
    assert off[0, 10.0].sum() > 10 and off[1, 0.0].sum() == 0 and 0 < off[2, 0.0].sum() < off[0, 10.0].sum() / 5
    # what the blocks alone leave are lone points: no other such point within the clusters' link (2.5 s)
    left = xyz[off[2, 0.0]]
    assert (np.linalg.norm(left[:, None] - left[None], axis=2) + np.eye(len(left)) * 1e9 > 2.5 * roof.spacing).all()
    assert off[2, 10.0].sum() == 0
    assert rmse[1, 0.0] < 0.15 and rmse[2, 10.0] < rmse[2, 0.0] < 0.15 < rmse[0, 10.0]


def test_delft_faces_fit_the_points_under_them(monkeypatch):
    """Delft BGT feature 27 (roof levels in steps, small faces at the step corners): every face's plane lies
    within the step height of at least half of the top-surface points under it; without
    ``roof.faces.fit_faces`` a few small faces lie metres off the points under them.  The step merges faces
    (never adds one) and the top points' RMSE to the faces does not grow.  (On feature 126, measured before, the
    claim of ``roof.faces.claim_points`` one wedge at a time now leaves no such face.)"""
    import rooftrace.roof.structure as structure
    from rooftrace.roof.faces import faces_off_their_points
    from rooftrace.roof.planes import plane_height
    from tests.roof.test_structure import _top

    xyz, outline = _bgt_building(27)

    def faces():
        roof = roof_structure(xyz, outline, building_id=27)
        polys = [shapely.force_2d(f) for f in roof.faces]
        assert shapely.union_all(polys).area == pytest.approx(outline.area, rel=1e-6)
        off = faces_off_their_points(polys, roof.face_plane, xyz, roof.labels, roof.planes, spacing=roof.spacing)
        top = _top(xyz, roof.spacing, 0.5)
        dz = np.full(len(xyz), np.nan)
        for f, k in zip(polys, roof.face_plane):
            inside = shapely.contains_xy(f, xyz[:, 0], xyz[:, 1])
            dz[inside] = xyz[inside, 2] - plane_height(roof.planes[k], xyz[inside, :2])
        return int(off.sum()), len(polys), float(np.sqrt(np.nanmean(dz[top] ** 2)))

    fitted, n_fitted, rmse_fitted = faces()
    monkeypatch.setattr(structure, "fit_faces", lambda polys, ids, *a, **k: (polys, ids))
    left, n_left, rmse_left = faces()
    assert fitted == 0 and left >= 2  # measured: 2
    assert n_fitted < n_left and rmse_fitted <= rmse_left


def test_delft_points_the_claim_of_all_wedges_left_are_claimed_one_by_one(monkeypatch):
    """Delft BGT feature 30 (a corner of small faces at a height step): every labelled point with a face of its
    own plane within the claim's radius (twice the point spacing) that no higher level's eave hides lies under
    a face of its plane or of one within 0.1 m of it; claiming all wedges at once only, which drops every
    wedge on a face one of them would cut in two and one of two wedges that meet, leaves 15 under another
    level."""
    import rooftrace.roof.faces as faces_module
    from rooftrace.roof.faces import points_off_their_faces
    from rooftrace.roof.structure import RoofOptions

    xyz, outline = _bgt_building(30)

    def breaks():
        roof = roof_structure(xyz, outline, building_id=30)
        faces = [shapely.force_2d(f) for f in roof.faces]
        assert shapely.union_all(faces).area == pytest.approx(outline.area, rel=1e-6)
        s = roof.spacing
        eaves = ~roof.plane_detail & (roof.plane_n * s**2 >= 2 * RoofOptions().min_area)
        return int(points_off_their_faces(faces, roof.face_plane, xyz, roof.labels, roof.planes, radius=2 * s,
                                          hidden_within=s, overhanging=eaves).sum())

    assert breaks() == 0
    monkeypatch.setattr(faces_module, "_claimed_singly", lambda polys, ids, *a, **k: (polys, ids))
    assert breaks() > 5  # measured: 15
