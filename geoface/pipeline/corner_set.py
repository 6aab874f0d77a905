"""One corner set of the conversion (:func:`geoface.pipeline.convert`): Ricci flow → optimal
transport (or stay conformal) → geometry images → reconstruction, its error and the preview,
written into the set's folder; and carrying the mesh's per-vertex data and texture coordinates
over to the triangulation the flow ends on."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import GeofaceError
from ..mesh.core import bbox_diagonal, check_mesh, triple_keys
from ..mesh.io import first_corner_uv
from ..progress import log


#: a Ricci flow that stalls short of its tolerance is kept when its largest curvature error is
#: below this (radians): the floor of floating point on large, ill-conditioned scans, not a
#: failure to converge
RICCI_ACCEPT = 1e-6


@dataclass
class SetInputs:
    """What the corner sets of one ``convert`` share: the Ricci-flow solver of the disk, the
    disk's per-vertex positions, ROI and colours (a set whose flow splits boundary edges extends
    them, and the next set starts from there), the options, and, for the images: the repaired
    mesh with its texture (``disk``), the rotation into the stored frame, the scan under a proxy
    (``full``: :class:`geoface.pipeline.proxy.FullSurface`, which the images sample and the
    error report measures against) and the face found on it (``face``: ``meta.json``'s face)."""

    solver: Any
    V: np.ndarray
    roi: np.ndarray | None
    colors: np.ndarray | None
    opts: Any
    quiet: bool | None = None
    disk: Any = None
    stored: np.ndarray | None = None
    full: Any = None
    face: dict | None = None


def map_set(st, corners, s: SetInputs, pos=0, count=1):
    """The maps of one corner set: Ricci flow (conformal, a rectangle) then, with ``opts.method ==
    "ot"``, the measure-preserving map. Fills ``st`` (``ricci``, ``conformal_distortion``, ``ot``)
    and returns ``(r, V, roi, colors, uv)``: the flow's result, the per-vertex data extended where
    the flow split boundary edges, and the final UVs (``s`` is left as it is)."""
    from ..param.measure import measure_preserving_map
    from ..param.metrics import distortion

    solver, V, roi, colors, opts, quiet = s.solver, s.V, s.roi, s.colors, s.opts, s.quiet

    t = time.perf_counter()
    log(f"convert [{pos + 1}/{count}]: corner set {st['corner_set']}: Ricci flow, optimal transport, images", quiet=quiet)
    r = solver.solve(corners, quiet=quiet)
    if not r.converged:
        if not (np.isfinite(r.residual) and r.residual <= RICCI_ACCEPT):
            raise GeofaceError(f"Ricci flow did not converge (max |K - target| {r.residual:.3g})")
        # stalled at the floor of floating point on a hard scan, short of the solver's own
        # 1e-9: a curvature error this small moves no pixel; the metrics say so
        log(f"convert [{pos + 1}/{count}]: Ricci flow stopped at max |K - target| {r.residual:.2g} "
            f"(asked {solver.tolerance:g}); kept", quiet=quiet, detail=True)
    F = r.F
    if len(r.V) > len(V):  # boundary edges split by the flow: extend per-vertex data
        V, roi, colors = extend_split(r.V, r.split_edges, len(V), roi, colors)
    uv = r.unit_square()
    st["ricci"] = {"seconds": time.perf_counter() - t, "iterations": r.iterations, "residual": r.residual, "aspect": r.aspect,
                   "log_conformal_factor_range": float(r.u.max() - r.u.min()), "intrinsic_flips": r.intrinsic_flips,
                   "converged": bool(r.converged)}
    st["conformal_distortion"] = distortion(V, F, uv).summary()
    if opts.method == "ot":
        t = time.perf_counter()
        log(f"convert [{pos + 1}/{count}]: optimal transport (lam {opts.lam:g}, blend {opts.blend:g}, feature {opts.feature:g})",
            quiet=quiet, detail=True)
        mp = measure_preserving_map(V, F, uv, roi=roi, lam=opts.lam, blend=opts.blend, feature=opts.feature, tol=opts.ot_tol,
                                    quiet=quiet)
        uv = mp.uv
        st["ot"] = {
            "seconds": time.perf_counter() - t, "lam": opts.lam, "blend": opts.blend, "feature": opts.feature, "path": mp.path, "sites": mp.sites, "restarts": mp.restarts,
            "converged": mp.converged,
            "residual": mp.residual, "iterations": mp.ot.iterations if mp.ot else 0, "halvings": mp.ot.halvings if mp.ot else 0,
            "stages": mp.ot.stages if mp.ot else 0, "gradient_steps": mp.ot.gradient_steps if mp.ot else 0,
            "power_diagrams": mp.ot.backend if mp.ot else None, "attempts": mp.attempts,
            "balanced": None if mp.balanced is None else {
                "rounds": mp.balanced.best_round, "start_max_log_ratio": mp.balanced.start_max_log_ratio,
                "max_log_ratio": mp.balanced.max_log_ratio},
            "flipped_before": mp.flipped_before, "flipped_after": mp.flipped_after,
            "area_error_before": mp.area_error_before, "area_error_after": mp.area_error_after,
            "fitted_vertices": mp.fold_free.fitted_vertices if mp.fold_free else 0,
            "boundary_adjusted": mp.fold_free.boundary_adjusted if mp.fold_free else 0,
            "max_displacement": mp.fold_free.max_displacement if mp.fold_free else 0.0,
            "fold_free_solve": mp.fold_free.solve if mp.fold_free else None,
        }
    return r, V, roi, colors, uv


def convert_set(st, folder, corners, s: SetInputs, pos=0, count=1, mapped=None) -> None:
    """One corner set: Ricci flow → OT → images → reconstruction, into ``folder``; fills ``st``
    and extends ``s``'s per-vertex data where the flow split boundary edges. The face's
    landmarks (``s.face``) get where they land in this set's images. ``mapped``: ``(st entries,
    map_set's result)`` of these corners, made already."""
    from ..gimage import geometry_image, reconstruct, save_reconstruction
    from ..gimage.image import write_gimage_files
    from ..gimage.raster import interpolate, rasterize_faces
    from ..param.metrics import distortion

    opts, quiet, dm, stored, full, face = s.opts, s.quiet, s.disk, s.stored, s.full, s.face
    if mapped is None:
        r, V, roi, colors, uv = map_set(st, corners, s, pos, count)
    else:
        st.update(mapped[0])
        r, V, roi, colors, uv = mapped[1]
    s.V, s.roi, s.colors = V, roi, colors
    F = r.F
    st["distortion"] = distortion(V, F, uv).summary()
    t = time.perf_counter()
    log(f"convert [{pos + 1}/{count}]: geometry images {opts.res}x{opts.res}", quiet=quiet, detail=True)
    kw: dict = {}
    if dm.texture is not None and dm.UV is not None:
        UVx, FUVx = corner_uvs_for(F, dm.F, dm.UV, dm.FUV, split_edges=r.split_edges)
        kw = {"texture": dm.texture, "tex_uv": UVx, "tex_fuv": FUVx}
    elif colors is not None:
        kw = {"colors": colors}
    # statistics to 6 significant digits: floating-point noise (~1e-12, from memory
    # alignment in vectorised sums) must not change the file's bytes between runs
    meta = {"corners": st["corners"], "method": opts.method, "lam": opts.lam if opts.method == "ot" else None,
            "blend": opts.blend if opts.method == "ot" else None,
            "feature": opts.feature if opts.method == "ot" else None,
            "param": {k: float(f"{v:.6g}") if isinstance(v, float) else v for k, v in st["distortion"].items()},
            # positions and normals are stored upright (x right, y up, z front); to_input turns them back
            "frame": {"to_input": [[float(f"{x:.12g}") for x in row] for row in stored.T]}}
    if face is not None:
        meta["face"] = dict(face["meta"], **face_pixels(face["points"], V, F, uv, opts.res))
        st["face_pixels"] = {k: meta["face"][k] for k in ("eye_line_degrees", "center_offset")}
    fid, bary = rasterize_faces(F, uv, opts.res, align_corners=True)
    if full is None:
        gi = geometry_image(V @ stored.T, F, uv, opts.res, meta=meta, raster=(fid, bary), **kw)
    else:
        gi, st["scan_pixel_share"] = _scan_gimage(full, V, F, uv, fid, bary, stored, meta)
    face_img = None
    if roi is not None:
        face_img = interpolate(fid, bary, F, roi.astype(float))[0] > 0.5
        st["roi_pixel_share"] = float(face_img[gi.mask].mean())
    st["coverage"] = float(gi.mask.mean())
    write_gimage_files(folder, gi)
    if face_img is not None:  # where the ROI (the magnified face) lies in the images
        from .._io import write_image

        write_image(folder / "roi.png", (face_img & gi.mask).astype(np.uint8) * 255)
    st["images_seconds"] = time.perf_counter() - t
    if opts.reconstruct:
        t = time.perf_counter()
        log(f"convert [{pos + 1}/{count}]: reconstruction", quiet=quiet, detail=True)
        rec = reconstruct(gi, smooth=opts.smooth)
        save_reconstruction(folder / "reconstruction.obj", rec, gi)
        rec_mask = None
        if face_img is not None:  # each reconstructed vertex sits at a pixel centre
            N = opts.res
            jj = np.clip(np.round(rec.UV[:, 0] * N - 0.5).astype(int), 0, N - 1)
            ii = np.clip(np.round((1.0 - rec.UV[:, 1]) * N - 0.5).astype(int), 0, N - 1)
            rec_mask = face_img[ii, jj]
        st["reconstruction"] = {"vertices": int(len(rec.V)), "faces": int(len(rec.F))}
        if full is None:
            st["reconstruction"].update(reconstruction_error(V, F, rec.V, rec.F, ref_mask=roi, rec_mask=rec_mask))
        else:
            # without smoothing the reconstruction's vertices are the covered pixels' positions, in
            # their order: their distances to the scan are bounded by the sampling's
            st["reconstruction"].update(full.error(rec.V, rec.F, rec_mask=rec_mask,
                                                    sampled=opts.smooth == 0 and np.array_equal(gi.mask, fid >= 0)))
        st["reconstruction"]["seconds"] = time.perf_counter() - t
    if opts.preview:
        _preview(gi, folder / "preview.png")


#: the corner sets are turned until the face's eye line in the default image is within this many
#: degrees of level (:func:`level_turn`; the images themselves are judged at ±3°)
LEVEL_TARGET = 0.5


#: a secant step of the level search that would turn the corners further than this share of the
#: boundary (an eighth) is not a small correction: the search stops there
MAX_LEVEL_TURN = 0.125


def level_turn(tilt, first: float, *, target: float = LEVEL_TARGET, tries: int = 3) -> dict:
    """The turn of the corner sets (a share of the boundary's length, :func:`geoface.param.corners.corner_sets`)
    that brings a face's eye line level in the default image: a boundary that is not
    mirror-symmetric about the face (a bust's shoulders, a coarse neck cut, a torso) and the
    measure's pull turn the face in the image, and turning the corners along the boundary turns it
    back (a whole turn of the boundary turns the image once round). ``tilt(turn)``: the eye line's
    angle (degrees) in the final map of corner set 0 turned so, or None where it fails (a caller
    that memoises it by the corners a turn picks makes a turn too small to move them free);
    ``first``: ``tilt(0)``. Secant steps from the first prediction ``first / 360``, at most
    ``tries``, while the line is more than ``target`` off: two heads that differ by a little
    (a copy turned in space) get turns that differ by a little. ``{"turn", "eye_line_before",
    "eye_line_after", "tries"}``."""
    out = {"turn": 0.0, "eye_line_before": first, "eye_line_after": first, "tries": 0}
    if first is None or abs(first) <= target:
        return out
    best = (abs(first), 0.0, first)
    x0, y0, x1 = 0.0, first, first / 360.0
    for k in range(tries):
        y1 = tilt(x1)
        out["tries"] = k + 1
        if y1 is None:
            break
        if abs(y1) < best[0]:
            best = (abs(y1), x1, y1)
        if abs(y1) <= target or y1 == y0:
            break
        x0, y0, x1 = x1, y1, x1 - y1 * (x1 - x0) / (y1 - y0)
        if abs(x1) > MAX_LEVEL_TURN:
            break
    out.update(turn=best[1], eye_line_after=best[2])
    return out


def face_pixels(points, V, F, uv, N) -> dict:
    """Where face landmarks ``points (k, 3)`` (the 68 iBUG, NaN where unknown; or the detector's
    four key points) land in the ``N``² images of the map ``uv`` of ``(V, F)``: each at the closest
    point of the surface, carried through the map. ``{"pixels": [[x (column), y (row)] or None],
    "eye_line_degrees": the line from the subject's right eye to the left (each eye the midpoint of
    its corners) against the image rows (positive: the left eye higher), "center_offset": the eyes' and the mouth's centre's column
    from the image's middle, over the width}``."""
    from ..gimage.raster import uv_to_pixel
    from ..track.face3d import keypoints_of
    from ..uvmap.bake import closest_points

    P = np.asarray(points, np.float64)
    ok = np.isfinite(P).all(1)
    px = np.full((len(P), 2), np.nan)
    if ok.any():
        _, f, b = closest_points(P[ok], V, F)
        q = np.einsum("kj,kjd->kd", b, uv[F[f]])
        x, y = uv_to_pixel(q, N, True)
        px[ok] = np.column_stack([x, y])
    K = keypoints_of(px) if len(P) == 68 else px  # (right eye, left eye, nose, mouth) in pixels
    if len(P) == 68:  # the eye line through the eyes' corners: a blink or a wink moves the lids, not them
        K[0], K[1] = px[[36, 39]].mean(0), px[[42, 45]].mean(0)
    eye = float(np.degrees(np.arctan2(-(K[1, 1] - K[0, 1]), K[1, 0] - K[0, 0])))
    center = float((0.25 * (K[0, 0] + K[1, 0]) + 0.5 * K[3, 0]) / (N - 1) - 0.5)
    r = lambda v: None if not np.isfinite(v) else round(float(v), 3)  # noqa: E731
    return {"pixels": [[r(a), r(b)] if np.isfinite(a) else None for a, b in px], "eye_line_degrees": r(eye),
            "center_offset": r(center)}


def _scan_gimage(full, V, F, uv, fid, bary, stored, meta):
    """The geometry image of a proxy's map with every pixel's position, normal and colour taken
    from the scan (``full``); and the share of pixels that moved onto it."""
    from ..gimage import gimage_from_samples
    from ..gimage.raster import interpolate
    from ..mesh.core import signed_uv_areas, vertex_normals

    mask = fid >= 0
    P = interpolate(fid, bary, F, V).transpose(1, 2, 0)[mask]
    Np = interpolate(fid, bary, F, vertex_normals(V, F)).transpose(1, 2, 0)[mask]
    Q, Nn, C, share = full.sample(P, Np)

    def image(a):
        out = np.zeros((*mask.shape, 3))
        out[mask] = a
        return out

    gi = gimage_from_samples(image(Q @ stored.T), image(Nn @ stored.T), mask, None if C is None else image(C),
                             uv_orientation=1 if signed_uv_areas(F, uv).sum() >= 0 else -1, meta=meta)
    return gi, share


def extend_split(V_new, split_edges, n_old, roi, colors):
    """Per-vertex data for vertices appended as edge midpoints (``split_edges``, in order)."""
    k = len(V_new) - n_old
    edges = np.asarray(split_edges)[-k:]
    for a, b in edges.tolist():
        if roi is not None:
            roi = np.append(roi, roi[a] and roi[b])
        if colors is not None:
            colors = np.concatenate([colors, (0.5 * (colors[a].astype(np.float64) + colors[b])).astype(colors.dtype)[None]])
    return V_new, roi, colors


def corner_uvs_for(F_new: np.ndarray, F_old: np.ndarray, UV: np.ndarray, FUV: np.ndarray, split_edges=None):
    """Texture coordinates for the faces ``F_new`` of a re-triangulated mesh: faces that
    exist in ``F_old`` keep their corner UVs (seams survive); others use one UV per vertex.
    ``split_edges (k, 2)``: vertices appended after ``F_old``'s, each the midpoint of an
    edge (their UV is the midpoint's).  Returns ``(UV_ext, FUV_new)``."""
    n = int(max(F_new.max(), F_old.max())) + 1

    def keys(F):
        r = np.argmin(F, axis=1)  # rotate so the smallest index is first (orientation kept)
        G = np.stack([F[np.arange(len(F)), (r + k) % 3] for k in range(3)], 1)
        return G, r

    (Go, ro), (Gn, rn) = keys(F_old), keys(F_new)
    ko, kn = triple_keys(Go, Gn, n=n)
    order = np.argsort(ko)
    pos = np.searchsorted(ko[order], kn)
    pos = np.minimum(pos, len(ko) - 1)
    hit = ko[order][pos] == kn
    src = order[pos]
    vert_uv = first_corner_uv(F_old, FUV, n)
    UV_ext = np.concatenate([UV, np.zeros((1, 2))])
    if split_edges is not None and len(split_edges):
        base = n - len(split_edges)
        for i, (a, b) in enumerate(np.asarray(split_edges).tolist()):  # in order: may chain
            ua = UV_ext[vert_uv[a]] if vert_uv[a] >= 0 else UV_ext[-1]
            ub = UV_ext[vert_uv[b]] if vert_uv[b] >= 0 else UV_ext[-1]
            UV_ext = np.concatenate([UV_ext[:-1], [0.5 * (ua + ub)], UV_ext[-1:]])
            vert_uv[base + i] = len(UV_ext) - 2
    fallback = np.where(vert_uv[F_new] >= 0, vert_uv[F_new], len(UV_ext) - 1)
    FUV_new = fallback.copy()
    # matching faces: corner k of F_new[f] is corner (k + rn - ro) of F_old[src]
    f = np.flatnonzero(hit)
    for k in range(3):
        FUV_new[f, k] = FUV[src[f], (k + rn[f] - ro[src[f]]) % 3]
    return UV_ext, FUV_new


def reconstruction_error(V_ref, F_ref, V_rec, F_rec, *, ref_mask=None, rec_mask=None) -> dict:
    """Two-sided vertex-to-surface distances between two meshes, divided by the reference's
    bounding-box diagonal: Hausdorff (max of both sides) and mean (of both sides).  With
    masks, also the same restricted to masked vertices (``face_*``)."""
    from .._lazy import lazy_import

    igl = lazy_import("igl", "reconstruction error")
    V_ref, F_ref = check_mesh(V_ref, F_ref)
    V_rec, F_rec = check_mesh(V_rec, F_rec)
    diag = bbox_diagonal(V_ref)
    d_rec = np.sqrt(igl.point_mesh_squared_distance(V_rec, V_ref, F_ref)[0]) / diag
    d_ref = np.sqrt(igl.point_mesh_squared_distance(V_ref, V_rec, F_rec)[0]) / diag
    out = {
        "hausdorff": float(max(d_rec.max(), d_ref.max())),
        "mean": float(0.5 * (d_rec.mean() + d_ref.mean())),
        "rec_to_ref_max": float(d_rec.max()),
        "ref_to_rec_max": float(d_ref.max()),
    }
    if ref_mask is not None and rec_mask is not None and ref_mask.any() and rec_mask.any():
        a, b = d_rec[rec_mask], d_ref[ref_mask]
        out["face_hausdorff"] = float(max(a.max(), b.max()))
        out["face_mean"] = float(0.5 * (a.mean() + b.mean()))
    return out


def _preview(gi, path: Path) -> None:
    from ..gimage.image import MODALITIES, import_cv2

    cv2 = import_cv2()
    N = gi.resolution
    size = min(N, 384)
    tiles = []
    for name in MODALITIES:
        if gi.has(name):
            t = np.round(gi.modality(name).transpose(1, 2, 0) * 255).astype(np.uint8)[:, :, ::-1]
            tiles.append(cv2.resize(t, (size, size), interpolation=cv2.INTER_AREA))
    m = np.repeat((gi.mask.astype(np.uint8) * 255)[:, :, None], 3, 2)
    tiles.append(cv2.resize(m, (size, size), interpolation=cv2.INTER_NEAREST))
    gap = np.full((size, 4, 3), 255, np.uint8)
    row = tiles[0]
    for t in tiles[1:]:
        row = np.concatenate([row, gap, t], 1)
    from .._io import write_image

    write_image(path, row)
