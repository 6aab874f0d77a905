"""Large scans through a decimated proxy (geoface.pipeline.proxy), at small sizes: the maps are
solved on the proxy, but every pixel's position, normal and colour comes from the full scan —
the decoded positions lie on the scan (closer than the proxy itself does), colours the proxy
never had appear at the right places, and the error report measures against the scan."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.gimage import load_gimage
from geoface.mesh.core import bbox_diagonal
from geoface.mesh.io import Mesh, save_mesh
from geoface.pipeline import ConvertOptions, convert
from geoface.repair.proxy import decimate
from geoface.uvmap import SurfaceQuery
from tests.helpers import REPO, geoface

sys.path.insert(0, str(REPO / "data_tools"))
import make_stress_cases as S  # noqa: E402


@pytest.fixture(scope="module")
def scan():
    """An ICT-FaceKit head (11K vertices, open at the neck) with colours that are a function of
    the position, far from the origin in millimetres, as a scan arrives."""
    b = S.ict_base(0)
    V = b.V * 10.0 + np.array([5000.0, -3000.0, 12000.0])
    lo, hi = V.min(0), V.max(0)
    C = (V - lo) / (hi - lo)
    return Mesh(V, b.F, colors=C), lo, hi


def test_decimate_keeps_the_opening_and_the_precision_far_from_the_origin(scan):
    m, lo, hi = scan
    r = decimate(m.V, m.F, 3000)
    assert 2700 <= len(r.V) <= 3300
    # the openings (neck, eyes, mouth of the ICT skin) survive, each as long as it was
    from geoface.mesh.topology import topology_report

    a, b = topology_report(m.V, m.F), topology_report(r.V, r.F)
    assert b.boundary_loops == a.boundary_loops == 4 and b.genus == 0
    assert np.allclose(sorted(b.boundary_loop_lengths), sorted(a.boundary_loop_lengths), rtol=0.03)
    d = SurfaceQuery(m.V, m.F)(r.V)[0] / bbox_diagonal(m.V)
    assert d.max() < 5e-3  # on the scan, 12 m from the origin, in float32 inside the simplifier
    assert decimate(m.V, m.F, 20000).V is m.V or len(decimate(m.V, m.F, 20000).V) == len(m.V)
    with pytest.raises(GeofaceError):
        decimate(m.V, m.F, 3)


def test_proxy_images_sample_the_full_scan(scan, tmp_path):
    m, lo, hi = scan
    out = tmp_path / "out"
    met = convert(m, out, ConvertOptions(res=96, proxy=2500, preview=False), quiet=True)
    px = met["proxy"]
    assert px["scan_vertices"] == len(m.V) and 2200 <= px["proxy_vertices"] <= 2800
    assert px["full_faces"] > 0.95 * len(m.F)  # the whole head is the full surface (nothing was cut away)
    st = met["sets"][0]
    assert st["distortion"]["flipped"] == 0 and st["scan_pixel_share"] > 0.95
    gi = load_gimage(out)
    P = gi.positions()[gi.mask]
    diag = bbox_diagonal(m.V)
    d_scan = SurfaceQuery(m.V, m.F)(P)[0] / diag
    prox = decimate(m.V, m.F, 2500)
    d_proxy = SurfaceQuery(prox.V, prox.F)(P)[0] / diag
    # on the scan up to the 16-bit quantisation (1/65535 of the bbox per axis), and off the proxy;
    # all but the pixels in the eyes and mouth, which the repair filled (they keep the proxy's)
    on = d_scan < 2e-5
    assert abs(on.mean() - st["scan_pixel_share"]) < 0.01, (on.mean(), st["scan_pixel_share"])
    assert np.median(d_proxy[on]) > 5 * np.median(d_scan[on])
    # the colours the proxy never had, sampled from the scan where each pixel is
    # (in the filled eyes and mouth: the colour of the nearest scan point, the rim)
    rgb = gi.modality("texture").transpose(1, 2, 0)[gi.mask]
    assert np.abs(rgb - (P - lo) / (hi - lo))[on].max() < 0.01
    # the report measures against the scan
    rec = st["reconstruction"]
    # (96² of a whole head: the back of the head and the neck get few pixels)
    assert rec["reference"] == "full scan" and rec["hausdorff"] < 0.04 and rec["face_hausdorff"] < 0.02, rec


def test_small_meshes_and_proxy_zero_take_the_direct_path(scan, tmp_path):
    m, _, _ = scan
    met = convert(m, tmp_path / "a", ConvertOptions(res=32, proxy=0, preview=False, reconstruct=False), quiet=True)
    assert "proxy" not in met and "scan_pixel_share" not in met["sets"][0]
    met = convert(m, tmp_path / "b", ConvertOptions(res=32, proxy=8000, preview=False, reconstruct=False), quiet=True)
    assert "proxy" not in met  # 11K vertices is not more than 1.5 x 8000
    for bad in (500, -1, 2.5, True):
        with pytest.raises(GeofaceError, match="proxy"):
            ConvertOptions(proxy=bad).validate()


def test_cli_proxy(scan, tmp_path):
    m, _, _ = scan
    f = tmp_path / "scan.ply"
    save_mesh(f, Mesh(m.V, m.F))
    run = ["convert", f, "-o", tmp_path / "o", "--res", "32", "--no-reconstruct"]
    code, out, err = geoface(*run, "--proxy", "2500")
    assert code == 0, err
    assert "-vertex proxy of the 11,248)" in out, out
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["proxy"]["proxy_vertices"] > 0
    code, out, err = geoface(*run, "--proxy", "-3", "--force")
    assert code == 2 and "Traceback" not in err and "--proxy" in err


def test_the_cli_default_proxy_is_the_library_default():
    from geoface.cli import build_parser
    from geoface.pipeline import DEFAULT_PROXY

    from geoface.repair.proxy import NEEDLE_RATIO

    args = build_parser().parse_args(["convert", "in.obj", "-o", "out"])
    assert args.proxy == DEFAULT_PROXY == ConvertOptions().proxy
    assert args.needles == NEEDLE_RATIO == ConvertOptions().needles


def test_the_cli_default_blend_is_the_library_default(tmp_path):
    from geoface.cli import build_parser
    from geoface.dataset import DatasetOptions
    from geoface.pipeline import DEFAULT_BLEND

    args = build_parser().parse_args(["convert", "in.obj", "-o", "out"])
    ds = build_parser().parse_args(["dataset", "build", "in", "-o", "out"])
    assert args.blend == ds.blend == DEFAULT_BLEND == ConvertOptions().blend == DatasetOptions().blend
    for bad in ("-0.1", "1", "nan"):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["convert", "in.obj", "-o", "out", "--blend", bad])
    with pytest.raises(GeofaceError, match="blend"):
        ConvertOptions(blend=1.5).validate()


def test_merge_needles_turns_sliver_strips_back_into_the_mesh():
    """Strips of needles (edges split a thousandth from their ends) collapse back to the mesh
    they were made from: the same vertex count and faces, every vertex on it; meshes without
    needles are left alone."""
    from geoface.repair.proxy import merge_needles

    base = S.real_base("ninjaHead_Low.obj")
    case = S.with_slivers(base)
    assert len(case.V) > len(base.V) + 100
    r = merge_needles(case.V, case.F)
    assert r is not None and r.merged == len(case.V) - len(base.V)
    assert len(r.V) == len(base.V) and len(r.F) == len(base.F)
    d = SurfaceQuery(base.V, base.F)(r.V)[0] / bbox_diagonal(base.V)
    assert d.max() < 1e-4
    # which proxy vertex and face each input vertex and face became: faces keep their corners
    # in order, a needle collapses (a repeated corner)
    img = r.vertex_of[case.F]
    live = r.face_of >= 0
    assert np.array_equal(r.F[r.face_of[live]], img[live])
    rep = (img[:, 0] == img[:, 1]) | (img[:, 1] == img[:, 2]) | (img[:, 2] == img[:, 0])
    assert np.array_equal(rep, ~live) and rep.sum() > 100
    assert np.array_equal(np.unique(r.face_of[live]), np.arange(len(r.F)))
    assert merge_needles(base.V, base.F) is None
    assert merge_needles(S.ict_base(0).V, S.ict_base(0).F) is None
    with pytest.raises(GeofaceError):
        merge_needles(base.V, base.F, 0.7)


@pytest.mark.parametrize("name", ["spot.obj", "male02.obj"])
def test_a_scan_with_needles_converts_like_its_clean_mesh(tmp_path, name):
    """The cow and the male body with sliver strips go through the needle proxy and come out as
    they do without (Hausdorff error at most 10% above; measured against the scan plus the
    repair's fills: the cow's hooves, the body's holes, where its other parts are dropped); with
    ``needles=0`` they take the direct path. (The frame from the shape: the subject is the proxy,
    and each of the three meshes would be looked at and levelled on its own.)"""
    base = S.real_base(name)
    case = S.with_slivers(base)
    opts = dict(res=64, preview=False, corner_set=0, find_face=False)
    clean = convert(Mesh(base.V, base.F), tmp_path / "clean", ConvertOptions(**opts), quiet=True)
    met = convert(Mesh(case.V, case.F), tmp_path / "needles", ConvertOptions(**opts), quiet=True)
    assert met["proxy"]["kind"] == "needles merged" and abs(met["proxy"]["proxy_vertices"] - len(base.V)) <= 2
    assert "proxy" not in clean
    h_clean = clean["sets"][0]["reconstruction"]["hausdorff"]
    h = met["sets"][0]["reconstruction"]["hausdorff"]
    assert met["sets"][0]["reconstruction"]["reference"] == "full scan"
    assert h < 1.1 * h_clean, (h, h_clean)
    direct = convert(Mesh(case.V, case.F), tmp_path / "direct", ConvertOptions(needles=0, **opts), quiet=True)
    assert "proxy" not in direct and direct["sets"][0]["distortion"]["flipped"] == 0
    for bad in (-0.1, 0.5, True, "x"):
        with pytest.raises(GeofaceError, match="needles"):
            ConvertOptions(needles=bad).validate()


def test_cli_needles(tmp_path):
    case = S.with_slivers(S.real_base("spot.obj"))
    f = tmp_path / "cow.obj"
    save_mesh(f, Mesh(case.V, case.F))
    run = ["convert", f, "-o", tmp_path / "o", "--res", "32", "--no-reconstruct", "--no-find-face"]
    code, out, err = geoface(*run)
    assert code == 0, err
    assert "needles merged)" in out, out
    code, out, err = geoface(*run, "--needles", "2", "--force")
    assert code == 2 and "Traceback" not in err and "--needles" in err


def test_the_cli_default_feature_is_the_library_default(tmp_path):
    from geoface.cli import build_parser
    from geoface.dataset import DatasetOptions
    from geoface.pipeline import DEFAULT_FEATURE

    args = build_parser().parse_args(["convert", "in.obj", "-o", "out"])
    ds = build_parser().parse_args(["dataset", "build", "in", "-o", "out"])
    assert args.feature == ds.feature == DEFAULT_FEATURE == ConvertOptions().feature == DatasetOptions().feature
    assert DatasetOptions().convert_options(0, None).feature == DEFAULT_FEATURE
    f = tmp_path / "in.obj"
    f.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    code, _, err = geoface("convert", f, "-o", tmp_path / "o", "--feature", "-1")
    assert code == 2 and "Traceback" not in err and "--feature" in err


def test_the_error_report_bounds_the_sampled_positions_without_querying_them(scan):
    """The reconstruction's vertices are the positions the sampling gave (stored, so moved by a
    rounding): their distance to the scan is bounded by the sampled point's plus that move — the
    report's bound is at least the queried distance and within 1e-6 of the diagonal of it, where
    a point off the scan (a proxy position kept) counts with its own distance."""
    from geoface.pipeline.proxy import full_surface
    from geoface.repair import make_disk

    m, _, _ = scan
    prox = decimate(m.V, m.F, 2500)
    d = make_disk(prox.V, prox.F, find_face=False)
    full = full_surface(m, d.V, d.F, None, fill=d.face_map < 0)
    rng = np.random.default_rng(0)
    f = rng.integers(0, len(d.F), 4000)
    b = rng.dirichlet(np.ones(3), 4000)
    P = np.einsum("kj,kjd->kd", b, d.V[d.F[f]])
    P[:50] += 3.0 * full.tol * rng.normal(size=(50, 3))  # a few far off the proxy: kept where they are
    Q, _, _, _ = full.sample(P, np.zeros_like(P))
    V_rec = Q.astype(np.float32).astype(np.float64)  # stored in single precision
    F_rec = np.arange(len(V_rec) - len(V_rec) % 3).reshape(-1, 3)
    bound = full.error(V_rec, F_rec, sampled=True)
    exact = full.error(V_rec, F_rec)
    assert exact["rec_to_ref_max"] <= bound["rec_to_ref_max"] <= exact["rec_to_ref_max"] + 1e-6
    assert exact["mean"] <= bound["mean"] + 1e-12 and bound["mean"] <= exact["mean"] + 1e-6
    assert bound["ref_to_rec_max"] == exact["ref_to_rec_max"]
    assert (full.last_distance > 0).any()  # some points stayed off the scan: their own distance counts


def test_the_fills_are_asked_only_where_they_can_matter():
    """``FullSurface._fill_near`` queries the fills only for points within ``tol`` of their box or
    off the scan, and :meth:`sample` gives exactly what querying every point gives."""
    from types import SimpleNamespace

    from geoface.pipeline.proxy import FullSurface
    from geoface.synth import square_grid
    from geoface.uvmap.bake import SurfaceQuery

    V, F = square_grid(20)  # the unit square at z = 0; the fill: four triangles just above a corner
    fillV = V[F[:4].ravel()] + [0.0, 0.0, 0.001]
    fillF = np.arange(12).reshape(4, 3)
    asked = []

    class Counting(SurfaceQuery):
        def __call__(self, P):
            asked.append(len(P))
            return super().__call__(P)

    q = SurfaceQuery(fillV, fillF)
    counting = Counting(fillV, fillF)

    surf = FullSurface(mesh=SimpleNamespace(V=V), F=F, query=SurfaceQuery(V, F), normals=np.tile([0.0, 0.0, 1.0], (len(V), 1)),
                       tol=0.02, diag=1.5, roi=None, kept=np.arange(len(V)), colour_source=None,
                       fill_query=counting, fill_vertices=fillV)
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(0, 1, (2000, 2)), rng.normal(0, 0.01, 2000)])
    P[:50, 2] += 0.5  # off the scan: asked wherever they are, and half of them nearer the fill than the scan
    P[:25, :2] = V[F[:4].ravel(), :2].mean(0) + rng.uniform(-0.005, 0.005, (25, 2))
    Q, N, _, _ = surf.sample(P, np.tile([0.0, 0.0, 1.0], (len(P), 1)))
    assert 50 <= asked[0] < len(P) / 2
    d_near = surf.last_distance.copy()
    surf._fill_near = lambda P_, dist: q(P_)  # every point asked
    Q2, N2, _, _ = surf.sample(P, np.tile([0.0, 0.0, 1.0], (len(P), 1)))
    assert np.array_equal(Q, Q2) and np.array_equal(N, N2) and np.array_equal(d_near, surf.last_distance)
