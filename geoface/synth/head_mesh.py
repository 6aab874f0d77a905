"""Meshing the procedural head: the parameter disk, rings stitched into triangles, landmark
snapping, tangential relaxation on the surface, and the texture's fine detail
(:mod:`geoface.synth.head`)."""
from __future__ import annotations

import numpy as np

from ..mesh.core import signed_uv_areas, vertex_adjacency, vertex_face_incidence
from .head_shape import sphere_dirs, gauss2, mix_colors, HeadShape, smoothstep
from .head_types import TWO_PI

class DiskParam:
    """Map between the parameter disk ``p`` (|p| <= 1) and the surface.

    ``(t, phi)``: ``t`` runs from the crown (0) to the neck cut (1) along the meridian of
    azimuth ``phi``; ``theta = t * theta_max(phi)`` with ``theta_max`` where that meridian
    crosses ``y = y_cut``.  ``rho(t, phi)`` is the normalised 3D arc length along the meridian
    and ``p = rho (sin phi, -cos phi)`` (the UV layout is ``0.5 + 0.49 p``).
    """

    t_ext = 1.04

    def __init__(self, shape: HeadShape, nt: int, nphi: int):
        self.shape = shape
        self.nt, self.nphi = nt, nphi
        phi = np.arange(nphi) * (TWO_PI / nphi)
        self.phi_grid = phi
        self.theta_max = self._theta_max(phi)
        t = np.linspace(0.0, self.t_ext, nt)
        self.t_grid = t
        X = shape.position(sphere_dirs(t[:, None] * self.theta_max[None, :], phi[None, :]).reshape(-1, 3)).reshape(nt, nphi, 3)
        seg = np.linalg.norm(np.diff(X, axis=0), axis=2)
        s = np.concatenate([np.zeros((1, nphi)), np.cumsum(seg, axis=0)], axis=0)
        i1 = int(np.searchsorted(t, 1.0))
        w = (1.0 - t[i1 - 1]) / (t[i1] - t[i1 - 1])
        self.L = s[i1 - 1] * (1 - w) + s[i1] * w
        self.rho_tab = s / self.L[None, :]
        self.rho_ext = float(self.rho_tab[-1].min()) - 1e-9
        self.nrho = nt
        rq = np.linspace(0.0, self.rho_ext, self.nrho)
        off = 4.0 * np.arange(nphi)                      # invert every column at once
        xp = (self.rho_tab + off[None, :]).T.ravel()
        xq = (rq[:, None] + off[None, :]).T.ravel()
        self.t_tab = np.interp(xq, xp, np.tile(t, nphi)).reshape(nphi, self.nrho).T
        self.X_grid = X
        # UV radius R(rho): a blend of linear and equal-area, so the face gets more texels
        self.uv_rho = np.linspace(0.0, 1.0, 257)
        curves = self.ring_curves(self.uv_rho)
        circ = np.linalg.norm(np.roll(curves, -1, axis=1) - curves, axis=2).sum(1)
        A = np.concatenate([[0.0], np.cumsum(0.5 * (circ[1:] + circ[:-1]) * np.diff(self.uv_rho))])
        self.area = float(A[-1] * self.L.mean())
        self.uv_R = 0.49 * (0.4 * self.uv_rho + 0.6 * np.sqrt(A / A[-1]))

    def ring_curves(self, rhos):
        """Approximate positions ``(len(rhos), nphi, 3)`` on the rings rho = const (grid interpolation)."""
        nphi, tg = self.nphi, self.t_grid
        T = self._bilinear(self.t_tab, self.rho_ext, np.repeat(rhos, nphi), np.tile(self.phi_grid, len(rhos)))
        f = np.clip(T, 0, tg[-1]) * ((self.nt - 1) / tg[-1])
        i0 = np.minimum(np.floor(f).astype(np.int64), self.nt - 2)
        u = (f - i0)[:, None]
        j = np.tile(np.arange(nphi), len(rhos))
        X = self.X_grid[i0, j] * (1 - u) + self.X_grid[i0 + 1, j] * u
        return X.reshape(len(rhos), nphi, 3)

    #: Moebius shift of the UV disk toward the face (magnifies the face about 1.5x, conformally)
    uv_shift = -0.45j

    def uv_of_p(self, p):
        rho = np.hypot(p[:, 0], p[:, 1])
        R = np.interp(rho, self.uv_rho, self.uv_R) / 0.49
        w = (p[:, 0] + 1j * p[:, 1]) * (R / np.maximum(rho, 1e-12))
        a = self.uv_shift
        z = (w - a) / (1.0 - np.conj(a) * w)
        return 0.5 + 0.49 * np.stack([z.real, z.imag], axis=1)

    def p_of_uv(self, uv):
        z = (uv[:, 0] - 0.5 + 1j * (uv[:, 1] - 0.5)) / 0.49
        a = self.uv_shift
        z = np.where(np.abs(z) > 1.0, z / np.maximum(np.abs(z), 1e-12), z)
        w = (z + a) / (1.0 + np.conj(a) * z)
        R = np.minimum(np.abs(w), 1.0) * 0.49
        rho = np.interp(R, self.uv_R, self.uv_rho)
        q = np.stack([w.real, w.imag], axis=1)
        return q * (rho / np.maximum(np.abs(w), 1e-12))[:, None]

    def _theta_max(self, phi):
        """Polar angle where the meridian of azimuth ``phi`` crosses the neck cut (bisection)."""
        lo = np.full(phi.shape, np.deg2rad(110.0))
        hi = np.full(phi.shape, np.deg2rad(176.0))
        y_cut = self.shape.y_cut * self.shape.scale[1]
        for _ in range(48):
            mid = 0.5 * (lo + hi)
            above = self.shape.position(sphere_dirs(mid, phi))[:, 1] > y_cut
            lo = np.where(above, mid, lo)
            hi = np.where(above, hi, mid)
        return 0.5 * (lo + hi)

    def _phi_index(self, phi):
        f = np.mod(phi, TWO_PI) * (self.nphi / TWO_PI)
        j0 = np.floor(f).astype(np.int64)
        w = f - j0
        j0 = np.mod(j0, self.nphi)
        return j0, np.mod(j0 + 1, self.nphi), w

    def _bilinear(self, tab, ext, a, phi):
        j0, j1, w = self._phi_index(phi)
        n = tab.shape[0]
        f = np.clip(a, 0.0, ext) * ((n - 1) / ext)
        i0 = np.minimum(np.floor(f).astype(np.int64), n - 2)
        u = f - i0
        lo = tab[i0, j0] * (1 - u) + tab[i0 + 1, j0] * u
        hi = tab[i0, j1] * (1 - u) + tab[i0 + 1, j1] * u
        return lo * (1 - w) + hi * w

    def theta_max_at(self, phi):
        j0, j1, w = self._phi_index(phi)
        return self.theta_max[j0] * (1 - w) + self.theta_max[j1] * w

    def dirs_of_p(self, p):
        rho = np.hypot(p[:, 0], p[:, 1])
        phi = np.mod(np.arctan2(p[:, 0], -p[:, 1]), TWO_PI)
        t = self._bilinear(self.t_tab, self.rho_ext, rho, phi)
        return sphere_dirs(t * self.theta_max_at(phi), phi)

    def p_of_dirs(self, d):
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        theta = np.arccos(np.clip(d[:, 1], -1, 1))
        phi = np.mod(np.arctan2(d[:, 0], d[:, 2]), TWO_PI)
        rho = self._bilinear(self.rho_tab, self.t_ext, theta / self.theta_max_at(phi), phi)
        return np.stack([rho * np.sin(phi), -rho * np.cos(phi)], axis=1)

    def X_of_p(self, p):
        return self.shape.position(self.dirs_of_p(p))


