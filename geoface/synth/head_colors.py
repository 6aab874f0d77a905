"""The procedural head's colours: skin, hair, stubble, lips, teeth, brows and eyes, painted
analytically on the canonical surface (layer 3 of :mod:`geoface.synth.head`)."""
from __future__ import annotations

import numpy as np

from .head_shape import T_CL, T_CU, T_LT, T_UT, gauss2, mix_colors, smoothstep
from .head_types import EXPRESSION_NAMES

__all__ = ["head_colors"]


def _palette(t, stops):
    """Piecewise-linear colour ramp: ``stops`` = [(t, (r, g, b)), ...]."""
    ts = np.array([s[0] for s in stops])
    cs = np.array([s[1] for s in stops], dtype=np.float64)
    return np.array([np.interp(t, ts, cs[:, k]) for k in range(3)])


SKIN = [(0.0, (0.96, 0.81, 0.71)), (0.3, (0.87, 0.66, 0.53)), (0.6, (0.67, 0.46, 0.33)), (1.0, (0.36, 0.23, 0.16))]
HAIR = [(0.0, (0.05, 0.04, 0.035)), (0.35, (0.20, 0.12, 0.07)), (0.6, (0.42, 0.29, 0.17)),
        (0.8, (0.70, 0.55, 0.34)), (1.0, (0.86, 0.78, 0.60))]
IRIS = [(0.0, (0.30, 0.46, 0.64)), (0.35, (0.36, 0.44, 0.26)), (0.65, (0.43, 0.28, 0.13)), (1.0, (0.17, 0.10, 0.05))]


def head_colors(self, P0, e=None, regions=False):
    """Per-point colours ``(k, 3)`` in [0, 1] of the head ``self`` (a :class:`~geoface.synth.head_shape._Shape`)
    at base points ``P0`` for expression weights ``e``.

    With ``regions=True`` also returns soft region masks (hair, brow, eye, lip, beard, skin)
    that the texture uses to place its fine detail.
    """
    e = np.zeros(len(EXPRESSION_NAMES)) if e is None else np.asarray(e, dtype=np.float64)
    ident = self.ident
    skin = _palette(ident.skin_tone, SKIN)
    hair = _palette(ident.hair_color, HAIR)
    x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
    n = len(P0)
    C = np.tile(skin, (n, 1))
    C *= (1.0 - 0.07 * smoothstep((-0.12 - y) / 0.07))[:, None]
    red = skin * np.array([1.0, 0.80, 0.78])
    ear = smoothstep((np.abs(x) - 0.05) / 0.015) * gauss2(z + 0.012, y + 0.013, 0.02, 0.035)
    C = mix_colors(C, red, 0.3 * ear)
    reg = {k: np.zeros(n) for k in ("brow", "eye", "lip", "beard")}
    face = np.flatnonzero(z > -0.02)                 # the facial colours live on the front only
    Cf, rf = _face_colors(self, P0[face], C[face], e, skin, hair, red)
    C[face] = Cf
    for k, v in rf.items():
        reg[k][face] = v
    hm = self.hair(P0)[1]
    C = np.clip(mix_colors(C, hair, hm), 0.0, 1.0)
    if regions:
        reg.update(hair=hm, skin=(1 - hm) * (1 - reg["eye"]))
        return C, reg
    return C

