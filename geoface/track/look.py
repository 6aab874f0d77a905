"""Looking at a mesh as a camera would: grey renders, pixels lifted back onto the surface, and
MediaPipe's face detector and face mesh run on the renders (:class:`Looker`). The search for a
face on a scan (:mod:`geoface.track.scan`) is built from these."""
from __future__ import annotations

import numpy as np

__all__ = ["render_grey", "face_cross", "lift", "Looker", "camera_at", "principal_frame", "search_views", "turn", "unit", "unrotate",
           "STYLES", "FOV"]

#: field of view of every render (degrees): a portrait lens
FOV = 30.0
#: the search looks at a copy decimated to this many faces
COARSE_FACES = 12000
#: how the refined views are drawn, tried in turn while the face mesh finds no face (its own
#: detector is fussier than the full-range one): (the view's width over the default, background
#: grey, a second light above the camera, a pitch of the view in degrees)
STYLES = ((1.0, 0.0, False, 0.0), (1.6, 0.35, True, 0.0), (1.0, 0.35, True, 0.0), (1.6, 0.0, False, 0.0),
          (1.3, 0.35, True, -12.0), (1.3, 0.35, True, 12.0))


def unit(v) -> np.ndarray:
    """``v`` over its length."""
    v = np.asarray(v, np.float64)
    return v / max(float(np.linalg.norm(v)), 1e-300)


def face_cross(V, F) -> np.ndarray:
    """Each face's edge cross product ``(V1 - V0) × (V2 - V0)`` (twice its area along its normal),
    ``(m, 3)``: what :func:`render_grey` shades with, which a caller rendering one mesh many
    times computes once."""
    return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])


def _vertex_normals_towards(V, F, toward, cross=None):
    """Area-weighted vertex normals with every face's normal turned towards ``toward`` (a scan's
    faces may be oriented either way; shading is two-sided); ``cross``: :func:`face_cross` of
    ``(V, F)``, when the caller has it."""
    n = face_cross(V, F) if cross is None else cross
    n = n * np.where(n @ toward < 0, -1.0, 1.0)[:, None]
    idx = F.T.ravel()
    vn = np.column_stack([np.bincount(idx, np.tile(n[:, c], 3), minlength=len(V)) for c in range(3)])
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)


def render_grey(V, F, camera, *, background: float = 0.0, key=None, cross=None):
    """A grey render of the mesh through ``camera`` (:class:`geoface.camera.Camera`): smooth
    two-sided Lambert shading lit from the camera, as a plaster cast under a flash; with ``key``
    (a direction towards a second light, e.g. above the camera), half the light comes from there.
    ``background``: the grey level where no surface is (0 black, 1 white); ``cross``: the faces'
    :func:`face_cross`, when the caller keeps it (the same image, sooner). Returns
    ``(image (H, W, 3) uint8, face (H, W) int64 (-1: background), depth (H, W) camera z, inf on
    the background)``."""
    from geoface.mesh.raster import rasterize_mesh

    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    face, bary, depth = rasterize_mesh(V, F, camera)
    C = camera.center
    hit = face >= 0
    img = np.full(face.shape, background, np.float64)
    if hit.any():
        view = unit(C - V.mean(0))
        vn = _vertex_normals_towards(V, F, view, cross)
        f = face[hit]
        n = np.einsum("pk,pkd->pd", bary[hit], vn[F[f]])
        P = np.einsum("pk,pkd->pd", bary[hit], V[F[f]])
        d = C - P
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        lam = np.abs((n * d).sum(1))
        if key is not None:
            lam = 0.5 * lam + 0.5 * np.clip(np.abs(n @ unit(key)) * np.sign((n * d).sum(1)) * np.sign(n @ unit(key)), 0, None)
        img[hit] = 0.12 + 0.83 * lam
    img8 = np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)
    return np.repeat(img8[..., None], 3, axis=2), face, depth


