"""Benchmarks of the measure-preserving pipeline; one JSON line per case.

* ``convert``: procedural heads of growing size through ``geoface.pipeline.convert`` —
  seconds per stage, OT Newton iterations and halvings, flips, reconstruction error.
* ``ot``: our OT solver and pysdot (if installed: ``pip install pysdot==0.2.16``) on the same
  points and masses in the same run — the vertices of a head's conformal map with the
  face weighted 2.5×, and 100K clustered points.  Both report the final
  max |w_i - ν_i| / ν_i, measured by our own power diagram at the returned weights.
* ``ot_equal``: the same problems (and set 0's problem of each ``--files`` mesh) solved by both
  to the *same* max relative cell-mass error (``--targets``, default 1e-3 and 1e-6), measured by
  our power diagram for both; pysdot's Newton run is stopped at its first iterate that reaches it.
* ``real``: ``geoface convert`` with all 8 corner sets on the real meshes of
  ``../shared/data/meshes`` and on random heads of the ICT-FaceKit model (identities
  ~ N(0, 1), three random expressions each) — per mesh: vertices, log range of the conformal
  factor, seconds per stage, OT iterations, folds of the centroid map and of the final map,
  mean |log area|, face-pixel share, face and whole Hausdorff; and the same OT problem (set 0's
  conformal map, the face weighted 2.5x) solved by pysdot in the same run.
* ``claim``: the paper's claim on the procedural head at N = 256 and 512 — reconstruction
  error (Hausdorff and mean distance / bbox diagonal, globally and on the face) and the share
  of face pixels, for conformal vs area-preserving (λ = 1) vs measure-preserving (λ = 2.5).

    python bench/bench_convert.py [--cases convert ot claim real] [--sizes 10000 50000 200000]
    python bench/bench_convert.py --cases ot_equal --files bust134k.obj
    python bench/bench_convert.py --cases ot_equal --with-real
    python bench/bench_convert.py --cases ot_equal --files bust134k.obj --only-files --no-pysdot
    python bench/bench_convert.py --cases real --res 256 512 [--meshes face.obj lion.off] [--ict 10]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def emit(**d):
    def r(v):
        if isinstance(v, float):
            return float(f"{v:.4g}")
        if isinstance(v, dict):
            return {k: r(x) for k, x in v.items()}
        return v

    print(json.dumps({k: r(v) for k, v in d.items()}), flush=True)


def head_mesh(n, seed=0):
    from geoface.mesh.io import Mesh
    from geoface.synth.head import procedural_head

    h = procedural_head(n, seed=seed)
    return h, Mesh.from_vertex_uv(h.V, h.F, h.UV, texture=h.texture, colors=h.colors)


def case_convert(sizes, res, files=()):
    from geoface.mesh.io import load_mesh
    from geoface.pipeline import ConvertOptions, convert

    jobs = [(f"head{n // 1000}k", n, lambda n=n: head_mesh(n)) for n in sizes]
    jobs += [(Path(f).name, None, lambda f=f: (None, load_mesh(f))) for f in files]
    for name, n, make in jobs:
        h, mesh = make()
        roi = h.face_mask if h is not None else "face"
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            m = convert(mesh, Path(tmp) / "out", ConvertOptions(res=res, roi=roi, lam=2.5), quiet=True)
            total = time.perf_counter() - t
        st = m["sets"][0]
        emit(case="convert", mesh=name, vertices=len(mesh.V), res=res, seconds_total=total, seconds_repair=m["seconds"]["repair"],
             seconds_ricci=st["ricci"]["seconds"], seconds_ot=st["ot"]["seconds"], seconds_images=st["images_seconds"],
             seconds_reconstruction=st["reconstruction"]["seconds"], ot_iterations=st["ot"]["iterations"],
             ot_halvings=st["ot"]["halvings"], ot_residual=st["ot"]["residual"], flipped_before=st["ot"]["flipped_before"],
             flipped_after=st["distortion"]["flipped"], path=st["ot"]["path"], log_area_abs_mean=st["distortion"]["log_area_abs_mean"],
             roi_pixel_share=st["roi_pixel_share"], hausdorff=st["reconstruction"]["hausdorff"],
             mean_distance=st["reconstruction"]["mean"])


def _residual(P, h, nu):
    from geoface.param.power import power_diagram

    a = power_diagram(P, h).area
    return float(np.max(np.abs(a - nu) / nu))


def _pysdot(P, nu, budget):
    try:
        from pysdot import ConvexPolyhedraAssembly, OptimalTransport
    except ImportError:
        return None
    dom = ConvexPolyhedraAssembly()
    dom.add_box([0.0, 0.0], [1.0, 1.0], 1.0, 2**64 - 1)  # pysdot 0.2.16's default cut_id -1 fails on NumPy 2
    ot = OptimalTransport(positions=P.copy(), masses=nu.copy(), domain=dom, linear_solver="Scipy", obj_max_dw=1e-10)
    ot.max_iter = 1000
    t = time.perf_counter()
    ot.adjust_weights(initial_weights=np.zeros(len(P)))
    sec = time.perf_counter() - t
    # pysdot's weights w: power |x - p|^2 - w, the same convention as our heights
    return sec, _residual(P, np.asarray(ot.get_weights()), nu), len(ot.delta_w)


class _Reached(Exception):
    pass


def _pysdot_to(P, nu, target):
    """pysdot's Newton run until the first iterate whose max relative cell-mass error, by *our*
    power diagram, is <= ``target``; the check runs before each of pysdot's assemblies, outside the
    clock.  Returns (seconds, error reached, Newton steps) or None when pysdot is missing."""
    try:
        from pysdot import ConvexPolyhedraAssembly, OptimalTransport
    except ImportError:
        return None
    dom = ConvexPolyhedraAssembly()
    dom.add_box([0.0, 0.0], [1.0, 1.0], 1.0, 2**64 - 1)
    ot = OptimalTransport(positions=P.copy(), masses=nu.copy(), domain=dom, linear_solver="Scipy", obj_max_dw=1e-14)
    ot.max_iter = 200
    pd = ot.pd
    assemble = pd.der_integrals_wrt_weights
    state = {"paused": 0.0, "calls": 0, "err": np.inf}

    def checked(*a, **k):
        t0 = time.perf_counter()
        state["err"] = _residual(P, np.asarray(pd.get_weights()), nu)
        state["paused"] += time.perf_counter() - t0
        if state["err"] <= target:
            raise _Reached
        state["calls"] += 1
        return assemble(*a, **k)

    pd.der_integrals_wrt_weights = checked
    t = time.perf_counter()
    try:
        ot.adjust_weights(initial_weights=np.zeros(len(P)))
        state["err"] = _residual(P, np.asarray(pd.get_weights()), nu)
    except _Reached:
        pass
    sec = time.perf_counter() - t - state["paused"]
    return sec, state["err"], max(state["calls"] - 1, 0)


def case_ot_equal(targets, files=(), real=None, pysdot=True, builtin=True):
    """Ours and pysdot to the *same* max relative cell-mass error, measured by the same code
    (our power diagram) for both: the 43K head, 100K clustered points, set 0's problem of
    each mesh in ``files`` (e.g. the 134K bust) and, with ``real = (names, n_ict)``, of the real
    meshes and ICT heads of the ``real`` case."""
    from geoface.mesh.io import load_mesh
    from geoface.param.ot import semi_discrete_ot

    def problems():
        if real is None and builtin:
            yield from _ot_problems()
        for f in files:
            yield (Path(f).stem, *_ot_problem(load_mesh(f), "face"))
        if real is not None:
            for name, mesh, roi in real_meshes(*real):
                yield (name, *_ot_problem(mesh, roi))

    for name, P, nu in problems():
        nu = nu / nu.sum()
        for target in targets:
            t = time.perf_counter()
            o = semi_discrete_ot(P, nu, tol=target, quiet=True)
            sec = time.perf_counter() - t
            ours = _residual(P, o.h, nu)
            emit(case="ot_equal", points=name, n=len(P), target=target, solver="geoface", seconds=sec,
                 iterations=o.iterations, max_rel_error=ours, mass_range=float(nu.max() / nu.min()))
            if not pysdot:
                continue
            ps = _pysdot_to(P, nu, target)
            if ps is None:
                emit(case="ot_equal", points=name, target=target, solver="pysdot",
                     skipped="pysdot not installed (pip install pysdot==0.2.16)")
                continue
            reached = ps[1] <= target  # pysdot can stop at its max_iter (200) without reaching it
            emit(case="ot_equal", points=name, n=len(P), target=target, solver="pysdot", seconds=ps[0],
                 iterations=ps[2], max_rel_error=ps[1], reached=reached, **({"speedup": ps[0] / sec} if reached else {}))


def _ot_problems():
    from geoface.mesh.core import vertex_areas
    from geoface.param.ricci import ricci_flow_rectangle

    h, _ = head_mesh(43000)
    r = ricci_flow_rectangle(h.V, h.F)
    yield "head43k_conformal_lam2.5", r.unit_square(), vertex_areas(h.V, r.F) * np.where(h.face_mask, 2.5, 1.0)
    rng = np.random.default_rng(0)
    n = 100_000
    centres = rng.random((10, 2)) * 0.8 + 0.1
    k = n // 2
    cl = centres[rng.integers(0, 10, k)] + rng.normal(0, 0.01, (k, 2))
    yield "clustered100k", np.clip(np.concatenate([rng.random((n - k, 2)), cl]), 0.0, 1.0), np.ones(n)


def case_ot(budget):
    from geoface.param.ot import semi_discrete_ot

    for name, P, nu in _ot_problems():
        nu = nu / nu.sum()
        t = time.perf_counter()
        o = semi_discrete_ot(P, nu, quiet=True)
        sec = time.perf_counter() - t
        emit(case="ot", points=name, n=len(P), solver="geoface", seconds=sec, iterations=o.iterations,
             halvings=o.halvings, stages=o.stages, max_rel_error=_residual(P, o.h, nu), mass_range=float(nu.max() / nu.min()))
        ps = _pysdot(P, nu, budget)
        if ps is None:
            emit(case="ot", points=name, solver="pysdot", skipped="pysdot not installed (pip install pysdot==0.2.16)")
        else:
            emit(case="ot", points=name, n=len(P), solver="pysdot", seconds=ps[0], max_rel_error=ps[1], iterations=ps[2])


def case_claim(n, resolutions):
    from geoface.pipeline import ConvertOptions, convert

    h, mesh = head_mesh(n)
    for res in resolutions:
        for method, lam in (("conformal", 1.0), ("ot", 1.0), ("ot", 2.5)):
            with tempfile.TemporaryDirectory() as tmp:
                m = convert(mesh, Path(tmp) / "o", ConvertOptions(res=res, roi=h.face_mask, lam=lam, method=method), quiet=True)
            st = m["sets"][0]
            rec = st["reconstruction"]
            emit(case="claim", vertices=n, res=res, map=("conformal" if method == "conformal" else f"ot_lam{lam:g}"),
                 face_pixel_share=st["roi_pixel_share"], hausdorff=rec["hausdorff"], mean=rec["mean"],
                 face_hausdorff=rec["face_hausdorff"], face_mean=rec["face_mean"], flipped=st["distortion"]["flipped"],
                 log_area_abs_mean=st["distortion"]["log_area_abs_mean"])


SHARED = REPO.parent / "shared" / "data" / "meshes"
REAL_MESHES = ["beetle.obj", "spot.obj", "ninjaHead_Low.obj", "face.obj", "decimated-max.obj", "camelhead.off", "lion.off",
               "male02.obj", "female02.obj"]


def real_meshes(names, n_ict):
    """(name, Mesh, roi mask or "face") for the shared real meshes and ``n_ict`` ICT heads."""
    from geoface.mesh.io import load_mesh
    from geoface.synth.ict import ict_head, load_ict_model, random_expression

    for name in names:
        p = SHARED / name
        if not p.is_file():
            p = REPO / "tests" / "data" / "meshes" / name
        yield name, load_mesh(p), "face"
    if n_ict:
        model = load_ict_model()
        for seed in range(n_ict):
            rng = np.random.default_rng(1000 + seed)
            h = ict_head(model, seed=seed, expression=random_expression(rng, model.expression_names))
            yield f"ict_seed{seed}", h.mesh(), h.face_mask


def _ot_problem(mesh, roi):
    """Set 0's OT problem as convert builds it: conformal sites and masses."""
    from geoface.mesh.core import vertex_areas
    from geoface.param.corners import corner_sets
    from geoface.param.ricci import RicciFlowSolver
    from geoface.pipeline import face_region
    from geoface.repair import make_disk

    d = make_disk(mesh.V, mesh.F, quiet=True)
    r = RicciFlowSolver(d.V, d.F).solve(corner_sets(d.V, d.F, n=1, up=(0, 1, 0))[0], quiet=True)
    if isinstance(roi, str):
        m = face_region(r.V)
    else:
        m = np.zeros(len(r.V), bool)
        ok = d.vertex_map >= 0
        m[: len(ok)][ok] = roi[d.vertex_map[ok]]
    nu = vertex_areas(r.V, r.F) * np.where(m, 2.5, 1.0)
    return r.unit_square(), nu / nu.sum()


