"""The HFM-GS model: the half-face-mapped Gaussian head (its settings: :mod:`geoface.hfm.config`;
:mod:`geoface.hfm` describes the method)."""
from __future__ import annotations


import numpy as np
import torch
from torch import Tensor, nn

from geoface.errors import AvatarError
from geoface.splat.gaussians import Gaussians, GaussianTensors, quat_mul, quat_to_rotmat
from geoface.hfm.blocks import (DeformHeads, ImageEncoder, axis_angle_to_quat, farthest_point_sampling,
                                      inverse_distance_weights, mlp, posenc)
from geoface.hfm.config import HFMConfig






# ----------------------------------------------------------------------------- the model
class HFMModel(nn.Module):
    """Canonical Gaussians + E_img + the deformation and mapping networks (module doc)."""

    #: the ``format`` of its config.json and its verb group (the avatar contract, :class:`geoface.hfm.avatar.HFMAvatar`)
    FORMAT = "geoface-hfm-gs"
    KIND = "hfm"

    def __init__(self, gaussians: Gaussians, cfg: HFMConfig, y_split: float, center=None, scale=None):
        super().__init__()
        self.cfg = cfg
        self.gaussians = gaussians
        self.y_split = float(y_split)
        P = gaussians.means.detach()
        c = P.mean(0) if center is None else torch.as_tensor(center, dtype=P.dtype)
        s = (P - c).abs().max() if scale is None else torch.as_tensor(scale, dtype=P.dtype)
        self.register_buffer("center", c.clone())
        self.register_buffer("scale", s.clone().reshape(()))
        e = 3 + 6 * cfg.pos_freqs
        L, H = cfg.latent_dim, cfg.hidden
        self.encoder = ImageEncoder(L, cfg.enc_width, cfg.crop)
        self.mlp_x, self.mlp_s, self.mlp_r = mlp(e + L, H, 3), mlp(e + L, H, 3), mlp(e + L, H, 4)
        if cfg.gaussian_mapping:
            self.mlp_gm = mlp(e + (7 if cfg.gm_input == "xsr" else 0), 64, cfg.emb_dim, zero_last=False)
            f_in = cfg.feat_dim if cfg.feature_mapping else 10
            if cfg.pm_per_component:  # f_L = [MLP_pm^X(γ, ΔX), MLP_pm^S(γ, log ΔS), MLP_pm^R(γ, ΔR)]
                self.mlp_pm = nn.ModuleList([mlp(e + k, 64, cfg.feat_dim, zero_last=False) for k in (3, 3, 4)])
                f_in = 3 * cfg.feat_dim
            elif cfg.feature_mapping:
                self.mlp_pm = mlp(e + 10, 64, cfg.feat_dim, zero_last=False)
            head_in = e + (L if cfg.map_theta else 0)
            head_in += cfg.feat_dim if cfg.pm_per_component and cfg.mapping_heads == 3 else f_in
            self.mlp_mapping = mlp(head_in, H, 10) if cfg.mapping_heads == 1 else DeformHeads(head_in, H)
        elif cfg.unmapped_upper == "separate":
            self.mlp_up = mlp(e + L, H, 10)
        if cfg.global_pose:
            if cfg.pose_residual:
                self.mlp_pose = mlp(L, 64, 6)
            if cfg.image_pose:
                self.mlp_head_pose = mlp(L, 128, 6)
        if cfg.gaussian_mapping and cfg.map_norm:
            # running mean square of each lower deformation channel (bias-corrected EMA over steps)
            self.register_buffer("p_ms", torch.zeros(10))
            self.register_buffer("p_steps", torch.zeros(()))
        if cfg.gaussian_mapping and cfg.feat_norm:
            # running mean and mean square of each upper feature channel (bias-corrected EMA)
            self.register_buffer("f_mean", torch.zeros(f_in))
            self.register_buffer("f_ms", torch.zeros(f_in))
            self.register_buffer("f_steps", torch.zeros(()))
        if cfg.gaussian_mapping and cfg.gm_input == "xsr":  # the canonical mean log-scale, MLP_gm's zero
            self.register_buffer("log_s0", gaussians.log_scales.detach().mean().clone())
        self._refit: str | None = None  # inside refit_statistics: which statistics it averages
        self.keys_u: Tensor | None = None
        #: the registration landmarks on the canonical head ({"names", "points" [K][3]}), for
        #: fitting a usage video's head pose to its landmarks (saved in config.json)
        self.landmarks3d: dict | None = None
        #: how poses fitted to the lower landmarks miss the registration frame
        #: (:func:`geoface.avatar.head_pose.calibrate_lower_poses`; saved in config.json)
        self.pose_calibration: dict | None = None
        self.keys_l: Tensor | None = None
        self.wdist: tuple[Tensor, Tensor] | None = None

    # ------------------------------------------------------------- halves and keys
    def upper_mask(self) -> Tensor:
        return self.gaussians.means.detach()[:, 1] > self.y_split

    def embed(self, X: Tensor) -> Tensor:
        return posenc((X - self.center) / self.scale, self.cfg.pos_freqs)

    def gm_embed(self, E: Tensor) -> Tensor:
        """What MLP_gm reads for every Gaussian, from its embedded positions ``E``: ``E`` itself
        (``gm_input="x"``), or with the Gaussian's log-scales (less the canonical mean) and its
        unit rotation quaternion (w ≥ 0), both detached (``"xsr"``): the mapping reads the shape
        of a Gaussian without reshaping it."""
        if self.cfg.gm_input == "x":
            return E
        g = self.gaussians
        q = g.quats.detach()
        q = q / q.norm(dim=-1, keepdim=True)
        q = torch.where(q[:, :1] < 0, -q, q)
        return torch.cat([E, g.log_scales.detach() - self.log_s0, q], -1)

    @torch.no_grad()
    def refresh_keys(self) -> None:
        """Pick the 512 + 512 key Gaussians and W_dist (correlation-weight sampling, eq. 9–10)."""
        if not (self.cfg.gaussian_mapping and self.cfg.sampling):
            self.keys_u = self.keys_l = self.wdist = None
            return
        up = self.upper_mask()
        iu, il = torch.nonzero(up).reshape(-1), torch.nonzero(~up).reshape(-1)
        X = self.gaussians.means.detach()
        ku, kl = select_keys(self, X, iu, il, self.cfg.n_keys, self.cfg.seed, self.cfg.lower_keys)
        self.keys_u, self.keys_l = ku, kl
        j, w = inverse_distance_weights(X[iu], X[ku], self.cfg.k_upsample)
        self.wdist = (j, w)
        self._keys_for = (len(X), iu, il)

    def _keys_valid(self, n, iu, il) -> bool:
        if self.keys_u is None:
            return False
        m, ju, jl = self._keys_for
        return m == n and torch.equal(ju, iu) and torch.equal(jl, il)

    # ------------------------------------------------------------- forward
    def lower_params(self, eX: Tensor, theta: Tensor, frozen: bool = False) -> Tensor:
        """[n, 10] eq.-2 deformations; ``frozen``: through the networks' weights detached (the
        result's gradient reaches θ and the positions, not MLP_X/S/R)."""
        h = torch.cat([eX, theta.expand(len(eX), -1)], -1)
        if frozen:
            def run(m):
                return torch.func.functional_call(m, {k: v.detach() for k, v in m.named_parameters()}, (h,))
        else:
            def run(m):
                return m(h)
        return torch.cat([run(self.mlp_x), run(self.mlp_s), run(self.mlp_r)], -1)

    def _mapping_input(self, p: Tensor, idx: Tensor, E: Tensor, theta: Tensor) -> tuple[Tensor, bool]:
        """The lower deformations the mapping reads at ``idx`` and whether to detach them: with
        ``map_latent_grad`` they are recomputed through frozen eq.-2 networks, so the upper-face
        loss trains θ but (as with ``detach_lower``) not the lower face's networks."""
        if self.cfg.detach_lower and self.cfg.map_latent_grad and p.requires_grad:  # False under no_grad
            return self.lower_params(E[idx], theta, frozen=True), False
        return p[idx], self.cfg.detach_lower

    def w_gm(self, eU: Tensor, eL: Tensor) -> Tensor:
        """W_gm = row-softmax(φ_U φ_Lᵀ) [|U|, |L|] from embedded positions (eq. 3–4)."""
        return torch.softmax(self.mlp_gm(eU) @ self.mlp_gm(eL).T, -1)

    @torch.no_grad()
    def _running_stats(self, steps: Tensor, bufs: tuple[Tensor, ...], values: tuple[Tensor, ...] | None):
        """Per-channel running statistics kept in the buffers ``bufs``: a bias-corrected EMA over
        steps (momentum ``map_norm_momentum``, step count ``steps``). Folds in ``values`` (one per
        buffer) when given, then returns the corrected estimates, or None before the first step.
        Inside :meth:`refit_statistics` the values are averaged with equal weights instead."""
        m = self.cfg.map_norm_momentum
        if values is not None:
            w = 1 / (float(steps) + 1) if self._refit is not None else m
            for b, v in zip(bufs, values):
                b.mul_(1 - w).add_(w * v)
            steps.add_(1)
        if float(steps) == 0:
            return None
        corr = 1 - (1 - m) ** steps
        return tuple(b / corr for b in bufs)

    def lower_rms(self, pL: Tensor, update: bool) -> Tensor:
        """[10] running RMS of the lower deformation channels, ``update``d by ``pL`` (in training,
        once the networks train; frozen otherwise and saved with the model). Without it (module
        doc, item 5) the upper deformations of a trained Full model varied 26× less across the
        synthetic frames than those of the variant that maps p_L itself."""
        st = self._running_stats(self.p_steps, (self.p_ms,), (pL.detach().pow(2).mean(0),) if update else None)
        if st is None:  # no statistics yet (an untrained model): p_L as it is
            return torch.ones_like(self.p_ms)
        return st[0].sqrt() + 1e-6

    def map_features(self, eU: Tensor, eL: Tensor, pL: Tensor, detach: bool | None = None,
                     gU: Tensor | None = None, gL: Tensor | None = None) -> Tensor:
        """Upper features f_U = W_gm f_L from lower deformations (eq. 3–4, 6), dense over the given
        sets (rows of W_gm in chunks, so |U|·|L| never has to fit at once). ``detach`` (default
        ``detach_lower``): read ``pL`` without passing gradients back into it. ``gU``/``gL``: what
        MLP_gm reads (:meth:`gm_embed`; default the embedded positions ``eU``/``eL``)."""
        update = self._updates_statistics(pL, "p")
        if self.cfg.detach_lower if detach is None else detach:  # upper-face errors cannot reshape the lower face
            pL = pL.detach()
        if self.cfg.map_norm:
            pL = pL / self.lower_rms(pL, update)
        if self.cfg.pm_per_component:
            fL = torch.cat([m(torch.cat([eL, pL[:, a:b]], -1)) for m, a, b in zip(self.mlp_pm, (0, 3, 6), (3, 6, 10))], -1)
        else:
            fL = self.mlp_pm(torch.cat([eL, pL], -1)) if self.cfg.feature_mapping else pL
        gU, gL = eU if gU is None else gU, eL if gL is None else gL
        chunk = max(1, int(2**26 // max(len(eL), 1)))
        return torch.cat([self.w_gm(gU[i:i + chunk], gL) @ fL for i in range(0, len(eU), chunk)])

    def standardise_features(self, fU: Tensor) -> Tensor:
        """``feat_norm``: f_U minus its running mean, over its running standard deviation, per
        channel (updated in training once the networks train; frozen otherwise and saved with the
        model). f_U is mostly a constant (the average of MLP_pm over positions) plus a smaller
        part that follows the expression; standardised, that part reaches MLP_mapping at unit
        scale per channel (module doc, item 5)."""
        if not self.cfg.feat_norm:
            return fU
        f = fU.detach()
        st = self._running_stats(self.f_steps, (self.f_mean, self.f_ms),
                                 (f.mean(0), f.pow(2).mean(0)) if self._updates_statistics(fU, "f") else None)
        if st is None:
            return fU
        mean, ms = st
        # floor: a channel that barely varies is scaled up at most tenfold against its RMS
        return (fU - mean) / ((ms - mean.pow(2)).clamp_min(0) + 0.01 * ms + 1e-12).sqrt()

    def _updates_statistics(self, x: Tensor, which: str) -> bool:
        """Whether this pass folds ``x`` into the running statistics ``which`` ("p": map_norm's,
        "f": feat_norm's): in training once the networks train (not during the static warm-up,
        where ``x`` carries no gradient); inside :meth:`refit_statistics`, in that statistics' pass."""
        return (self.training and x.requires_grad) if self._refit is None else self._refit == which

    @torch.no_grad()
    def refit_statistics(self, crops: Tensor, boxes: Tensor | None = None) -> None:
        """Recompute the running statistics of ``map_norm`` and ``feat_norm`` as plain means over
        the frames ``crops`` [T, 3, crop, crop] (crop boxes ``boxes`` [T, 3]) with the current
        weights: first those of p_L, then, reading p_L by them, those of f_U (as SWA recomputes
        batch-norm statistics for averaged weights). In training the statistics follow the
        weights as an EMA over the last ~50 frames, so they are noisy, and they belong to the
        last steps' weights rather than to averaged ones; a channel of f_U that barely varies is
        divided by its small deviation, which magnifies any offset in its mean."""
        if not self.cfg.gaussian_mapping:
            return
        passes = [("p", self.p_steps, (self.p_ms,))] if self.cfg.map_norm else []
        if self.cfg.feat_norm:
            passes.append(("f", self.f_steps, (self.f_mean, self.f_ms)))
        try:
            for mode, steps, bufs in passes:
                for b in bufs:
                    b.zero_()
                steps.zero_()
                self._refit = mode
                for t in range(len(crops)):
                    self(crops[t:t + 1], None if boxes is None else boxes[t:t + 1])
                steps.fill_(1e6)  # the EMA's bias correction is then exactly 1
        finally:
            self._refit = None

    def decode_upper(self, eU: Tensor, fU: Tensor, theta: Tensor | None = None) -> Tensor:
        """p_U = MLP_mapping(γ(x_U), f_U[, θ]) [n, 10]; with ``pm_per_component`` and three heads
        each head reads the features of its own component."""
        extra = []
        if self.cfg.map_theta:
            if theta is None:
                raise AvatarError("this model's MLP_mapping reads θ (map_theta): pass theta")
            extra = [theta.expand(len(eU), -1)]
        if self.cfg.pm_per_component and self.cfg.mapping_heads == 3:
            F, m = self.cfg.feat_dim, self.mlp_mapping
            return torch.cat([h(torch.cat([eU, fU[:, i * F:(i + 1) * F], *extra], -1))
                              for i, h in enumerate((m.x, m.s, m.r))], -1)
        return self.mlp_mapping(torch.cat([eU, fU, *extra], -1))

    def map_params(self, eU: Tensor, eL: Tensor, pL: Tensor, detach: bool | None = None, theta: Tensor | None = None,
                   gU: Tensor | None = None, gL: Tensor | None = None) -> Tensor:
        """Upper deformations p_U = MLP_mapping(γ(x_U), W_gm f_L) (eq. 3–7; ``map_features``)."""
        return self.decode_upper(eU, self.standardise_features(self.map_features(eU, eL, pL, detach, gU, gL)), theta)

    def map_keys(self, E: Tensor, iu: Tensor, pK: Tensor, detach: bool | None = None, theta: Tensor | None = None,
                 G: Tensor | None = None) -> Tensor:
        """Deformations [|U|, 10] of the upper Gaussians ``iu`` by the mapping between the key
        Gaussians (eq. 9–10; ``refresh_keys`` first), ``pK`` the lower keys' deformations and ``E``
        the embedded positions of all Gaussians. W_dist spreads over the upper Gaussians either
        the upper keys' deformations (``upsample="params"``) or their mapped features f_U, which
        MLP_mapping then turns into a deformation at each upper Gaussian's own position
        (``"features"``): keys lie ~12 mm apart on the synthetic head, so spreading deformations
        blurs an eyelid's closing into the brow and cheek around it."""
        j, w = self.wdist
        G = self.gm_embed(E) if G is None else G
        ku, kl = self.keys_u, self.keys_l
        if self.cfg.upsample == "features":
            fk = self.standardise_features(self.map_features(E[ku], E[kl], pK, detach, G[ku], G[kl]))
            return self.decode_upper(E[iu], (fk[j] * w[..., None]).sum(1), theta)
        pk = self.map_params(E[ku], E[kl], pK, detach, theta, G[ku], G[kl])
        return (pk[j] * w[..., None]).sum(1)

    @property
    def predicts_head_pose(self) -> bool:
        return self.cfg.global_pose and self.cfg.image_pose and hasattr(self, "mlp_head_pose")

    def head_pose_params(self, theta: Tensor) -> Tensor:
        """[B, 6]: the head pose read from the crop's latent — rotation vector (radians) and
        translation / (0.1 × head size), about the head's centre."""
        return self.mlp_head_pose(theta)

    def head_pose_from_params(self, q: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(R, t, pivot) of :meth:`head_pose_params`' output row ``q`` [6]."""
        R = quat_to_rotmat(axis_angle_to_quat(q[:3])[None])[0]
        return R, q[3:] * self.scale * 0.1, self.center

    def pose_params_of(self, R, t, pivot) -> np.ndarray:
        """The inverse of :meth:`head_pose_from_params` for a pose (R, t, pivot) in numpy: the
        [6] target of :meth:`head_pose_params` (the same motion about the head's centre)."""
        from scipy.spatial.transform import Rotation

        R, t, p = (np.asarray(a, np.float64) for a in (R, t, pivot))
        c = self.center.detach().cpu().numpy().astype(np.float64)
        tc = (p - R @ p + t) - (c - R @ c)
        return np.r_[Rotation.from_matrix(R).as_rotvec(), tc / (float(self.scale) * 0.1)]

    def deform(self, theta: Tensor, head_pose=None, read_pose: bool = True) -> GaussianTensors:
        """The Gaussians for latent ``theta`` [1, latent] (eq. 1–10), then the tracked rigid head
        pose ``head_pose`` = (R [3, 3], t [3], pivot [3]) when given (X' = R (X − pivot) + pivot + t);
        the global pose MLP is then the residual the tracker missed.  Without ``head_pose`` a
        model with ``image_pose`` reads the head pose from ``theta`` (``mlp_head_pose``, trained
        on the registration video's poses); ``read_pose=False`` keeps the canonical pose then."""
        g = self.gaussians
        X = g.means
        n = len(X)
        up = self.upper_mask()
        iu, il = torch.nonzero(up).reshape(-1), torch.nonzero(~up).reshape(-1)
        E = self.embed(X)
        one_field = not self.cfg.gaussian_mapping and self.cfg.unmapped_upper == "shared"
        if one_field:  # the eq.-2 networks deform both halves
            p = self.lower_params(E, theta)
        else:
            p = X.new_zeros(n, 10)
            p[il] = self.lower_params(E[il], theta)
        if len(iu) and not one_field:
            if not self.cfg.gaussian_mapping:
                p[iu] = self.mlp_up(torch.cat([E[iu], theta.expand(len(iu), -1)], -1))
            elif len(il) == 0:
                pass
            elif self.cfg.sampling:
                if not self._keys_valid(n, iu, il):
                    self.refresh_keys()
                p[iu] = self.map_keys(E, iu, *self._mapping_input(p, self.keys_l, E, theta), theta=theta)
            else:
                G = self.gm_embed(E)
                p[iu] = self.map_params(E[iu], E[il], *self._mapping_input(p, il, E, theta), theta=theta,
                                        gU=G[iu], gL=G[il])
        dX, dlogS, dq = p[:, :3], p[:, 3:6], p[:, 6:]
        means = X + dX * self.scale * 0.1
        log_scales = g.log_scales + dlogS
        one = torch.tensor([1.0, 0, 0, 0], dtype=X.dtype, device=X.device)
        quats = quat_mul(g.quats / g.quats.norm(dim=-1, keepdim=True), one + dq)
        if self.cfg.global_pose and self.cfg.pose_residual:
            pose = self.mlp_pose(theta)[0]
            qg = axis_angle_to_quat(pose[:3])
            R = quat_to_rotmat(qg[None])[0]
            means = (means - self.center) @ R.T + self.center + pose[3:] * self.scale * 0.1
            quats = quat_mul(qg[None].expand(n, 4), quats)
        if head_pose is None and read_pose and self.predicts_head_pose:
            head_pose = self.head_pose_from_params(self.head_pose_params(theta)[0])
        out = GaussianTensors(means, log_scales, quats, g.opacity_logits, g.colors)
        if head_pose is not None:
            out = out.rigidly_moved(*(torch.as_tensor(a, dtype=X.dtype, device=X.device) if torch.is_tensor(a) else
                                      torch.as_tensor(np.asarray(a), dtype=X.dtype, device=X.device) for a in head_pose))
        return out

    def forward(self, crop: Tensor, box: Tensor | None = None, head_pose=None, read_pose: bool = True) -> GaussianTensors:
        return self.deform(self.encoder(crop, box), head_pose, read_pose)


@torch.no_grad()
def select_keys(model: HFMModel, X: Tensor, iu: Tensor, il: Tensor, n_keys: int, seed: int = 0,
                lower: str = "sample"):
    """Key Gaussians (global indices, sorted): ``n_keys`` upper by farthest-point sampling,
    ``n_keys`` lower by their correlation weight c_l = Σ_u softmax_l(φ_u·φ_l) over the upper keys:
    drawn without replacement with probability ∝ c_l (``lower="sample"``, seeded by ``seed``) or
    the ``n_keys`` largest (``"top"``). All of a half when it has fewer."""
    ku = iu[farthest_point_sampling(X[iu], n_keys, seed)]
    if len(il) <= n_keys:
        return ku, il.clone()
    E = model.gm_embed(model.embed(X))
    corr = model.w_gm(E[ku], E[il]).sum(0)  # correlation weight of each lower Gaussian
    if lower == "top":
        pick = torch.topk(corr, n_keys).indices
    elif lower == "sample":
        gen = torch.Generator().manual_seed(int(seed))
        pick = torch.multinomial(corr.double().cpu(), n_keys, replacement=False, generator=gen).to(il.device)
    else:
        raise AvatarError(f"lower keys: 'sample' or 'top', not {lower!r}")
    return ku, il[pick.sort().values]