def ring_layout(par: DiskParam, n_target: int):
    """Rings of vertices at constant rho, equally spaced in 3D along each ring; exactly ``n_target`` vertices."""
    Lbar = float(par.L.mean())
    h = np.sqrt(2.0 * par.area / (np.sqrt(3.0) * n_target))
    for _ in range(4):
        K = max(int(round(Lbar / (h * np.sqrt(3.0) / 2.0))), 4)
        rhos = np.arange(K + 1) / K
        curves = par.ring_curves(rhos)
        segl = np.linalg.norm(np.roll(curves, -1, axis=1) - curves, axis=2)
        C = segl.sum(1)
        n_k = np.maximum(np.round(C / h).astype(np.int64), 3)
        n_k[0] = 1
        h *= np.sqrt(int(n_k.sum()) / n_target)
    resid = n_target - int(n_k.sum())
    order = np.argsort(-C[1:], kind="stable") + 1
    while resid != 0:
        step = int(np.sign(resid))
        k = min(abs(resid), len(order))
        n_k[order[:k]] += step
        resid -= step * k
    cum = np.concatenate([np.zeros((K + 1, 1)), np.cumsum(segl, axis=1)], axis=1)
    ring_id = np.repeat(np.arange(K + 1), n_k)
    start = np.concatenate([[0], np.cumsum(n_k)[:-1]])
    local = np.arange(int(n_k.sum())) - start[ring_id]
    target = (local + 0.5 * (ring_id % 2)) / n_k[ring_id] * C[ring_id]
    big = 10.0 * (C.max() + 1.0)
    xp = (cum + big * np.arange(K + 1)[:, None]).ravel()
    phi = np.interp(target + big * ring_id, xp, np.tile(np.append(par.phi_grid, TWO_PI), K + 1))
    phi = np.mod(phi, TWO_PI)
    phi[0] = 0.0
    return rhos[ring_id], phi, ring_id, n_k, start


