"""Expressions of the procedural head's analytic surface (layer 3 of :mod:`geoface.synth.head`):
the jaw's weight and hinge rotation, and the displacement field of each expression, mixed into
:class:`geoface.synth.head_shape.HeadShape`."""
from __future__ import annotations

import numpy as np

from .head_math import T_CL, T_CU, gauss2, smoothstep
from .head_types import TWO_PI


class HeadExpressions:
    """The expressions of a :class:`~geoface.synth.head_shape.HeadShape` (a mixin: it reads the
    shape's mouth, nose and eye features)."""

    hinge = np.array([0.0, -0.012, -0.005])

    def jaw_weight(self, P0, split=False):
        """1 on the lower jaw (below the lips), 0 above; sharp across the lips, soft on the cheeks.

        ``split=True`` returns ``(w_lips, falloff)`` whose product is the weight.
        """
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        ax = np.abs(x)
        mw = self.mouth["mw"]
        yj = np.where(ax < mw, self.mouth_line(x), self.mouth_line(mw) + 0.25 * (ax - mw))
        spread = 0.7 * np.maximum(ax - mw + 0.002, 0.0)
        w = smoothstep((yj + T_CU + spread - y) / (T_CU - T_CL + 2.0 * spread))
        # gentle falloffs toward the back and down the neck: the rotation moves points back by up to ~4 cm,
        # so a weight slope above ~1/0.04 per metre along z would fold the surface
        fall = smoothstep((z + 0.03) / 0.09) * smoothstep((y + 0.17) / 0.065)
        return (w, fall) if split else w * fall

    def displacement(self, P0, Pn, d, e):
        """Canonical expression displacement ``(k, 3)`` for weights ``e`` (10,) in NAMES order.

        Bulges and furrows move along the ray ``d`` (radial, so they cannot fold the surface);
        the jaw rotates about a hinge axis in front of the ears; everything else is a smooth
        vector field with gentle gradients.
        """
        smile, jaw, pl, pr, pk, cl, cr, puff, br, fr = (float(v) for v in e)
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        ax = np.abs(x)
        front = smoothstep((z - 0.015) / 0.03)
        ym = self.mouth_line(x)
        mw = self.mouth["mw"]
        D = np.zeros_like(Pn)

        def add(w, vec):
            D[:] += w[:, None] * np.asarray(vec, dtype=np.float64)

        if smile:
            for sg in (1.0, -1.0):
                add(smile * front * gauss2(x - sg * mw, y - ym, 0.012, 0.011), (sg * 0.0045, 0.0065, -0.003))
                add(smile * front * gauss2(x - sg * 0.038, y + 0.03, 0.016, 0.015), (sg * 0.001, 0.0035, 0.0025))
            D[:, 0] += smile * 0.15 * x * front * gauss2(x, y - ym, 0.032, 0.012)
            lipw = smile * front * np.exp(-0.5 * (x / 0.02) ** 4)
            above = smoothstep((y - ym) / 0.002 + 0.5)
            D[:, 1] += lipw * (0.0016 * above * np.exp(-0.5 * ((y - ym) / 0.008) ** 2)
                               - 0.0010 * (1 - above) * np.exp(-0.5 * ((y - ym) / 0.008) ** 2))
            ex, ey, u, up, lo = self.eye_frame(ax, y)
            D[:, 1] += smile * front * 0.0012 * gauss2(ex, ey - lo + 0.003, 0.012, 0.004)
            fold = self._fold_distance(ax, y)
            D -= (smile * front * 0.0018 * np.exp(-0.5 * (fold / 0.0025) ** 2))[:, None] * d
        if jaw:
            wl, fall = self.jaw_weight(P0, split=True)
            w = wl * fall
            c, s = np.cos(0.28 * jaw), np.sin(0.28 * jaw)
            R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
            Q = (Pn - self.hinge) @ R.T + self.hinge
            D += w[:, None] * (Q - Pn)
            # the opening: the crease walls become the inside of the mouth.  The push is a smooth bump over
            # the walls (wider than a mesh row) and peaks where the lips split, so every column of the
            # opening is a graph over (w, push) and cannot fold
            t = y - ym - 0.5 * (T_CU + T_CL)
            band = jaw * 0.022 * front * self.mouth_corner(ax) * np.exp(-0.5 * (t / 0.0022) ** 2)
            D -= band[:, None] * d
        for sg, amount in ((1.0, pl), (-1.0, pr)):
            if amount:
                wl = amount * front * gauss2(x, y - ym, 0.03, 0.014)
                add(wl, (sg * 0.006, 0.0, 0.0035))
                add(wl * smoothstep(sg * x / 0.02 + 0.5), (0.0, 0.0005, 0.003))
        if pk:
            D[:, 2] += pk * 0.011 * front * gauss2(x, y - ym, 0.02, 0.012)
            D[:, 0] -= pk * 0.33 * x * front * gauss2(x, y - ym, 0.034, 0.016)
            D -= (pk * 0.002 * front * gauss2(ax - 0.04, y + 0.045, 0.014, 0.016))[:, None] * d
        if cl or cr:
            closed = np.where(x > 0, cl, cr)
            dr = front * (self.eyes(ax, y, closed) - self.eyes(ax, y, 0.0))
            D += dr[:, None] * d
        if puff:
            D += (puff * 0.012 * front * gauss2(ax - 0.043, y + 0.052, 0.017, 0.017))[:, None] * d
            D[:, 2] += puff * 0.002 * front * gauss2(x, y - ym, 0.02, 0.012)
        if br:
            w = br * front * smoothstep((y - 0.006) / 0.014) * (1.0 - smoothstep((y - 0.04) / 0.05)) \
                * np.exp(-0.5 * (ax / 0.055) ** 4)
            add(w, (0.0, 0.008, 0.001))
            fold = 0.5 * (1.0 - np.cos(TWO_PI * (y - 0.036) / 0.0105)) * smoothstep((y - 0.036) / 0.004) \
                * smoothstep((0.075 - y) / 0.01) * np.exp(-0.5 * (x / 0.045) ** 4)
            D -= (br * 0.0005 * front * fold)[:, None] * d
        if fr:
            for sg in (1.0, -1.0):
                add(fr * front * gauss2(x - sg * 0.017, y - 0.021, 0.012, 0.009), (-sg * 0.004, -0.004, 0.0012))
            add(fr * front * gauss2(ax - 0.042, y - 0.024, 0.012, 0.008), (0.0, -0.0012, 0.0))
            furrow = np.exp(-0.5 * ((ax - 0.0055) / 0.0013) ** 2) * smoothstep((y - 0.01) / 0.004) \
                * smoothstep((0.032 - y) / 0.004)
            D -= (fr * 0.0007 * front * furrow)[:, None] * d
        return D

    def _fold_distance(self, ax, y):
        """Distance to the nasolabial fold segment (ala -> beside the mouth corner)."""
        a = np.array([self.nose["ala"] + 0.006, self.nose["ys"] + 0.006])
        b = np.array([self.mouth["mw"] + 0.008, self.mouth["ym"] - 0.004])
        ab = b - a
        t = np.clip(((ax - a[0]) * ab[0] + (y - a[1]) * ab[1]) / (ab @ ab), 0.0, 1.0)
        return np.hypot(ax - a[0] - t * ab[0], y - a[1] - t * ab[1])