def lift(points2d, camera, face, V, F, *, depth=None, window: int = 0, gap: float = np.inf) -> np.ndarray:
    """Pixels ``points2d (k, 2)`` (x right, y down; pixel centres at +0.5, as MediaPipe's and the
    camera's) of a render onto the surface: the ray through each pixel cut with the triangle that
    the render shows there (``face``: :func:`render_grey`'s), ``(k, 3)``; NaN where the pixel shows
    no triangle or lies outside the image.

    ``depth (H, W)`` (the render's z-buffer), ``window`` and ``gap``: where the pixel looks through
    a slit or a hole (an eyelid's seam, a nostril: deeper by more than ``gap`` than the nearest
    surface within ``window`` pixels), the ray is cut with that nearest surface's triangle instead."""
    p = np.asarray(points2d, np.float64).reshape(-1, 2)
    out = np.full((len(p), 3), np.nan)
    H, W = face.shape
    ok = np.isfinite(p).all(1)
    col = np.where(ok, np.floor(np.nan_to_num(p[:, 0])), -1).astype(np.int64)
    row = np.where(ok, np.floor(np.nan_to_num(p[:, 1])), -1).astype(np.int64)
    ok &= (col >= 0) & (col < W) & (row >= 0) & (row < H)
    f = np.full(len(p), -1, np.int64)
    f[ok] = face[row[ok], col[ok]]
    if depth is not None and window > 0:
        for i in np.flatnonzero(ok):
            r0, r1 = max(row[i] - window, 0), min(row[i] + window + 1, H)
            c0, c1 = max(col[i] - window, 0), min(col[i] + window + 1, W)
            win = depth[r0:r1, c0:c1]
            k = int(np.argmin(win))
            if np.isfinite(win.flat[k]) and not (depth[row[i], col[i]] <= win.flat[k] + gap):
                f[i] = face[r0 + k // (c1 - c0), c0 + k % (c1 - c0)]
    ok &= f >= 0
    if not ok.any():
        return out
    C = camera.center
    dirs = np.column_stack([(p[ok, 0] - camera.cx) / camera.fx, (p[ok, 1] - camera.cy) / camera.fy, np.ones(ok.sum())])
    dirs = dirs @ camera.R  # camera -> world (R is world -> camera)
    A, B, Cc = V[F[f[ok], 0]], V[F[f[ok], 1]], V[F[f[ok], 2]]
    n = np.cross(B - A, Cc - A)
    denom = (n * dirs).sum(1)
    t = ((n * (A - C)).sum(1)) / np.where(np.abs(denom) > 1e-300, denom, 1e-300)
    X = C + t[:, None] * dirs
    good = np.isfinite(X).all(1) & (t > 0)
    idx = np.flatnonzero(ok)
    out[idx[good]] = X[good]
    return out


def camera_at(center, front, up, half_width, res):
    """A camera on ``front`` of ``center``, ``up`` at the top, the square of ``half_width`` about
    ``center`` filling the ``res``² image."""
    from geoface.camera import look_at

    dist = half_width / np.tan(np.radians(FOV) / 2)
    return look_at(center + dist * front, center, up, width=res, height=res, fov_y_deg=FOV)


def principal_frame(V, F):
    """Area centroid, the largest distance of a vertex from it, and the principal axes (columns,
    signs by the third moment) of the surface: the search's views are taken in it, so they turn
    with the scan."""
    from geoface.mesh.core import face_areas

    A = face_areas(V, F)
    Cf = V[F].mean(1)
    w = A / max(A.sum(), 1e-300)
    c = (w[:, None] * Cf).sum(0)
    X = Cf - c
    _, E = np.linalg.eigh((w[:, None, None] * np.einsum("ni,nj->nij", X, X)).sum(0))
    E = E * np.where((w[:, None] * (X @ E) ** 3).sum(0) < 0, -1.0, 1.0)
    if np.linalg.det(E) < 0:
        E[:, 0] = -E[:, 0]
    return c, float(np.linalg.norm(V[np.unique(F)] - c, axis=1).max()), E


def search_views() -> np.ndarray:
    """The 26 unit directions of the search (the cube's faces, edges and corners), ``(26, 3)``."""
    g = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)], float)
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def any_up(d) -> np.ndarray:
    """Some unit direction orthogonal to ``d`` (the search's views have no up)."""
    a = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    return unit(a - (a @ d) * d)


def turn(front, up, yaw, pitch):
    """``front`` and ``up`` turned by ``yaw`` degrees about ``up``, then ``pitch`` about the right."""
    from geoface.rotations import rodrigues

    R = rodrigues(np.radians(pitch) * np.cross(up, front)) @ rodrigues(np.radians(yaw) * up)
    return unit(R @ front), unit(R @ up)