def stitch_rings(phi, n_k, start):
    """Triangulate the annuli between consecutive rings (vectorised merge of segment mid-angles).

    Segment ``i`` of a ring joins vertex ``i`` to ``i + 1``; it is closed by the vertex of the
    neighbouring ring that lies between the mid-angles of that ring's segments around it.
    """
    K1 = len(n_k)
    ring_id = np.repeat(np.arange(K1), n_k)
    nxt = np.arange(len(phi)) + 1
    nxt[start + n_k - 1] = start
    gap = np.mod(phi[nxt] - phi, TWO_PI)
    gap[start[n_k == 1]] = TWO_PI
    mid = np.mod(phi + 0.5 * gap, TWO_PI)
    order = np.lexsort((mid, ring_id))
    skey = (ring_id * 8.0 + mid)[order]

    def apex(v, k_other, side):
        c = np.searchsorted(skey, k_other * 8.0 + mid[v], side=side) - start[k_other]
        prev = np.where(c == 0, n_k[k_other] - 1, c - 1)
        seg = order[start[k_other] + prev] - start[k_other]
        return start[k_other] + np.mod(seg + 1, n_k[k_other])

    vA = np.flatnonzero((ring_id < K1 - 1) & (n_k[ring_id] > 1))     # segments of the upper ring
    vB = np.flatnonzero(ring_id > 0)                                  # segments of the lower ring
    FA = np.stack([nxt[vA], vA, apex(vA, ring_id[vA] + 1, "left")], axis=1)
    FB = np.stack([vB, nxt[vB], apex(vB, ring_id[vB] - 1, "right")], axis=1)
    return np.concatenate([FA, FB], axis=0).astype(np.int64)


def _vertex_normals(X, F):
    N = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    out = np.stack([sum(np.bincount(F[:, k], weights=N[:, c], minlength=len(X)) for k in range(3))
                    for c in range(3)], axis=1)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)


def _min_angles(X, F):
    """Smallest corner angle (radians) of each triangle."""
    e = [X[F[:, (k + 1) % 3]] - X[F[:, k]] for k in range(3)]
    L = [np.linalg.norm(v, axis=1) + 1e-300 for v in e]
    cos = [np.einsum("ij,ij->i", e[k], -e[(k + 2) % 3]) / (L[k] * L[(k + 2) % 3]) for k in range(3)]
    return np.arccos(np.clip(np.max(cos, axis=0), -1.0, 1.0))


def snap_landmarks(par, p, F, fixed, dirs, candidates=8):
    """Move one vertex exactly onto each landmark; ``p`` and ``fixed`` are updated in place.

    Among the nearest free vertices (in the parameter disk) the one whose move leaves the
    best smallest 3D angle in its fan, without flipping a triangle, is chosen.
    """
    names = list(dirs)
    tp = par.p_of_dirs(np.array([dirs[k] for k in names]))
    Xt = par.X_of_p(tp)
    X = par.X_of_p(p)
    n = len(p)
    fan = vertex_face_incidence(F, n)
    out = {}
    for k, name in enumerate(names):
        dist = np.hypot(p[:, 0] - tp[k, 0], p[:, 1] - tp[k, 1])
        dist[fixed] = np.inf
        best, best_q = int(np.argmin(dist)), -1.0
        for v in np.argsort(dist, kind="stable")[:candidates]:
            if not np.isfinite(dist[v]):
                break
            faces = F[fan[v].indices]
            pp, XX = p.copy(), X
            pp[v] = tp[k]
            if (signed_uv_areas(faces, pp) <= 1e-14).any():
                continue
            XX = X.copy()
            XX[v] = Xt[k]
            q = float(_min_angles(XX, faces).min())
            if q > best_q + 1e-9:
                best, best_q = int(v), q
        if best_q > 0:
            p[best], X[best] = tp[k], Xt[k]
        fixed[best] = True
        out[name] = best
    return out


