"""The procedural head's analytic surface: section profiles, features, expressions and colours
(layers 1–3 of :mod:`geoface.synth.head`).  The expressions are :mod:`geoface.synth.head_expression`,
the small fields both are built from :mod:`geoface.synth.head_math`."""
from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.interpolate import PchipInterpolator

from .head_expression import HeadExpressions
from .head_math import SIG_C, T_CL, T_CU, T_LT, T_UT, gauss2, mix_colors, smoothstep, sphere_dirs  # noqa: F401  (re-exported)
from .head_types import TWO_PI, HeadIdentity

# canonical section profiles (metres): y -> value below the crown cap that starts at Y0
Y0, YTOP = 0.02, 0.125
PROFILES = {
    "w": [(0.02, 0.076), (0.0, 0.0745), (-0.015, 0.072), (-0.03, 0.068), (-0.05, 0.062), (-0.07, 0.0575),
          (-0.09, 0.056), (-0.11, 0.0555), (-0.14, 0.055), (-0.17, 0.0556), (-0.21, 0.062), (-0.3, 0.076)],
    "zf": [(0.02, 0.092), (0.008, 0.0895), (-0.01, 0.0875), (-0.03, 0.0875), (-0.05, 0.089), (-0.066, 0.089),
           (-0.08, 0.0855), (-0.095, 0.0835), (-0.104, 0.079), (-0.111, 0.068), (-0.116, 0.054), (-0.121, 0.043),
           (-0.13, 0.039), (-0.16, 0.040), (-0.21, 0.046), (-0.3, 0.052)],
    "zb": [(0.02, 0.106), (0.0, 0.1055), (-0.02, 0.102), (-0.04, 0.095), (-0.055, 0.086), (-0.068, 0.076),
           (-0.08, 0.071), (-0.1, 0.069), (-0.16, 0.069), (-0.21, 0.077), (-0.3, 0.092)],
    "nf": [(0.02, 2.2), (0.0, 2.4), (-0.02, 2.6), (-0.05, 2.4), (-0.07, 2.2), (-0.09, 1.8), (-0.105, 1.6),
           (-0.115, 1.8), (-0.125, 2.0), (-0.3, 2.0)],
    "nb": [(0.02, 2.1), (-0.05, 2.1), (-0.08, 2.0), (-0.3, 2.0)],
}
CAP_EXP = {"w": 2.4, "zf": 2.6, "zb": 2.2}


