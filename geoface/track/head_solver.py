"""The Levenberg–Marquardt solver of the ICT head track (:mod:`geoface.track.head_track`)."""
from __future__ import annotations

import numpy as np

__all__ = ["LM", "skew", "expmap", "logmap"]


def _skew(v):
    """(..., 3) → (..., 3, 3) cross-product matrices."""
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def _expmap(w):
    """(T, 3) rotation vectors → (T, 3, 3) (Rodrigues)."""
    th = np.linalg.norm(w, axis=-1)[:, None, None]
    K = _skew(w / np.maximum(th[..., 0], 1e-15))
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * (K @ K)


def _logmap(R):
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


class LM:
    """Levenberg–Marquardt over the clip, as in bundle adjustment: per frame a block of 59
    unknowns (rotation update, translation, 53 expression weights), shared by all frames the
    identity weights and the focal length's logarithm; each step solves the normal equations by
    the Schur complement on the shared block (frames are independent given it). The Cauchy loss
    by iteratively reweighted least squares; the expression bounds by projection; the temporal
    smoothness pulls each frame towards the mean of its neighbours at the current iterate."""

    NF = 59

    def __init__(self, P, ok, use, conf, width, f0, centre, R0, t0, mean, Bid, Bex, s, *, estimate_focal, offsets):
        self.offsets = offsets  # (R, t, centre) → (T, K, 3): where the points sit as the view turns
        self.P, self.ok, self.s = np.nan_to_num(P), ok, s
        self.f0, self.c = f0, np.asarray(centre, np.float64)
        self.mean, self.Bid, self.Bex = mean, Bid, Bex
        self.nid, self.ne = len(Bid), len(Bex)
        self.Bex_k = np.ascontiguousarray(Bex.transpose(1, 2, 0))  # (K, 3, 53)
        self.Bid_k = np.ascontiguousarray(Bid.transpose(1, 2, 0))  # (K, 3, nid)
        self.est_f = estimate_focal
        self.Wpt = ok[:, None] * (conf * use)[None]  # (T, K)
        self.norm = max(float(self.Wpt.sum()), 1e-9)
        self.sc2 = (s.scale * width) ** 2  # (T,)
        self.depth = float(np.median(t0[ok, 2]))
        T = len(P)
        self.state = (np.zeros(self.nid), 0.0, np.zeros((T, self.ne)), R0.copy(), t0.copy())
        self.lam = 1e-3

    def project(self, st):  # noqa: D102
        a, logf, E, R, t = st
        X = ((self.mean + np.tensordot(a, self.Bid, axes=1))[None] + np.einsum("te,ekd->tkd", E, self.Bex)
             + self.offsets(R, t, self.mean.mean(0)))
        Xc = np.einsum("tij,tkj->tki", R, X) + t[:, None]
        z = np.maximum(Xc[..., 2], 1e-6)
        f = self.f0 * np.exp(logf)
        return X, Xc, f * Xc[..., :2] / z[..., None] + self.c

    def _neighbours(self, A):
        """The mean of each frame's neighbours (one neighbour at the ends)."""
        out = np.empty_like(A)
        if len(A) == 1:
            return A.copy()
        out[1:-1] = 0.5 * (A[:-2] + A[2:])
        out[0], out[-1] = A[1], A[-2]
        return out

    def cost(self, st, full):
        a, logf, E, R, t = st
        _, _, uv = self.project(st)
        s2 = ((uv - self.P) ** 2).sum(-1) / self.sc2[:, None]
        c = float((self.Wpt * np.log1p(s2)).sum()) / self.norm
        s, T = self.s, len(E)
        c += s.w_focal * logf ** 2
        ws = s.w_smooth / T
        Rn = self._neighbours_rot(R)
        c += ws * float((_logmap(np.einsum("tij,tkj->tik", R, Rn)) ** 2).sum())
        c += ws * float((((t - self._neighbours(t)) / self.depth) ** 2).sum())
        if full:
            c += s.w_identity * float(a @ a) + s.w_expression * float(E.sum()) / T
            c += ws * float(((E - self._neighbours(E)) ** 2).sum())
        return c

    def _neighbours_rot(self, R):
        from scipy.spatial.transform import Rotation

        if len(R) == 1:
            return R.copy()
        q = Rotation.from_matrix(R).as_quat()
        q = q * np.sign((q * q[np.r_[0, np.arange(len(q) - 1)]]).sum(1))[:, None]  # one hemisphere
        qs = self._neighbours(q)
        return Rotation.from_quat(qs / np.linalg.norm(qs, axis=1, keepdims=True)).as_matrix()

    def step_system(self, st, full):
        """Normal equations: (H_ff (T, 59, 59), H_fs (T, 59, S), H_ss (S, S), g_f (T, 59), g_s (S,))."""
        a, logf, E, R, t = st
        s, T, K = self.s, len(E), self.P.shape[1]
        S = self.nid + 1
        X, Xc, uv = self.project(st)
        r = uv - self.P  # (T, K, 2)
        s2 = (r ** 2).sum(-1) / self.sc2[:, None]
        w = 2 * self.Wpt / (1 + s2) / self.sc2[:, None] / self.norm  # IRLS weights (T, K)
        f = self.f0 * np.exp(logf)
        z = np.maximum(Xc[..., 2], 1e-6)
        A = np.zeros((T, K, 2, 3))
        A[..., 0, 0] = A[..., 1, 1] = f / z
        A[..., 0, 2] = -f * Xc[..., 0] / z ** 2
        A[..., 1, 2] = -f * Xc[..., 1] / z ** 2
        Hff = np.zeros((T, self.NF, self.NF))
        Hfs = np.zeros((T, self.NF, S))
        Hss = np.zeros((S, S))
        gf = np.zeros((T, self.NF))
        gs = np.zeros(S)
        RX = Xc - t[:, None]
        # the columns this stage solves for: the rigid stage only pose and focal length
        cols = np.r_[0:self.NF + S] if full else np.r_[0:6, self.NF + self.nid]
        nc = len(cols)
        for lo in range(0, T, 32):  # frames in chunks (the Jacobians are 468 × 2 × 160 per frame)
            sl = slice(lo, min(lo + 32, T))
            Ac = A[sl]
            n = Ac.shape[0]
            J = np.empty((n, K, 2, self.NF + S)) if full else np.empty((n, K, 2, nc))
            J[..., 0:3] = -Ac @ _skew(RX[sl])
            J[..., 3:6] = Ac
            J[..., -1] = uv[sl] - self.c
            if full:
                # A R (per frame), then per point a (2n × 3) @ (3 × modes) product: one batched
                # matrix product over the 468 points instead of 468·n tiny ones
                AR = (Ac @ R[sl][:, None]).transpose(1, 0, 2, 3).reshape(K, 2 * n, 3)
                J[..., 6:self.NF] = (AR @ self.Bex_k).reshape(K, n, 2, -1).transpose(1, 0, 2, 3)
                if self.nid:
                    J[..., self.NF:self.NF + self.nid] = (AR @ self.Bid_k).reshape(K, n, 2, -1).transpose(1, 0, 2, 3)
            J = J.reshape(n, 2 * K, J.shape[-1])
            wr = np.repeat(w[sl], 2, axis=1)  # (n, 2K)
            Jw = J * wr[..., None]
            gc = np.einsum("tra,tr->ta", Jw, r[sl].reshape(n, 2 * K))
            # the Gauss–Newton matrix in single precision (half the time; its rounding is far below
            # the damping's share, and the step is solved in double)
            J32, Jw32 = J.astype(np.float32), Jw.astype(np.float32)
            Hc = (Jw32.transpose(0, 2, 1) @ J32).astype(np.float64)  # (n, nc, nc)
            H = np.zeros((n, self.NF + S, self.NF + S))
            g = np.zeros((n, self.NF + S))
            H[:, cols[:, None], cols[None, :]] = Hc
            g[:, cols] = gc
            Hff[sl] = H[:, :self.NF, :self.NF]
            Hfs[sl] = H[:, :self.NF, self.NF:]
            Hss += H[:, self.NF:, self.NF:].sum(0)
            gf[sl] = g[:, :self.NF]
            gs += g[:, self.NF:].sum(0)
        ws = 2 * s.w_smooth / T
        # smoothness towards the neighbours' mean (the neighbours held at the current iterate)
        dr = _logmap(np.einsum("tij,tkj->tik", R, self._neighbours_rot(R)))
        gf[:, 0:3] += ws * dr
        gf[:, 3:6] += ws * (t - self._neighbours(t)) / self.depth ** 2
        idx = np.arange(6)
        Hff[:, idx[:3], idx[:3]] += ws
        Hff[:, idx[3:], idx[3:]] += ws / self.depth ** 2
        gs[self.nid] += 2 * s.w_focal * logf
        Hss[self.nid, self.nid] += 2 * s.w_focal
        if full:
            gf[:, 6:] += s.w_expression / T + ws * (E - self._neighbours(E))
            Hff[:, np.arange(6, self.NF), np.arange(6, self.NF)] += ws
            gs[:self.nid] += 2 * s.w_identity * a
            Hss[np.arange(self.nid), np.arange(self.nid)] += 2 * s.w_identity
        return Hff, Hfs, Hss, gf, gs

    def solve(self, sys_, full):
        Hff, Hfs, Hss, gf, gs = (x.copy() for x in sys_)
        active_f = np.ones(self.NF, bool)
        active_s = np.ones(len(gs), bool)
        if not full:
            active_f[6:] = False
            active_s[:self.nid] = False
        if not self.est_f:
            active_s[self.nid] = False
        for H, g, act in ((Hff, gf, active_f), (None, None, None)):
            if H is None:
                break
            H[:, ~act, :] = 0
            H[:, :, ~act] = 0
            H[:, ~act, ~act] = 1
            g[:, ~act] = 0
        Hfs[:, ~active_f, :] = 0
        Hfs[:, :, ~active_s] = 0
        Hss[~active_s, :] = 0
        Hss[:, ~active_s] = 0
        Hss[~active_s, ~active_s] = 1
        gs[~active_s] = 0
        d = np.arange(self.NF)
        Hff[:, d, d] += self.lam * Hff[:, d, d] + 1e-12
        ds = np.arange(len(gs))
        Hss[ds, ds] += self.lam * Hss[ds, ds] + 1e-12
        Y = np.linalg.solve(Hff, np.concatenate([Hfs, gf[..., None]], -1))  # H_ff⁻¹ [H_fs | g_f]
        Sc = Hss - np.einsum("tfa,tfb->ab", Hfs, Y[..., :-1])
        rhs = -gs + np.einsum("tfa,tf->a", Hfs, Y[..., -1])
        xs = np.linalg.solve(Sc, rhs)
        xf = -Y[..., -1] - np.einsum("tfa,a->tf", Y[..., :-1], xs)
        return xf, xs

    def apply(self, st, xf, xs):
        a, logf, E, R, t = st
        return (a + xs[:self.nid], logf + float(xs[self.nid]), np.clip(E + xf[:, 6:], 0.0, 1.0),
                _expmap(xf[:, :3]) @ R, t + xf[:, 3:6])

    def run(self, iterations: int, *, full: bool, bar) -> None:
        c = self.cost(self.state, full)
        done = 0
        while done < iterations:
            sys_ = self.step_system(self.state, full)
            for _ in range(8):
                xf, xs = self.solve(sys_, full)
                cand = self.apply(self.state, xf, xs)
                cc = self.cost(cand, full)
                done += 1
                bar.update(1)
                if cc < c:
                    self.lam = max(self.lam / 3, 1e-7)
                    break
                self.lam = min(self.lam * 5, 1e7)
            else:
                bar.update(max(iterations - done, 0))
                return
            improved = c - cc
            self.state, c = cand, cc
            if improved < 1e-9 * max(c, 1e-12):
                bar.update(max(iterations - done, 0))
                return


skew, expmap, logmap = _skew, _expmap, _logmap
