"""`geoface convert` on real meshes written by others and on real heads of the ICT-FaceKit
morphable model: optimal transport (exact power diagrams), a fold-free map, the boundary
sampled, every corner set a different parameterization."""

from __future__ import annotations

import json

import numpy as np
import pytest

from geoface.mesh.core import boundary_loops
from geoface.mesh.io import load_mesh
from geoface.pipeline import ConvertOptions, convert
from tests.helpers import shared_mesh

ALL_REAL = ["beetle.obj", "spot.obj", "ninjaHead_Low.obj", "face.obj", "decimated-max.obj", "camelhead.off", "lion.off",
            "male02.obj", "female02.obj"]


def _check_sets(m, count):
    assert len(m["sets"]) == count and m["failed_sets"] == []
    for st in m["sets"]:
        ot = st["ot"]
        assert ot["power_diagrams"] == "cgal"
        assert ot["path"] in ("ot", "ot+convex-combination", "balanced+ot", "balanced+ot+convex-combination")
        assert ot["converged"]
        assert ot["residual"] <= 1e-3
        assert ot["flipped_after"] == 0 and st["distortion"]["flipped"] == 0
        assert st["coverage"] == 1.0  # the square is filled: every pixel samples the surface


@pytest.mark.parametrize("name", ALL_REAL)
def test_real_mesh_converts_with_ot_and_no_fold(tmp_path, name):
    mesh = load_mesh(shared_mesh(name))
    m = convert(mesh, tmp_path / "out", ConvertOptions(res=64, augment=2, roi="face"), quiet=True)
    _check_sets(m, 2)
    assert m["sets"][0]["corners"] != m["sets"][1]["corners"]
    # 64x64 samples of a whole scan: coarse, but every part of the surface is reached (the full
    # body male02 too, its limbs no longer squeezed into strips: 1.9-2.0% at 64^2)
    for st in m["sets"]:
        assert st["reconstruction"]["hausdorff"] < 0.08, (name, st["reconstruction"])
    meta = json.loads((tmp_path / "out" / "aug0" / "meta.json").read_text())
    assert meta["version"] == 2 and meta["align_corners"] is True
    # the face cone and the upright corners look where the scan faces, whichever way that is
    # (the lion's neck is cut at 70 degrees to its up: its frame is the opening's, tilted with it)
    facing = {"decimated-max.obj": (0, 0, -1), "face.obj": (0, 0, 1),
              "ninjaHead_Low.obj": (0, 0, 1), "camelhead.off": (0, 0, 1), "spot.obj": (0, 0, -1)}
    if name in facing:
        assert np.dot(m["front"], facing[name]) > np.cos(np.radians(30)), (name, m["front"])


def test_a_limb_squeezed_by_the_whole_fold_free_solve_is_relaxed_back(tmp_path):
    """male02, corner set 1: OT's centroids fold 108 triangles, and the whole convex-combination
    solve squeezes a forearm into a strip (mean |log| cell-area error 0.30 -> 1.04; 4.4% Hausdorff
    at 128^2). The folds untangled where they are and relaxed towards the masses
    (geoface.param.relax) keep the areas (error under 0.3) and the arm (1.0%)."""
    mesh = load_mesh(shared_mesh("male02.obj"))
    m = convert(mesh, tmp_path / "out", ConvertOptions(res=128, corner_set=1, preview=False), quiet=True)
    st = m["sets"][0]
    _check_sets(m, 1)
    assert st["ot"]["flipped_before"] > 50 and st["ot"]["fold_free_solve"] == "untangled"
    assert st["ot"]["area_error_after"] < 0.3, st["ot"]
    assert st["reconstruction"]["hausdorff"] < 0.02, st["reconstruction"]


def test_eight_corner_sets_are_eight_parameterizations(tmp_path):
    mesh = load_mesh(shared_mesh("lion.off"))
    m = convert(mesh, tmp_path / "out", ConvertOptions(res=32, augment=8, reconstruct=False, preview=False), quiet=True)
    _check_sets(m, 8)
    assert len({frozenset(st["corners"]) for st in m["sets"]}) == 8
    # different maps, not rotations of one image: compare the position images up to the
    # four rotations and two flips of the square
    from geoface.gimage import load_gimage

    imgs = [load_gimage(tmp_path / "out" / f"aug{k}").image for k in range(8)]
    for a in range(8):
        for b in range(a + 1, 8):
            variants = [np.rot90(imgs[b], r, axes=(1, 2)) for r in range(4)]
            variants += [v[:, :, ::-1] for v in variants]
            assert min(np.abs(imgs[a] - v).mean() for v in variants) > 1e-3


