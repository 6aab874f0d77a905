"""Build the table that puts MediaPipe's 468 face-mesh points on the ICT-FaceKit head
(geoface/data/mediapipe_ict.json): for each face-mesh point a triangle of the model's face and
barycentric weights in it, so that a fitted ICT head (any identity, any expression, any pose)
says where each of the 468 points should appear in a frame (:mod:`geoface.track.head_track`).

How: ICT-FaceKit people (random identities, random ARKit expressions, head poses up to ±35° yaw,
±15° pitch, ±10° roll) are rendered lit with skin, eyes and teeth (:class:`geoface.avatar.ict.ICTPerson`)
and MediaPipe's face mesh runs on each picture. The ray through each detected point meets the
true posed head in one triangle at some barycentric weights; those weights, evaluated on the
model's *mean neutral* head, place the point on the canonical face. The table's point is the
per-coordinate median of those canonical places over the training pictures, snapped to the
nearest face triangle (the model's narrow and outer face). A point whose rays scatter more is
less certain: its weight in the fit is ``1 / (1 + (spread / 5 mm)²)``.

Measured on other people (validation and test seeds): the table's points on the *true* posed
head, projected, against MediaPipe's detections, in pixels and in fractions of the outer-eye-corner
distance; beside it the same for the nearest model vertex instead of the barycentric point.

    python data_tools/fit_mediapipe_ict.py [--renders 30] [--res 256]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SPLITS = {"train": (0, 1, 2, 3, 4, 5, 6, 7), "val": (8, 9), "test": (10, 16)}
FACE_LABELS = (0, 1)  # narrow_face, outer_face (geoface.synth.ict.REGIONS)


def renders(seed: int, n: int, res: int):
    """(person, [(posed V, 468 points (NaN: not found)), ...]) for ``n`` random pictures of person ``seed``."""
    from geoface.avatar.ict import ICTPerson
    from geoface.rotations import euler_rotation
    from geoface.synth.ict import random_expression
    from geoface.track import facemesh_points

    rng = np.random.default_rng([seed, 8801])
    person = ICTPerson(rng, res=res)
    names = person.model.expression_names
    out = []
    for k in range(n):
        expr = {} if k % 4 == 0 else random_expression(rng, names, count=int(rng.integers(1, 5)), strength=0.8)
        ang = np.radians([rng.uniform(-35, 35), rng.uniform(-15, 15), rng.uniform(-10, 10)]) * (k > 0)
        R = euler_rotation(*ang)
        V, rgb, alpha, _ = person.render(expr, R, rng.normal(0, 0.005, 3))
        img = np.round(np.clip(rgb * (alpha[..., None] > 0.5), 0, 1) * 255).astype(np.uint8)
        # the direction to the camera in the head's own (canonical) frame
        centre = V[person.rest.landmarks].mean(0)
        eye = -person.cam.R.T @ person.cam.t
        d = R.T @ (eye - centre)
        out.append((V, facemesh_points([img], video=False, quiet=True)[0], d / np.linalg.norm(d)))
    return person, out


def hits(person, V, pts):
    """(triangle [468] (−1: missed), barycentric [468, 3]) where the rays through ``pts`` meet ``V``."""
    from geoface.mesh.raster import rasterize_mesh

    F, cam = person.rest.F, person.cam
    face, _, _ = rasterize_mesh(V, F, cam)
    tri = np.full(len(pts), -1)
    bary = np.zeros((len(pts), 3))
    origin = -cam.R.T @ cam.t
    for i, (x, y) in enumerate(pts):
        if not np.isfinite([x, y]).all():
            continue
        c, r = int(np.floor(x)), int(np.floor(y))
        if not (0 <= r < cam.height and 0 <= c < cam.width) or face[r, c] < 0:
            continue
        f = int(face[r, c])
        d = cam.R.T @ np.array([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0])
        a, b, cc = V[F[f]]
        n = np.cross(b - a, cc - a)
        X = origin + d * float(n @ (a - origin)) / float(n @ d)
        # barycentric weights of X in (a, b, cc)
        T = np.column_stack([b - a, cc - a])
        uv = np.linalg.lstsq(T, X - a, rcond=None)[0]
        tri[i], bary[i] = f, [1 - uv.sum(), uv[0], uv[1]]
    return tri, bary


def _head_rotation(person, V):
    """The rotation that posed ``V`` (Kabsch against the person's rest head)."""
    from scipy.spatial.transform import Rotation

    A = person.V0 - person.V0.mean(0)
    return Rotation.align_vectors(V - V.mean(0), A)[0].as_matrix()


def canonical(person, tri, bary):
    Vn = person.model.view(("skin", "eyes", "teeth", "mouth")).neutral  # the mean neutral head (cm)
    out = np.full((len(tri), 3), np.nan)
    ok = tri >= 0
    out[ok] = np.einsum("kj,kjd->kd", bary[ok], Vn[person.rest.F[tri[ok]]])
    return out


def view_features(d) -> np.ndarray:
    """The view's features (the direction to the camera in the head's frame): (dx, dy, dx², dy², dx·dy)."""
    d = np.atleast_2d(d)
    return np.stack([d[:, 0], d[:, 1], d[:, 0] ** 2, d[:, 1] ** 2, d[:, 0] * d[:, 1]], 1)


def evaluate(table_tri, table_bary, people, F, coef=None):
    """Reprojection of the table's points on the true posed heads against MediaPipe's; with
    ``coef`` (468, 5, 3) cm the view-dependent offsets (turned with the head) added."""
    errs, errs_v, iods = [], [], []
    for person, shots in people:
        cam = person.cam
        lm = person.rest.landmarks
        for V, pts, d in shots:
            ok = np.isfinite(pts).all(1)
            if not ok.any():
                continue
            P = np.einsum("kj,kjd->kd", table_bary, V[F[table_tri]])
            if coef is not None:  # the offsets live in the head's frame: turn them as the head is turned
                R = _head_rotation(person, V)
                P = P + (np.einsum("f,kfd->kd", view_features(d)[0], coef) * 0.01) @ R.T
            Q = V[F[table_tri, np.argmax(table_bary, 1)]]  # the nearest vertex of the triangle
            uv, uvv = cam.project(P)[0], cam.project(Q)[0]
            iod = float(np.linalg.norm(np.subtract(*cam.project(V[lm[[36, 45]]])[0])))
            errs.append(np.linalg.norm(uv - pts, axis=1)[ok])
            errs_v.append(np.linalg.norm(uvv - pts, axis=1)[ok])
            iods.append(np.full(int(ok.sum()), iod))
    e, ev, io = np.concatenate(errs), np.concatenate(errs_v), np.concatenate(iods)
    return {"mean_px": float(e.mean()), "p95_px": float(np.percentile(e, 95)), "mean_over_iod": float((e / io).mean()),
            "nearest_vertex_mean_px": float(ev.mean()), "points": int(len(e))}


def main(argv=None) -> int:
    import igl
    import trimesh

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--renders", type=int, default=30, help="pictures per person")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--out", default=str(ROOT / "geoface/data/mediapipe_ict.json"))
    a = ap.parse_args(argv)
    data = {s: [renders(seed, a.renders if s == "train" else a.renders // 2, a.res) for seed in seeds]
            for s, seeds in SPLITS.items()}
    person0 = data["train"][0][0]
    F = person0.rest.F
    lab = person0.rest.labels
    places, views = [], []
    for person, shots in data["train"]:
        for V, pts, d in shots:
            places.append(canonical(person, *hits(person, V, pts)))
            views.append(d)
    places = np.stack(places)  # [pictures, 468, 3] cm
    views = np.stack(views)
    seen = np.isfinite(places).all(2)
    med = np.nanmedian(places, axis=0)
    spread = np.sqrt(np.nanmean(np.sum((places - med) ** 2, axis=2), axis=0)) * 10.0  # mm
    face_tris = np.flatnonzero(np.isin(lab[F], FACE_LABELS).all(1))
    Vn = person0.model.view(("skin", "eyes", "teeth", "mouth")).neutral
    sq, tid, closest = igl.point_mesh_squared_distance(np.ascontiguousarray(med), np.ascontiguousarray(Vn, np.float64),
                                                       np.ascontiguousarray(F[face_tris], np.int64))
    dist = np.sqrt(sq)
    tri = face_tris[tid]
    bary = trimesh.triangles.points_to_barycentric(Vn[F[tri]], closest)
    bary = np.clip(bary, 0, None)
    bary /= bary.sum(1, keepdims=True)
    # where MediaPipe puts a point moves with the view (its points slide as the head turns: the
    # face's outline most): per point, the canonical place's offset from the table's point as a
    # quadratic in the view direction (ridge least squares over the training pictures)
    Phi = view_features(views)
    P0 = np.einsum("kj,kjd->kd", bary, Vn[F[tri]])
    coef = np.zeros((468, Phi.shape[1], 3))
    resid_spread = np.zeros(468)
    for k in range(468):
        okk = seen[:, k]
        A, B = Phi[okk], places[okk, k] - P0[k]
        if len(A) < 10:
            continue
        coef[k] = np.linalg.solve(A.T @ A + 1e-3 * len(A) * np.eye(A.shape[1]), A.T @ B)
        resid_spread[k] = np.sqrt(np.mean(np.sum((B - A @ coef[k]) ** 2, 1))) * 10.0
    weight = 1.0 / (1.0 + (resid_spread / 5.0) ** 2)
    report = {}
    for s in ("val", "test"):
        report[s] = evaluate(tri, bary, data[s], F)
        report[s + "_view"] = evaluate(tri, bary, data[s], F, coef)
        for key in (s, s + "_view"):
            print(json.dumps({"split": key, **{k: round(v, 4) for k, v in report[key].items()}}), flush=True)
    doc = {"vertices": F[tri].tolist(), "weights": np.round(bary, 6).tolist(), "confidence": np.round(weight, 4).tolist(),
           "view_offsets_cm": np.round(coef, 5).tolist(), "view_features": "dx, dy, dx^2, dy^2, dx*dy",
           "spread_mm": np.round(spread, 3).tolist(), "spread_after_view_mm": np.round(resid_spread, 3).tolist(), "seen": seen.sum(0).tolist(),
           "parts": ["skin", "eyes", "teeth", "mouth"], "model_vertices": int(len(Vn)),
           "fitted": f"data_tools/fit_mediapipe_ict.py --renders {a.renders} --res {a.res}",
           "people": {s: list(v) for s, v in SPLITS.items()}, **report,
           "snap_mm": {"median": round(float(np.median(dist) * 10), 3), "max": round(float(dist.max() * 10), 3)},
           "mediapipe": __import__("mediapipe").__version__}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(doc) + "\n")
    print(json.dumps({"wrote": a.out, "pictures": int(len(places)), "spread_mm_median": round(float(np.median(spread)), 3),
                      "snap_mm": doc["snap_mm"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