def _face_colors(self, P0, C, e, skin, hair, red):
    ident = self.ident
    x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
    ax = np.abs(x)
    front = smoothstep((z - 0.015) / 0.03)
    C = mix_colors(C, red, front * (0.30 * gauss2(ax - 0.042, y + 0.03, 0.015, 0.014)
                              + 0.2 * gauss2(x, y - self.nose["yt"], 0.008, 0.008)))
    # beard shadow
    ym = self.mouth_line(x)
    hu, hl = self.lip_heights(x)
    lip = front * np.where(y > ym, smoothstep((ym + hu - y) / 0.0012 + 0.5),
                           smoothstep((y - ym + hl) / 0.0016 + 0.5)) * np.exp(-0.5 * (x / (self.mouth["mw"] + 0.002)) ** 8)
    side_w = smoothstep((ax - 0.012) / 0.014)                   # beard top: under the nose, then the cheek line
    beard_top = (1.0 - side_w) * (self.nose["ys"] - 0.002) + side_w * (-0.03 + 0.35 * np.maximum(ax - 0.035, 0.0))
    beard = smoothstep((beard_top - y) / 0.012 + 0.2) * smoothstep((y + 0.15) / 0.03) \
        * smoothstep((z + 0.02) / 0.03) * smoothstep((0.078 - ax) / 0.01)
    beard = beard * (1.0 - 0.7 * gauss2(x, y - self.mouth["ym"] + 0.014, 0.006, 0.004)) * (1.0 - lip)
    C = mix_colors(C, 0.6 * skin + 0.4 * (0.5 * hair + 0.06), 0.4 * ident.stubble * beard)
    # lips, mouth interior and teeth
    lipcol = skin * np.array([0.80, 0.58, 0.60]) + np.array([0.07, 0.02, 0.04])
    C = mix_colors(C, lipcol, 0.8 * lip)
    corner = front * self.mouth_corner(ax)
    t = y - ym
    inner = corner * smoothstep((0.0035 - np.abs(t)) / 0.0015)
    C = mix_colors(C, skin * np.array([0.62, 0.36, 0.38]), inner)                  # inside of the lips
    C = mix_colors(C, [0.16, 0.04, 0.05], 0.6 * e[1] * inner)                       # shadowed when open
    C = mix_colors(C, [0.16, 0.04, 0.05], corner * smoothstep((T_CU - t) / 0.0004 + 0.5) * smoothstep((t - T_CL) / 0.0004 + 0.5))
    teeth = np.clip(3.0 * e[1] + 1.2 * e[0], 0.0, 1.0)
    if teeth > 0:
        band = lambda a, b: smoothstep((t - a) / 0.0003 + 0.5) * smoothstep((b - t) / 0.0003 + 0.5)  # noqa: E731
        tw = band(T_CU, T_UT) + np.clip(2.0 * e[1] - 0.6, 0.0, 1.0) * band(T_LT, T_CL)
        C = mix_colors(C, [0.86, 0.84, 0.77], teeth * corner * tw * np.exp(-0.5 * (x / 0.019) ** 6))
    # nostrils
    C = mix_colors(C, skin * 0.4, front * 0.8 * gauss2(ax - 0.0063, y - self.nose["ys"] - 0.005, 0.0024, 0.0017))
    # eyebrows: a tapered arch from the head (medial) to the tail (lateral)
    b = self.brow
    yb = b["y"] + b["arch"] * np.exp(-0.5 * ((ax - 0.034) / 0.012) ** 2) - 0.0015 * smoothstep((ax - 0.04) / 0.012)
    s_ = np.clip((ax - 0.012) / 0.04, 0.0, 1.0)
    thick = b["thick"] * (1.25 - 0.85 * s_ ** 1.5)
    brow = front * smoothstep((thick - np.abs(y - yb)) / 0.0018 + 0.5) \
        * smoothstep((ax - 0.0115) / 0.004) * smoothstep((0.053 - ax) / 0.006)
    C = mix_colors(C, hair * 0.75 + 0.05 * skin, brow * (0.85 - 0.3 * s_))
    # eyes: sclera (shaded toward the corners), iris, pupil; lash line on the upper lid margin
    closed = np.where(x > 0, e[5], e[6])
    opening, (ex, ey, u, up, lo) = self.eye_opening(ax, y, closed, soft=0.0008)
    opening = opening * front
    rho = np.hypot(ex + 0.0003, ey + 0.0002)
    eye = np.tile([0.88, 0.85, 0.80], (len(P0), 1))
    eye *= (1.0 - 0.22 * smoothstep((np.abs(u) - 0.45) / 0.5))[:, None]
    eye = mix_colors(eye, [0.83, 0.55, 0.52], smoothstep((-0.8 - u) / 0.15))
    iris = _palette(ident.eye_color, IRIS)
    ic = iris[None, :] * (0.7 + 0.5 * smoothstep((rho - 0.0022) / 0.0035))[:, None]
    eye = mix_colors(eye, ic, smoothstep((0.006 - rho) / 0.0005 + 0.5))
    eye = mix_colors(eye, [0.02, 0.02, 0.02], smoothstep((0.0023 - rho) / 0.0003 + 0.5))
    C = mix_colors(C, eye, opening)
    lash = front * np.exp(-0.5 * ((ey - up - 0.0005) / 0.0008) ** 2) * smoothstep((1.05 - np.abs(u)) / 0.15)
    C = mix_colors(C, 0.25 * hair + 0.1 * skin, (0.6 + 0.2 * max(-ident.masculinity, 0.0)) * lash)
    return C, dict(brow=brow, eye=opening, lip=lip, beard=beard)