def case_real(names, n_ict, resolutions, augment, pysdot_budget):
    from geoface.errors import GeofaceError
    from geoface.param.ot import semi_discrete_ot
    from geoface.pipeline import ConvertOptions, convert

    for name, mesh, roi in real_meshes(names, n_ict):
        for res in resolutions:
            with tempfile.TemporaryDirectory() as tmp:
                t = time.perf_counter()
                try:
                    m = convert(mesh, Path(tmp) / "o", ConvertOptions(res=res, roi=roi, lam=2.5, augment=augment), quiet=True)
                except GeofaceError as e:
                    emit(case="real", mesh=name, res=res, failed=str(e), seconds_total=time.perf_counter() - t)
                    continue
                total = time.perf_counter() - t
            sets = m["sets"]
            st = sets[0]
            worst = lambda key, sub: max(s[sub][key] for s in sets)  # noqa: E731
            emit(case="real", mesh=name, res=res, vertices=m["input_vertices"], disk_vertices=m["disk_vertices"],
                 sets_ok=len(sets), sets_failed=len(m["failed_sets"]),
                 log_conformal_range=st["ricci"]["log_conformal_factor_range"], seconds_total=total,
                 seconds_repair=m["seconds"]["repair"], seconds_ricci=st["ricci"]["seconds"], seconds_ot=st["ot"]["seconds"],
                 seconds_images=st["images_seconds"], seconds_reconstruction=st["reconstruction"]["seconds"],
                 ot_iterations=st["ot"]["iterations"], power_diagrams=st["ot"]["power_diagrams"], path=st["ot"]["path"],
                 flipped_before=st["ot"]["flipped_before"], flipped_after_max=worst("flipped", "distortion"),
                 area_error_before=st["ot"]["area_error_before"], area_error_after=st["ot"]["area_error_after"],
                 log_area_abs_mean=st["distortion"]["log_area_abs_mean"], face_pixel_share=st.get("roi_pixel_share"),
                 face_hausdorff=st["reconstruction"].get("face_hausdorff"), hausdorff=st["reconstruction"]["hausdorff"],
                 hausdorff_max_over_sets=worst("hausdorff", "reconstruction"))
        P, nu = _ot_problem(mesh, roi)
        t = time.perf_counter()
        o = semi_discrete_ot(P, nu, quiet=True)
        emit(case="real_ot", mesh=name, n=len(P), solver="geoface", seconds=time.perf_counter() - t, iterations=o.iterations,
             max_rel_error=_residual(P, o.h, nu), mass_range=float(nu.max() / nu.min()))
        ps = _pysdot(P, nu, pysdot_budget)
        if ps is None:
            emit(case="real_ot", mesh=name, solver="pysdot", skipped="pysdot not installed (pip install pysdot==0.2.16)")
        else:
            emit(case="real_ot", mesh=name, n=len(P), solver="pysdot", seconds=ps[0], max_rel_error=ps[1], iterations=ps[2])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", nargs="+", default=["convert", "ot", "claim"])
    ap.add_argument("--sizes", nargs="*", type=int, default=[10000, 50000, 200000])
    ap.add_argument("--res", type=int, nargs="+", default=[512])
    ap.add_argument("--meshes", nargs="+", default=REAL_MESHES, help="real meshes (names in ../shared/data/meshes)")
    ap.add_argument("--ict", type=int, default=10, help="random ICT-FaceKit heads in the real case")
    ap.add_argument("--augment", type=int, default=8)
    ap.add_argument("--files", nargs="*", default=[], help="meshes to time in the convert case besides the procedural heads "
                    "(e.g. the ~134K bust of data_tools/make_dense_bust.py)")
    ap.add_argument("--targets", type=float, nargs="+", default=[1e-3, 1e-6],
                    help="max relative cell-mass errors of the ot_equal case")
    ap.add_argument("--with-real", action="store_true",
                    help="ot_equal: the real meshes' and ICT heads' problems instead of the head and clustered points")
    ap.add_argument("--no-pysdot", action="store_true", help="ot_equal: time geoface only (pysdot on the 134K bust takes ~10 min a target)")
    ap.add_argument("--only-files", action="store_true", help="ot_equal: only the --files problems (not the head and clustered points)")
    ap.add_argument("--claim-vertices", type=int, default=50000)
    args = ap.parse_args()
    if "convert" in args.cases:
        for res in args.res:
            case_convert(args.sizes, res, args.files)
    if "real" in args.cases:
        case_real(args.meshes, args.ict, args.res, args.augment, 600)
    if "ot" in args.cases:
        case_ot(600)
    if "ot_equal" in args.cases:
        case_ot_equal(args.targets, args.files, (args.meshes, args.ict) if args.with_real else None,
                      pysdot=not args.no_pysdot, builtin=not args.only_files)
    if "claim" in args.cases:
        case_claim(args.claim_vertices, [256, 512])


if __name__ == "__main__":
    main()