def relax_tangential(par, p, F, fixed, iters, lam=0.6, eps=1e-5):
    """Tangential umbrella smoothing in 3D, pulled back to the parameter disk (no flips)."""
    A = vertex_adjacency(F, len(p))
    deg = np.asarray(A.sum(1)).ravel()
    for _ in range(iters):
        X = par.X_of_p(p)
        delta = (A @ X) / deg[:, None] - X
        N = _vertex_normals(X, F)
        delta -= np.einsum("ij,ij->i", delta, N)[:, None] * N
        J1 = (par.X_of_p(p + [eps, 0.0]) - X) / eps
        J2 = (par.X_of_p(p + [0.0, eps]) - X) / eps
        g11, g12, g22 = (np.einsum("ij,ij->i", a, b) for a, b in ((J1, J1), (J1, J2), (J2, J2)))
        b1, b2 = np.einsum("ij,ij->i", J1, delta), np.einsum("ij,ij->i", J2, delta)
        det = np.maximum(g11 * g22 - g12 * g12, 1e-30)
        dp = np.stack([g22 * b1 - g12 * b2, g11 * b2 - g12 * b1], axis=1) / det[:, None]
        dp[fixed] = 0.0
        new = p + lam * dp
        for _k in range(10):
            bad = signed_uv_areas(F, new) <= 1e-14
            if not bad.any():
                break
            vb = F[bad].ravel()
            new[vb] = p[vb]
        p = new
    return p


# ============================================================================ texture detail
class ValueNoise3D:
    """Deterministic 3D value noise (hashed lattice, smooth trilinear), values in [-1, 1]."""

    def __init__(self, seed: int):
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x6EAD])
        perm = rng.permutation(256).astype(np.int64)
        self.perm = np.concatenate([perm, perm])
        self.vals = rng.uniform(-1.0, 1.0, 256)

    def __call__(self, P, scale, offset=0.0):
        q = (P + offset) / np.asarray(scale, dtype=np.float64)
        i = np.floor(q)
        f = q - i
        w = f * f * (3.0 - 2.0 * f)
        i = i.astype(np.int64) & 255
        pm, vals = self.perm, self.vals
        out = 0.0
        for cx in (0, 1):
            px = pm[(i[:, 0] + cx) & 255]
            wx = w[:, 0] if cx else 1.0 - w[:, 0]
            for cy in (0, 1):
                py = pm[px + ((i[:, 1] + cy) & 255)]
                wy = w[:, 1] if cy else 1.0 - w[:, 1]
                for cz in (0, 1):
                    wz = w[:, 2] if cz else 1.0 - w[:, 2]
                    out = out + vals[pm[py + ((i[:, 2] + cz) & 255)]] * wx * wy * wz
        return out


def texture_detail(C, reg, P0, ident, noise, fine=True):
    """Modulate colours with skin, freckle, hair and stubble detail (``fine=False``: low frequency only).

    Noise is evaluated only where its region weight is non-zero.
    """
    mult = np.ones(len(P0))

    def add(w, fn, target=mult):
        idx = np.flatnonzero(w > 1e-3)
        if len(idx):
            target[idx] += w[idx] * fn(P0[idx])

    add(reg["skin"], lambda P: 0.045 * noise(P, 0.012, 3.7))
    if not fine:
        return np.clip(C * mult[:, None], 0.0, 1.0)
    add(reg["skin"], lambda P: 0.035 * noise(P, 0.0011, 1.3))
    add(reg["hair"], lambda P: 0.25 * (noise(P, (0.0009, 0.005, 0.0009), 2.2) + 0.6 * noise(P, (0.004, 0.0008, 0.004), 9.4)))
    add(reg["brow"], lambda P: 0.3 * noise(P, (0.0006, 0.002, 0.002), 6.6))
    add(reg["eye"], lambda P: 0.12 * noise(P, 0.0005, 8.8))
    C = C * mult[:, None]
    x, y = P0[:, 0], P0[:, 1]
    if ident.freckles > 0:
        region = np.clip(gauss2(np.abs(x) - 0.025, y + 0.018, 0.028, 0.02) + gauss2(x, y + 0.01, 0.01, 0.02), 0, 1) * reg["skin"]
        spot = np.zeros(len(P0))
        add(region, lambda P: smoothstep((noise(P, 0.0019, 0.31) - (0.62 - 0.3 * ident.freckles)) / 0.1), spot)
        C = mix_colors(C, C * np.array([0.78, 0.62, 0.52]), spot * 0.7 * ident.freckles)
    if ident.stubble > 0:
        dots = np.zeros(len(P0))
        add(reg["beard"], lambda P: smoothstep((noise(P, 0.0008, 7.7) - 0.1) / 0.3), dots)
        C = mix_colors(C, C * 0.55, dots * 0.6 * ident.stubble)
    return np.clip(C, 0.0, 1.0)


# ============================================================================ the model