# ============================================================================ shape
class HeadShape(HeadExpressions):
    """Canonical head surface of one identity: ``X(d) = S (c + r(d) d)``."""

    centre = np.array([0.0, -0.025, -0.005])
    y_cut = -0.195
    _ny, _y_lo = 2048, -0.32

    def __init__(self, ident: HeadIdentity, ntheta: int = 144, nphi: int = 288):
        self.ident = ident
        m = ident.masculinity
        self.scale = ident.size * (1.0 + 0.03 * m) * np.array([ident.width, ident.height, ident.depth])
        self._features(ident)
        self._profiles(ident)
        self._table(ntheta, nphi)

    # ---------------------------------------------------------------- parameters
    def _features(self, ident):
        m = ident.masculinity
        L = 1.0 + 0.1 * ident.nose_length + 0.03 * m
        S = 1.0 + 0.15 * ident.nose_size + 0.08 * m
        self.nose = dict(yn=0.011, yt=0.011 - 0.037 * L, ys=0.011 - 0.054 * L, amp=0.021 * S * (0.9 + 0.1 * L),
                         w0=0.0052 * S, w1=0.0035 * S, ala=0.0145 * (1.0 + 0.12 * ident.nose_size + 0.04 * m))
        f = 1.0 + 0.25 * ident.lips - 0.15 * m
        self.mouth = dict(ym=-0.0655 - 0.001 * L, mw=0.026 * (1.0 + 0.03 * m), up=0.0045 * f, lo=0.0058 * f,
                          hu=0.0078 * (1.0 + 0.15 * ident.lips - 0.08 * m), hl=0.0095 * (1.0 + 0.15 * ident.lips - 0.08 * m))
        e = 1.0 + 0.08 * ident.eye_size - 0.05 * m
        self.eye = dict(x=0.0315, y=0.004, exi=-0.0152 * e, exo=0.0142 * e, hu=0.0063 * e, hl=0.0049 * e)
        self.brow = dict(amp=0.003 * max(1.0 + 0.5 * ident.brow + 0.5 * m, 0.15), y=0.021 - 0.0015 * m,
                         arch=0.0035 * (1.0 - 0.35 * m), thick=0.0032 * (1.0 + 0.25 * m))
        self.cheek = dict(amp=0.0035 * (1.0 + 0.5 * ident.cheekbones - 0.15 * m), y=-0.008 + 0.002 * ident.cheekbones,
                          fat=0.002 * (1.0 - 0.4 * m))
        self.chin = dict(amp=0.0075 * (1.0 + 0.4 * ident.chin + 0.25 * m), sx=0.014 * (1.0 + 0.25 * m))
        self.adam = 0.0045 * max(m, 0.0)
        hl = ident.hair_length
        self.hairp = dict(thick=0.003 + 0.009 * hl, nape=-0.068 - 0.05 * hl, behind=-0.015 - 0.045 * hl,
                         sideburn=0.012 - 0.02 * max(m, 0.0), curtain=smoothstep((hl - 0.45) / 0.3),
                         bottom=-0.06 - 0.07 * hl)

    def _profiles(self, ident):
        m = ident.masculinity
        yg = np.linspace(self._y_lo, YTOP, self._ny)
        jaw = smoothstep((-0.04 - yg) / 0.03) * smoothstep((yg + 0.13) / 0.02)
        neck = smoothstep((-0.105 - yg) / 0.02)
        chin = np.exp(-0.5 * ((yg + 0.1) / 0.01) ** 2)
        self.prof = {}
        for k, pts in PROFILES.items():
            pts = sorted(pts)
            f = PchipInterpolator([p[0] for p in pts], [p[1] for p in pts], extrapolate=True)
            v = f(np.minimum(yg, Y0))
            if k == "w":
                v = v * (1.0 + jaw * (0.05 * ident.jaw_width + 0.04 * m) + neck * 0.09 * m)
            elif k == "zf":
                v = v + chin * (0.003 * ident.chin + 0.002 * m) + neck * 0.004 * m
            elif k == "zb":
                v = v + neck * 0.004 * m
            elif k == "nf":
                v = v + jaw * (0.3 * m + 0.2 * ident.jaw_width)
            v = ndimage.gaussian_filter1d(v, {"nf": 35.0, "nb": 35.0, "w": 22.0}.get(k, 12.0), mode="nearest")
            if k in CAP_EXP:
                u = np.clip((yg - Y0) / (YTOP - Y0), 0.0, 1.0)
                v = v * (1.0 - u ** CAP_EXP[k]) ** (1.0 / CAP_EXP[k])
            self.prof[k] = v
        self._pack = np.stack([self.prof[k] for k in ("w", "zf", "zb", "nf", "nb")], axis=1)

    # ---------------------------------------------------------------- base (lofted sections)
    def section(self, y, sx, sz):
        """Horizontal radius of the section at height ``y`` toward unit (sx, sz)."""
        f = (np.clip(y, self._y_lo, YTOP) - self._y_lo) * ((self._ny - 1) / (YTOP - self._y_lo))
        i = np.minimum(f.astype(np.int64), self._ny - 2)
        u = (f - i)[:, None]
        p = self._pack[i] * (1.0 - u) + self._pack[i + 1] * u          # columns: w, zf, zb, nf, nb
        front = sz >= 0
        n = np.where(front, p[:, 3], p[:, 4])
        zz = np.where(front, p[:, 1], p[:, 2])
        s = (np.abs(sx) / np.maximum(p[:, 0], 1e-9)) ** n + (np.abs(sz) / np.maximum(zz, 1e-9)) ** n
        return np.maximum(s, 1e-300) ** (-1.0 / n)

    def _solve(self, theta, phi, lo=None, hi=None, iters=26):
        """Distance from the centre to the lofted surface along each ray (bisection in [lo, hi])."""
        st, ct = np.sin(theta), np.cos(theta)
        dx, dz = st * np.sin(phi), st * np.cos(phi)
        c = self.centre

        def outside(r):
            px, py, pz = c[0] + r * dx, c[1] + r * ct, c[2] + r * dz
            rh = np.maximum(np.hypot(px, pz), 1e-12)
            return (rh >= self.section(py, px / rh, pz / rh)) | (py >= YTOP)

        lo = np.zeros_like(theta) if lo is None else lo
        hi = np.full_like(theta, 0.7) if hi is None else hi
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            out = outside(mid)
            hi = np.where(out, mid, hi)
            lo = np.where(out, lo, mid)
        return 0.5 * (lo + hi)

    def _table(self, ntheta, nphi):
        self._th_top = np.deg2rad(177.0)
        pad = 6
        th = np.arange(-pad, ntheta + pad) * (self._th_top / (ntheta - 1))
        ph = np.arange(nphi) * (TWO_PI / nphi)
        T, P = np.meshgrid(th, ph, indexing="ij")
        T, P = np.abs(T).ravel(), np.where(T < 0, P + np.pi, P).ravel()
        # coarse solve on every 4th ray, then a bracketed refinement (falls back where it fails)
        sub = ((np.arange(len(th)) % 4 == 0)[:, None] & (np.arange(nphi) % 4 == 0)[None, :]).ravel()
        rc = self._solve(T[sub], P[sub]).reshape(-1, nphi // 4)
        I, J = np.meshgrid(np.arange(len(th)) / 4.0, np.arange(nphi) / 4.0, indexing="ij")
        guess = ndimage.map_coordinates(rc, [I.ravel(), J.ravel()], order=1, mode="nearest")
        lo, hi = np.maximum(guess - 0.008, 0.0), guess + 0.008
        r = self._solve(T, P, lo, hi, iters=13)
        bad = (r - lo < 1e-6) | (hi - r < 1e-6)
        if bad.any():
            r[bad] = self._solve(T[bad], P[bad])
        self._coef = ndimage.spline_filter(r.reshape(len(th), nphi), order=3, mode="grid-wrap")
        self._pad, self._nth, self._nph = pad, ntheta, nphi

    def base(self, d):
        """Base radius along unit directions ``d`` (bicubic spline of the lofted table)."""
        theta = np.arccos(np.clip(d[:, 1], -1.0, 1.0))
        phi = np.mod(np.arctan2(d[:, 0], d[:, 2]), TWO_PI)
        i = theta * ((self._nth - 1) / self._th_top) + self._pad
        j = phi * (self._nph / TWO_PI)
        return ndimage.map_coordinates(self._coef, [i, j], order=3, mode="grid-wrap", prefilter=False)

    # ---------------------------------------------------------------- features
    def mouth_corner(self, ax):
        """1 between the mouth corners, 0 beyond them."""
        return smoothstep((self.mouth["mw"] + 0.0005 - ax) / 0.004)

    def mouth_line(self, x):
        return self.mouth["ym"] - 0.0018 * (x / self.mouth["mw"]) ** 2

    def lip_heights(self, x):
        mo = self.mouth
        ax = np.abs(x)
        hu = mo["hu"] * np.sqrt(np.maximum(1 - (x / mo["mw"]) ** 2, 0)) + 0.0012 * np.exp(-0.5 * ((ax - 0.005) / 0.003) ** 2) \
            - 0.0008 * np.exp(-0.5 * (x / 0.002) ** 2)
        hl = mo["hl"] * np.sqrt(np.maximum(1 - (x / (mo["mw"] + 0.0005)) ** 2, 0))
        return hu, hl

    def eye_frame(self, ax, y):
        """Eye-local coordinates, corner parameter ``u`` (-1 inner, +1 outer) and lid margins."""
        e = self.eye
        ex, ey = ax - e["x"], y - e["y"]
        u = (ex - 0.5 * (e["exi"] + e["exo"])) / (0.5 * (e["exo"] - e["exi"]))
        uc = np.clip(u, -1.0, 1.0)
        env = (1.0 - uc * uc) ** 0.75
        yc = -0.0005 + 0.001 * (uc + 1.0)
        up = yc + e["hu"] * env * (1.0 - 0.12 * uc)
        lo = yc - e["hl"] * env * (1.0 + 0.1 * uc)
        return ex, ey, u, up, lo

    def eye_opening(self, ax, y, closed, soft=0.0014):
        ex, ey, u, up, lo = self.eye_frame(ax, y)
        up = up + closed * (lo + 0.0004 - up)
        din = np.minimum(up - ey, ey - lo)
        return smoothstep(din / soft + 0.3) * smoothstep((1.0 - np.abs(u)) / 0.08), (ex, ey, u, up, lo)

    def eyes(self, ax, y, closed):
        opening, (ex, ey, u, up, lo) = self.eye_opening(ax, y, closed)
        socket = -0.0085 * gauss2(ex, ey - 0.002, 0.017, 0.0125)
        bulge = 0.0062 * gauss2(ex, ey, 0.0105, 0.0085)
        env = np.exp(-0.5 * (ex / 0.012) ** 4)
        _, _, _, up0, _ = self.eye_frame(ax, y)
        crease = -0.0011 * env * np.exp(-0.5 * ((ey - up0 - 0.0065) / 0.0016) ** 2)
        lower = 0.0005 * env * np.exp(-0.5 * ((ey - lo + 0.0025) / 0.0015) ** 2)
        return socket + bulge - 0.0019 * opening + crease + lower

    def _nose(self, x, y):
        n = self.nose
        prog = np.clip((n["yn"] - y) / (n["yn"] - n["yt"]), 0.0, 1.4)
        P = 0.001 + n["amp"] * prog ** 1.2
        cut = smoothstep((y - (n["ys"] + 0.001)) / (n["yt"] - n["ys"] - 0.001))
        top = smoothstep((0.02 - y) / 0.012)
        wid = n["w0"] + n["w1"] * np.clip(prog, 0, 1)
        dorsum = P * cut * top * np.exp(-0.5 * (x / wid) ** 2)
        ax = np.abs(x)
        yb = n["ys"] + 0.008
        tip = 0.0055 * gauss2(x, y - n["yt"] + 0.0015, 0.0078, 0.0068)
        alae = 0.0085 * gauss2(ax - n["ala"], y - yb, 0.0062, 0.006)
        nostril = -0.004 * gauss2(ax - 0.0063, y - yb + 0.0025, 0.003, 0.0022)
        crease = -0.0015 * gauss2(ax - n["ala"] - 0.0065, y - yb - 0.001, 0.0025, 0.007)
        return dorsum + tip + alae + nostril + crease

    def _mouth(self, x, y):
        mo = self.mouth
        ax = np.abs(x)
        ym = self.mouth_line(x)
        hu, _ = self.lip_heights(x)
        muzzle = 0.006 * gauss2(x, y - ym - 0.004, 0.028, 0.02)
        xenv = np.exp(-0.5 * (x / (mo["mw"] * 0.7)) ** 4)
        upper = mo["up"] * xenv * np.exp(-0.5 * ((y - ym - 0.004) / 0.0042) ** 2)
        border = 0.0007 * xenv * np.exp(-0.5 * ((y - ym - hu) / 0.001) ** 2)
        lower = mo["lo"] * np.exp(-0.5 * (x / (mo["mw"] * 0.64)) ** 4) * np.exp(-0.5 * ((y - ym + 0.0058) / 0.0052) ** 2)
        # exponential groove: steep walls down to the centre line, so rings of vertices land in every band
        crease = -0.009 * self.mouth_corner(ax) * np.exp(-np.sqrt((y - ym) ** 2 + 0.0002**2) / SIG_C)
        dimple = -0.0015 * gauss2(ax - mo["mw"] - 0.0005, y - ym, 0.003, 0.003)
        philtrum = (-0.0008 * np.exp(-0.5 * (x / 0.0025) ** 2) + 0.0005 * np.exp(-0.5 * ((ax - 0.0045) / 0.0015) ** 2)) \
            * smoothstep((y - ym - hu) / 0.002) * smoothstep((self.nose["ys"] - y) / 0.003)
        return muzzle + upper + border + lower + crease + dimple + philtrum

    def _ears(self, x, y, z):
        side = smoothstep((np.abs(x) - 0.03) / 0.02)
        ze, ye, tilt = -0.012, -0.013, np.deg2rad(15.0)
        c, s = np.cos(tilt), np.sin(tilt)
        ez = c * (z - ze) + s * (y - ye)
        ey = -s * (z - ze) + c * (y - ye)
        a, b = 0.0165, 0.031
        q = np.sqrt((ez / a) ** 2 + (ey / b) ** 2)
        hf = 0.5 + 0.5 * smoothstep(0.3 - ez / a)
        edge = 0.3 + 0.1 * smoothstep(-ey / b * 2.0)             # the front attaches to the head
        back = smoothstep(0.5 - ez / (0.6 * a))                  # blend front (attached) and back (free) edges
        body = back * smoothstep((1.35 - q) / 0.45) + (1.0 - back) * smoothstep((1.05 - q) / edge)
        rim = np.exp(-0.5 * ((q - 0.86) / 0.095) ** 2) * smoothstep((ey + 0.6 * b) / (0.3 * b) + 0.5)
        concha = 0.008 * gauss2(ez - 0.004, ey + 0.004, 0.006, 0.01)
        tragus = 0.003 * gauss2(ez - 0.011, ey + 0.005, 0.003, 0.003)
        anti = 0.003 * np.exp(-0.5 * ((q - 0.55) / 0.07) ** 2) * smoothstep(-ez / a + 0.3)
        return side * (hf * (0.010 * body + 0.004 * rim + anti) - concha + tragus)

    #: hairline height by azimuth (degrees from the front); None = set by the identity
    HAIRLINE = [(0, 0.077), (20, 0.075), (35, 0.066), (48, 0.056), (58, 0.042), (65, 0.024), (70, None),
                (74, None), (78, None), (83, 0.016), (90, 0.027), (98, 0.03), (108, 0.022), (117, None), (140, None),
                (160, None), (180, None)]

    def hair_mask(self, P):
        """Scalp hair coverage in [0, 1] at base points ``P``."""
        psi = np.degrees(np.abs(np.arctan2(P[:, 0], P[:, 2])))
        h = self.hairp
        sb = h["sideburn"]
        fill = {70: 0.006 + 0.5 * sb, 74: sb - 0.008, 78: 0.5 * sb - 0.002, 117: h["behind"],
                140: h["nape"] + 0.012, 160: h["nape"] + 0.003, 180: h["nape"]}
        k = np.array([(a, fill.get(a, b)) for a, b in self.HAIRLINE], dtype=np.float64)
        yh = np.interp(psi, k[:, 0], k[:, 1])
        return smoothstep((P[:, 1] - yh) / 0.005 + 0.5)

    def hair(self, P):
        """(radial hair thickness, hair colour weight) at base points ``P``.

        Scalp hair is a layer over the hairline mask; long hair adds a curtain that falls
        from the widest part of the head behind the ears down toward the neck cut.
        """
        h = self.hairp
        hm = self.hair_mask(P)
        top = smoothstep((P[:, 1] + 0.01) / 0.09)
        layer = h["thick"] * (0.55 + 0.45 * top) * hm
        if h["curtain"] <= 0:
            return layer, hm
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        rb = np.maximum(np.hypot(x, z), 1e-9)
        rtop = self.section(np.full(len(P), -0.005), x / rb, z / rb) + h["thick"] * (0.55 + 0.45 * smoothstep(0.005 / 0.09))
        taper = 1.0 - 0.22 * smoothstep((-0.005 - y) / 0.13)
        fill = np.maximum(rtop * taper - rb, 0.0) * smoothstep((-0.005 - y) / 0.02 + 1.0)
        psi = np.degrees(np.abs(np.arctan2(x, z)))
        w = h["curtain"] * smoothstep((psi - 100.0) / 35.0) * smoothstep((y - h["bottom"]) / 0.03)
        horiz = np.maximum(np.hypot(x, z - self.centre[2]) / np.maximum(np.linalg.norm(P - self.centre, axis=1), 1e-9), 0.5)
        curtain = w * fill / horiz
        k = 0.004
        hh = np.clip(0.5 + 0.5 * (layer - curtain) / k, 0.0, 1.0)
        return curtain + (layer - curtain) * hh + k * hh * (1.0 - hh), np.maximum(hm, w * smoothstep(fill / 0.004))

    def detail(self, P):
        """Neutral radial displacement ``(n,)`` of all features at base points ``P`` (canonical)."""
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        ax = np.abs(x)
        front = smoothstep((z - 0.015) / 0.03)
        b = self.brow
        yb = b["y"] + b["arch"] * np.exp(-0.5 * ((ax - 0.034) / 0.012) ** 2)
        dr = b["amp"] * np.exp(-0.5 * ((y - yb) / 0.006) ** 2) * np.exp(-0.5 * ((ax - 0.028) / 0.02) ** 2)
        dr += 0.5 * b["amp"] * gauss2(x, y - 0.02, 0.01, 0.008)
        dr += 0.0015 * gauss2(ax - 0.025, y - 0.055, 0.02, 0.02)
        dr += self.eyes(ax, y, 0.0)
        ck = self.cheek
        dr += ck["amp"] * gauss2(ax - 0.05, y - ck["y"], 0.014, 0.009) + ck["fat"] * gauss2(ax - 0.038, y + 0.045, 0.014, 0.016)
        dr -= 0.0015 * gauss2(ax - 0.027, y + 0.013, 0.011, 0.005)
        dr += self._nose(x, y) + self._mouth(x, y)
        dr += -0.002 * gauss2(x, y - self.mouth["ym"] + 0.019, 0.014, 0.004)
        dr += self.chin["amp"] * gauss2(x, y + 0.099, self.chin["sx"], 0.011)
        out = front * dr
        out -= 0.003 * gauss2(ax - 0.06, y - 0.03, 0.02, 0.015) * np.exp(-0.5 * ((z - 0.045) / 0.02) ** 2)
        out += self.adam * gauss2(x, y + 0.14, 0.007, 0.012) * smoothstep((z - 0.0) / 0.02)
        out += self._ears(x, y, z)
        out += self.hair(P)[0]
        return out

    # ---------------------------------------------------------------- evaluation
    def neutral(self, d):
        """(base point P0, neutral point Pn) in canonical coordinates, both ``(k, 3)``."""
        r0 = self.base(d)
        P0 = self.centre + r0[:, None] * d
        return P0, P0 + self.detail(P0)[:, None] * d

    def position(self, d):
        """World position of the neutral surface along unit directions ``d``."""
        return self.neutral(d)[1] * self.scale


# ============================================================================ parameter disk