def test_rim_is_sampled_no_notches(tmp_path):
    """The outermost pixels lie on the mesh boundary: the reconstruction's boundary runs
    along the input's (length within a few percent at 256^2; the pixel-centre grid of
    format 1 cut four notches into it, one per side)."""
    from geoface.mesh.core import bbox_diagonal
    from geoface.repair import make_disk

    mesh = load_mesh(shared_mesh("face.obj"))
    m = convert(mesh, tmp_path / "out", ConvertOptions(res=256, preview=False), quiet=True)
    rec = load_mesh(tmp_path / "out" / "reconstruction.obj")
    disk = make_disk(mesh.V, mesh.F, quiet=True)

    def loop_length(V, F):
        loop = max(boundary_loops(F), key=len)
        return float(np.linalg.norm(V[np.roll(loop, -1)] - V[loop], axis=1).sum())

    L_in, L_rec = loop_length(disk.V, disk.F), loop_length(rec.V, rec.F)
    assert abs(L_rec - L_in) / L_in < 0.03, (L_in, L_rec)
    # and every reconstructed boundary vertex lies on the input's boundary curve
    loop = max(boundary_loops(rec.F), key=len)
    b = max(boundary_loops(disk.F), key=len)
    A, B = disk.V[b], disk.V[np.roll(b, -1)]
    Q = rec.V[loop]
    AB = B - A
    t = np.clip(((Q[:, None] - A[None]) * AB[None]).sum(2) / (AB * AB).sum(1)[None], 0, 1)
    d = np.linalg.norm(Q[:, None] - (A[None] + t[:, :, None] * AB[None]), axis=2).min(1)
    assert d.max() / bbox_diagonal(disk.V) < 0.002
    assert m["sets"][0]["reconstruction"]["hausdorff"] < 0.01


def test_ict_heads_convert(tmp_path):
    from geoface.synth.ict import ict_head, load_ict_model, random_expression

    model = load_ict_model()
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        h = ict_head(model, seed=seed, expression=random_expression(rng, model.expression_names))
        m = convert(h.mesh(), tmp_path / f"h{seed}", ConvertOptions(res=64, augment=2, roi=h.face_mask), quiet=True)
        _check_sets(m, 2)
        st = m["sets"][0]
        # the face (2.5x mass) gets more of the image than of the surface
        from geoface.mesh.core import face_areas

        a = face_areas(h.V, h.F)
        share = a[h.face_mask[h.F].all(1)].sum() / a.sum()
        assert st["roi_pixel_share"] > share + 0.1
        assert st["reconstruction"]["face_hausdorff"] < 0.02