class Looker:
    """The mesh, MediaPipe's face detectors (full and short range) and its static face mesh, built
    once per search; counts the renders. A context manager: MediaPipe's graphs write their set-up
    chatter (TFLite delegates, feedback tensors) to file descriptor 2 from their own threads, at
    their first runs, so the descriptor is held from set-up to close (as the tracker holds it)."""

    def __init__(self, V, F):
        self.V, self.F, self.renders = V, F, 0
        self._full = (V, F)
        self._hold = None
        self._cross = None  # (V, F, face_cross(V, F)) of the mesh looked at

    def __enter__(self):
        from geoface.track import load_mediapipe, quiet_native_stderr

        mp = load_mediapipe()
        self._hold = quiet_native_stderr()
        self._hold.__enter__()
        try:
            self.det = mp.solutions.face_detection.FaceDetection(model_selection=1, min_detection_confidence=0.3)
            self.near = mp.solutions.face_detection.FaceDetection(model_selection=0, min_detection_confidence=0.3)
            self.mesh = mp.solutions.face_mesh.FaceMesh(static_image_mode=True, max_num_faces=1, refine_landmarks=False,
                                                        min_detection_confidence=0.3)
        except BaseException:
            self._hold.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc):
        try:
            for g in (self.det, self.near, self.mesh):
                g.close()
        finally:
            self._hold.__exit__(None, None, None)
        return False

    def coarse(self, faces: int = COARSE_FACES) -> None:
        """Look at a decimated copy from now on (at most ``faces`` faces: quadric edge collapse by
        fast-simplification, where installed): the search's many small renders need no more."""
        V, F = self._full
        if len(F) > faces:
            try:
                import fast_simplification as fs
            except ImportError:
                return
            c = 0.5 * (V.min(0) + V.max(0))  # the simplifier works in float32: centred first
            V1, F1 = fs.simplify((V - c).astype(np.float32), F.astype(np.int32), target_reduction=1.0 - faces / len(F))
            if len(F1):
                self.V, self.F = np.asarray(V1, np.float64) + c, np.asarray(F1, np.int64)

    def focus(self, center, radius: float) -> None:
        """Look at the full mesh's faces with a corner within ``radius`` of ``center`` from now on
        (a view of the face sees nothing else)."""
        V, F = self._full
        near = np.linalg.norm(V - np.asarray(center, np.float64), axis=1) <= radius
        keep = near[F].any(1)
        self.V, self.F = V, (F[keep] if keep.sum() >= 100 else F)

    def render(self, camera, style=None):
        """A grey render (:func:`render_grey`) in a ``style`` of :data:`STYLES` (None: the first)."""
        self.renders += 1
        st = STYLES[0] if style is None else style
        key = None if not st[2] else unit(camera.R.T @ np.array([0.0, -1.0, -1.0]))  # above the camera
        if self._cross is None or self._cross[0] is not self.V or self._cross[1] is not self.F:
            self._cross = (self.V, self.F, face_cross(np.asarray(self.V, np.float64), np.asarray(self.F, np.int64)))
        return render_grey(self.V, self.F, camera, background=st[1], key=key, cross=self._cross[2])

    def _run(self, graph, img):
        return graph.process(np.ascontiguousarray(img))

    def detect_all(self, img, *, near: bool = False):
        """Every face the detector finds: ``[(score, key points (6, 2) px, box (x0, y0, w, h) px)]``;
        ``near``: the short-range model's (a face filling much of the image) instead of the full-range's."""
        r = self._run(self.near if near else self.det, img)
        H, W = img.shape[:2]
        out = []
        for d in r.detections or []:
            kp = np.array([[p.x * W, p.y * H] for p in d.location_data.relative_keypoints])
            b = d.location_data.relative_bounding_box
            out.append((float(d.score[0]) if d.score else 0.0, kp, np.array([b.xmin * W, b.ymin * H, b.width * W, b.height * H])))
        return out

    def detect(self, img):
        """(score, key points (6, 2) px, box (x0, y0, w, h) px) of the best face either model finds
        (a face framed close, as the refined views frame it, can be too near for the full-range
        model), or None."""
        return max(self.detect_all(img) + self.detect_all(img, near=True), key=lambda x: x[0], default=None)

    def face_mesh(self, img):
        """MediaPipe's 468 face-mesh points in pixels, ``(468, 2)``, or None."""
        r = self._run(self.mesh, img)
        if not r.multi_face_landmarks:
            return None
        H, W = img.shape[:2]
        return np.array([[p.x * W, p.y * H] for p in r.multi_face_landmarks[0].landmark[:468]])


def unrotate(kp, k, W):
    """Key points found on ``np.rot90(img, k)`` (a square image of width ``W``) back in ``img``."""
    p = np.asarray(kp, np.float64).copy()
    for _ in range(k % 4):  # undo one counter-clockwise quarter turn: (x, y) in the turned image
        p = np.column_stack([W - p[:, 1], p[:, 0]])
    return p