def test_a_failing_corner_set_is_recorded_and_skipped(tmp_path, monkeypatch):
    """One corner set that fails does not throw the others away: it is recorded in
    metrics.json and its folder is absent; only when every set fails does convert fail."""
    import geoface.param.ricci as ricci
    from geoface.errors import GeofaceError, ParameterizationError
    from geoface.synth import procedural_head

    from geoface.mesh.io import Mesh

    h = procedural_head(n_vertices=2000, seed=0)
    mesh = Mesh(h.V, h.F)
    solve = ricci.RicciFlowSolver.solve
    calls = {"n": 0}

    def flaky(self, corners=None, *a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise ParameterizationError("injected failure")
        return solve(self, corners, *a, **k)

    monkeypatch.setattr(ricci.RicciFlowSolver, "solve", flaky)
    m = convert(mesh, tmp_path / "out", ConvertOptions(res=32, augment=3, reconstruct=False, preview=False), quiet=True)
    assert [st["corner_set"] for st in m["sets"]] == [0, 2]
    assert m["failed_sets"] == [{"corner_set": 1, "error": "injected failure"}]
    assert (tmp_path / "out" / "aug0").is_dir() and not (tmp_path / "out" / "aug1").exists()
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["failed_sets"][0]["corner_set"] == 1

    def broken(self, *a, **k):
        raise ParameterizationError("always")

    monkeypatch.setattr(ricci.RicciFlowSolver, "solve", broken)
    with pytest.raises(GeofaceError, match="every corner set failed"):
        convert(mesh, tmp_path / "out2", ConvertOptions(res=32, augment=2), quiet=True)
    assert not (tmp_path / "out2").exists()


def test_front_is_found_from_the_face_mask(tmp_path):
    """A head facing +X with its face mask: ``front="auto"`` finds the face direction, and
    the default corner set puts the face upright and centred (the face pixels' centroid in
    the middle column); assuming +Z, without looking for the face (which would level and
    centre it again), puts it off to one side."""
    from geoface.mesh.io import Mesh
    from geoface.synth import procedural_head

    h = procedural_head(n_vertices=4000, seed=2)
    R = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # +Z -> +X
    mesh = Mesh(h.V @ R.T, h.F)
    cols = {}
    for front in ("auto", "z"):
        out = tmp_path / front
        m = convert(mesh, out, ConvertOptions(res=64, roi=h.face_mask, front=front, reconstruct=False, find_face=front == "auto"),
                    quiet=True)
        if front == "auto":
            assert np.dot(m["front"], [1, 0, 0]) > 0.9
        from geoface.gimage import load_gimage

        gi = load_gimage(out)
        # face pixels: where the position is inside the face region's bounding box in 3D
        P = gi.positions()
        face_pts = mesh.V[h.face_mask]
        inside = ((P >= face_pts.min(0)) & (P <= face_pts.max(0))).all(2) & (P[:, :, 0] > face_pts[:, 0].min())
        jj = np.nonzero(inside)[1]
        cols[front] = jj.mean() / 63
    assert abs(cols["auto"] - 0.5) < 0.1, cols
    assert abs(cols["z"] - 0.5) > abs(cols["auto"] - 0.5)


def test_up_is_found_from_the_neck_opening(tmp_path):
    """A head scanned z-up and facing -y (a common scanner convention): ``up="auto"`` takes
    the neck opening's normal, and with the face mask the face comes out upright and
    centred, as it does for the y-up head."""
    from geoface.mesh.io import Mesh
    from geoface.synth import procedural_head

    h = procedural_head(n_vertices=4000, seed=2)
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # +y -> +z, +z -> -y
    mesh = Mesh(h.V @ R.T, h.F)
    m = convert(mesh, tmp_path / "auto", ConvertOptions(res=64, roi=h.face_mask, up="auto", reconstruct=False), quiet=True)
    assert np.dot(m["up"], [0, 0, 1]) > 0.9 and np.dot(m["front"], [0, -1, 0]) > 0.9
    ref = convert(Mesh(h.V, h.F), tmp_path / "y", ConvertOptions(res=64, roi=h.face_mask, reconstruct=False), quiet=True)
    # the same corners on the same surface, to a vertex (each frame is its face's, found to a degree)
    from geoface.mesh.core import boundary_loops
    from geoface.repair import make_disk

    loop = boundary_loops(make_disk(h.V, h.F, find_face=False).F)[0].tolist()
    apart = [min(abs(loop.index(a) - loop.index(b)), len(loop) - abs(loop.index(a) - loop.index(b)))
             for a, b in zip(m["sets"][0]["corners"], ref["sets"][0]["corners"]) if a in loop and b in loop]
    assert len(apart) == 4 and max(apart) <= 1, (m["sets"][0]["corners"], ref["sets"][0]["corners"])


def test_level_turn_finds_the_turn_that_levels_a_face_even_on_a_coarse_boundary():
    """The secant steps of ``level_turn`` on a tilt that a whole turn of the boundary takes once
    round, offset by 7°: level within 0.5° in a few tries; where corners move by whole vertices of
    a 36-vertex boundary (10° steps) the best is kept and said (more than 2° off: ``convert`` then
    refines the boundary)."""
    from geoface.pipeline.corner_set import level_turn

    def tilt(turn):
        return 7.0 - 360.0 * turn

    r = level_turn(tilt, tilt(0.0))
    assert abs(r["eye_line_after"]) <= 0.5 and r["tries"] <= 3 and abs(r["turn"] - 7.0 / 360) < 0.003

    def coarse(turn):
        return 7.0 - 360.0 * round(turn * 36) / 36

    r = level_turn(coarse, coarse(0.0))
    assert abs(r["eye_line_after"]) == 3.0 and abs(r["turn"] - 1 / 36) < 1 / 72
    assert level_turn(tilt, 0.4)["tries"] == 0  # within 0.5° already: no more maps


def test_a_datasets_other_corner_sets_reuse_the_level_turn(tmp_path, monkeypatch):
    """A dataset converts a mesh once per corner set (``corner_set=k``); the turn that levels the
    face is found once (set 0's maps) and the other items take it: the same ``level`` record, and
    one map each (not the levelling's maps again)."""
    import geoface.pipeline.corner_set as cs
    import geoface.pipeline.face as pf

    mesh = load_mesh(shared_mesh("decimated-max.obj"))
    opts = dict(res=32, preview=False, reconstruct=False)
    first = convert(mesh, tmp_path / "a", ConvertOptions(corner_set=0, **opts), quiet=True)
    assert first["face"]["level"]["tries"] >= 1, first["face"]["level"]
    calls = []
    real = cs.map_set
    monkeypatch.setattr(cs, "map_set", lambda *a, **k: calls.append(1) or real(*a, **k))
    other = convert(mesh, tmp_path / "b", ConvertOptions(corner_set=3, **opts), quiet=True)
    assert other["face"]["level"] == first["face"]["level"] and len(calls) == 1, (len(calls), other["face"]["level"])
    pf._LEVELS.clear()  # without the caches (this process's, and the shared one on disk) the levelling's maps are made again
    from geoface import _cache

    monkeypatch.setenv(_cache.ENV, str(tmp_path / "empty cache"))
    calls.clear()
    third = convert(mesh, tmp_path / "c", ConvertOptions(corner_set=3, **opts), quiet=True)
    assert len(calls) >= 2, len(calls)
    # another process (here: this one, its own cache emptied) reads the turn back from the disk cache
    pf._LEVELS.clear()
    calls.clear()
    fourth = convert(mesh, tmp_path / "d", ConvertOptions(corner_set=3, **opts), quiet=True)
    assert fourth["face"]["level"] == third["face"]["level"] and len(calls) == 1, len(calls)


def test_a_large_disk_is_levelled_on_a_decimated_copy(tmp_path, monkeypatch):
    """Above ``LEVEL_SEARCH_FACTOR × LEVEL_SEARCH_VERTICES`` the level turn is sought on a copy
    (every boundary vertex kept, a disk) and the disk itself is mapped once or twice: the bust,
    26° off level on its own, ends within 2° with at most two maps of the full disk, where the
    search on the disk itself makes more."""
    import geoface.pipeline.corner_set as cs
    import geoface.pipeline.face as pf
    from geoface.param.ricci import RicciFlowSolver
    from geoface.repair import make_disk

    mesh = load_mesh(shared_mesh("decimated-max.obj"))
    d = make_disk(mesh.V, mesh.F, find_face=False)
    solver = RicciFlowSolver(d.V, d.F)
    coarse, _ = pf._coarse_disk(solver, None, 1500)
    loop = boundary_loops(coarse.F)
    assert len(loop) == 1 and 1300 <= len(coarse.V) <= 1700
    # the copy keeps the disk's boundary, vertex for vertex
    assert np.array_equal(np.sort(coarse.V[loop[0]], axis=0), np.sort(d.V[boundary_loops(d.F)[0]], axis=0))

    from geoface import _cache

    monkeypatch.delenv(_cache.ENV, raising=False)  # the level sought here, not read back from other tests
    monkeypatch.setattr(pf, "LEVEL_SEARCH_VERTICES", 1500)
    monkeypatch.setattr(pf, "LEVEL_SEARCH_FACTOR", 2.0)
    pf._LEVELS.clear()
    sizes = []
    real = cs.map_set
    monkeypatch.setattr(cs, "map_set", lambda st, c, s, *a, **k: sizes.append(len(s.solver.V)) or real(st, c, s, *a, **k))
    opts = dict(res=32, preview=False, reconstruct=False)
    m = convert(mesh, tmp_path / "a", ConvertOptions(**opts), quiet=True)
    level = m["face"]["level"]
    assert level["searched_on"]["vertices"] < 2000 and abs(level["eye_line_after"]) <= 2.0, level
    assert abs(m["sets"][0]["face_pixels"]["eye_line_degrees"]) <= 2.0
    full = [n for n in sizes if n > 3000]
    assert 1 <= len(full) <= 2 and len(sizes) > len(full), sizes
    monkeypatch.setattr(pf, "LEVEL_SEARCH_FACTOR", 1e9)  # the search on the disk itself
    pf._LEVELS.clear()
    sizes.clear()
    convert(mesh, tmp_path / "b", ConvertOptions(**opts), quiet=True)
    assert len(sizes) > len(full), sizes


def test_the_default_proxy_takes_only_large_scans():
    """With the default proxy (15,000) a scan goes through it above 45,000 vertices (smaller ones
    convert whole in seconds); an explicit size keeps the 1.5 × rule."""
    from geoface.pipeline import DEFAULT_PROXY, PROXY_ABOVE, proxy_threshold

    assert proxy_threshold(DEFAULT_PROXY) == PROXY_ABOVE == 45000
    assert proxy_threshold(2500) == 3750 and proxy_threshold(40000) == 60000
