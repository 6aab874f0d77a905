"""Adaptive density control for Gaussian splatting (3DGS, Kerbl et al. 2023, Sec. 5.2).

A strategy object that a training loop calls around ``backward``::

    strategy = DensityStrategy(DensityConfig(), scene_extent=extent)
    for step in range(iters):
        rgb, alpha, depth, info = rasterize(gaussians, cam, return_info=True)
        strategy.step_pre_backward(info)          # info["means2d"].retain_grad()
        loss.backward()
        optimizer.step(); optimizer.zero_grad()   # (either order with the next call)
        strategy.step_post_backward(gaussians, optimizer, info, step)

Rules (3DGS):

* statistics: for every Gaussian visible in a view (radius > 0) accumulate the norm of the
  gradient of the loss with respect to its projected 2D mean, in NDC units — the pixel-space
  gradient times ``(width / 2, height / 2)``, which is what 3DGS and gsplat threshold — and
  the largest screen radius (pixels) seen;
* every ``refine_every`` steps in ``(refine_start, refine_stop)``, with ``ḡ`` the mean
  accumulated gradient norm: **clone** Gaussians with ``ḡ ≥ grad_threshold`` and
  ``max scale ≤ percent_dense · extent`` (an exact copy, both then move apart under the
  optimiser); **split** those with ``ḡ ≥ grad_threshold`` and larger scale into ``split_n``
  children sampled from the parent's own distribution ``N(μ, Σ)``, scales divided by
  ``split_scale_div`` (1.6 = 0.8 · 2 in 3DGS), the parent removed; **prune** Gaussians with
  opacity < ``prune_opacity`` and, after the first opacity reset, those whose screen radius
  exceeded ``max_screen_size`` pixels or whose largest world scale exceeds
  ``max_world_scale · extent``; then the statistics restart;
* every ``reset_every`` steps (before ``refine_stop``): **opacity reset**, opacities clamped
  to ≤ 0.01 (their optimiser moments zeroed).

Children get the ``parent`` (vertex) index of their source Gaussian, so mesh-bound methods
(THGS) keep it through densification. Subclasses add constraints through the hooks
:meth:`DensityStrategy.filter_split` (veto split children, e.g. HFM-GS's plane constraint),
:meth:`DensityStrategy.on_added` and :meth:`DensityStrategy.on_pruned` (keep per-Gaussian
side data in sync).

The optimiser must hold one param group per Gaussian attribute with a ``"name"`` equal to the
attribute (``means``, ``log_scales``, ``quats``, ``opacity_logits``, ``colors``), as
:func:`make_optimizer` builds; :func:`append_gaussians` / :func:`keep_gaussians` replace the
``nn.Parameter``\\ s and extend (zeros) or slice the Adam moments to match.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import Tensor, nn

from geoface.splat.errors import SplatError
from geoface.splat.gaussians import quat_to_rotmat

PARAM_NAMES = ("means", "log_scales", "quats", "opacity_logits", "colors")


@dataclass
class DensityConfig:
    """3DGS density-control schedule and thresholds (defaults as in the paper's code).

    grad_threshold : mean screen-space gradient norm (NDC units, see module doc) that triggers
        clone/split.
    percent_dense : clone if max scale ≤ percent_dense · extent, else split.
    refine_start, refine_stop, refine_every : densify at steps ``refine_start < s <
        refine_stop`` with ``s % refine_every == 0``.
    reset_every : opacity reset period (steps); 0 disables.
    prune_opacity : prune when opacity < this.
    max_screen_size : prune when the screen radius exceeded this many pixels (after the first
        reset); None disables.
    max_world_scale : prune when the largest scale > this · extent (after the first reset).
    split_n, split_scale_div : children per split and the scale divisor (3DGS: 2 and 0.8·2).
    max_gaussians : cap on the count; densification takes the largest gradients first.
    """

    grad_threshold: float = 2e-4
    percent_dense: float = 0.01
    refine_start: int = 500
    refine_stop: int = 15000
    refine_every: int = 100
    reset_every: int = 3000
    prune_opacity: float = 0.005
    max_screen_size: float | None = 20.0
    max_world_scale: float = 0.1
    split_n: int = 2
    split_scale_div: float = 1.6
    max_gaussians: int | None = None

    def __post_init__(self):
        if self.split_n < 1 or self.split_scale_div <= 0:
            raise SplatError(f"split_n must be >= 1 and split_scale_div > 0; got {self.split_n}, "
                             f"{self.split_scale_div}")
        if self.refine_every < 1:
            raise SplatError(f"refine_every must be >= 1; got {self.refine_every}")
        if not 0 < self.prune_opacity < 1:
            raise SplatError(f"prune_opacity must lie in (0, 1); got {self.prune_opacity}")

    def to_dict(self) -> dict:
        return asdict(self)


# ------------------------------------------------------------------ optimiser bookkeeping
def make_optimizer(gaussians, lrs: dict | None = None, **adam_kw) -> torch.optim.Adam:
    """Adam with one named param group per Gaussian attribute (what density control expects).

    ``lrs`` maps attribute → learning rate (defaults: the 3DGS values for a unit-extent scene).
    """
    lr = {"means": 1.6e-4, "log_scales": 5e-3, "quats": 1e-3, "opacity_logits": 5e-2,
          "colors": 2.5e-3, **(lrs or {})}
    groups = [{"params": [getattr(gaussians, n)], "lr": lr[n], "name": n} for n in PARAM_NAMES]
    return torch.optim.Adam(groups, **adam_kw)


def _update(gaussians, optimizer, param_fn, state_fn):
    """Replace every Gaussian parameter ``p`` by ``param_fn(name, p)`` and each per-Gaussian
    optimiser state tensor ``s`` (exp_avg, exp_avg_sq, ...) by ``state_fn(name, s)``."""
    groups = {}
    if optimizer is not None:
        for grp in optimizer.param_groups:
            if grp.get("name") in PARAM_NAMES:
                if len(grp["params"]) != 1:
                    raise SplatError(f"param group {grp['name']!r} must hold exactly one tensor")
                groups[grp["name"]] = grp
    for name in PARAM_NAMES:
        old = getattr(gaussians, name)
        new = nn.Parameter(param_fn(name, old.detach()), requires_grad=old.requires_grad)
        grp = groups.get(name)
        if grp is not None:
            if grp["params"][0] is not old:
                raise SplatError(f"optimizer group {name!r} does not hold gaussians.{name}")
            state = optimizer.state.pop(old, None)
            if state:
                optimizer.state[new] = {k: (state_fn(name, v) if torch.is_tensor(v) and v.ndim > 0
                                            and v.shape[0] == old.shape[0] else v)
                                        for k, v in state.items()}
            grp["params"][0] = new
        setattr(gaussians, name, new)


def append_gaussians(gaussians, optimizer, values: dict, parent: Tensor | None = None) -> None:
    """Append Gaussians given by ``values`` (attribute → [M, ...] tensor) to ``gaussians``;
    the optimiser moments of the new rows are zeros. ``parent`` [M] extends the parent buffer."""
    m = values["means"].shape[0]
    _update(gaussians, optimizer,
            lambda n, p: torch.cat([p, values[n].to(p)], 0),
            lambda n, s: torch.cat([s, s.new_zeros((m,) + s.shape[1:])], 0))
    if getattr(gaussians, "parent", None) is not None:
        extra = parent if parent is not None else torch.full((m,), -1, dtype=torch.int64)
        gaussians.parent = torch.cat([gaussians.parent, extra.to(gaussians.parent)])


def keep_gaussians(gaussians, optimizer, keep: Tensor) -> None:
    """Keep only the Gaussians where ``keep`` [N] bool is true (parameters, optimiser moments
    and the parent buffer sliced alike)."""
    keep = keep.to(gaussians.means.device)
    _update(gaussians, optimizer, lambda n, p: p[keep], lambda n, s: s[keep])
    if getattr(gaussians, "parent", None) is not None:
        gaussians.parent = gaussians.parent[keep.to(gaussians.parent.device)]


def reset_opacity(gaussians, optimizer, value: float = 0.01) -> None:
    """Clamp opacities to ≤ ``value`` (3DGS opacity reset); the opacity moments are zeroed."""
    cap = math.log(value / (1 - value))
    _update(gaussians, optimizer,
            lambda n, p: torch.clamp_max(p, cap) if n == "opacity_logits" else p,
            lambda n, s: torch.zeros_like(s) if n == "opacity_logits" else s)


# ------------------------------------------------------------------ the strategy
class DensityStrategy:
    """3DGS clone / split / prune / opacity reset, with hooks for subclasses (module doc).

    Parameters
    ----------
    cfg : DensityConfig, optional
    scene_extent : float
        Scene size (3DGS: 1.1 × the radius of the camera centres around their mean) that
        ``percent_dense`` and ``max_world_scale`` are relative to.
    """

    def __init__(self, cfg: DensityConfig | None = None, scene_extent: float = 1.0):
        if not scene_extent > 0:
            raise SplatError(f"scene_extent must be positive; got {scene_extent}")
        self.cfg = cfg or DensityConfig()
        self.scene_extent = float(scene_extent)
        self.grad2d = self.count = self.max_radii = None  # [N] running statistics
        self.n_resets = 0

    # ---------------------------------------------------------------- hooks
    def filter_split(self, gaussians, parent_idx: Tensor, child_params: dict) -> Tensor:
        """Return a bool mask [M] over the split children (``child_params``: attribute → [M,..];
        ``parent_idx`` [M] the index of each child's parent). Default: keep all."""
        return torch.ones(len(parent_idx), dtype=torch.bool, device=parent_idx.device)

    def on_added(self, gaussians, src_idx: Tensor, n_new: int) -> None:
        """Called after ``n_new`` Gaussians were appended; ``src_idx`` [n_new] are their sources
        (indices before the append)."""

    def on_pruned(self, gaussians, keep: Tensor) -> None:
        """Called after Gaussians were removed; ``keep`` [N_before] bool marks the survivors."""

    # ---------------------------------------------------------------- per step
    def step_pre_backward(self, info: dict) -> None:
        """Ask autograd to keep the gradient of the 2D means (call before ``backward``)."""
        m = info["means2d"]
        if not m.requires_grad:
            raise SplatError("info['means2d'] does not require grad; render with trainable Gaussians")
        m.retain_grad()

    @torch.no_grad()
    def update_state(self, gaussians, info: dict) -> None:
        """Accumulate ‖∂L/∂means2d‖ (NDC units) and the max screen radius of visible Gaussians."""
        n = len(gaussians)
        dev = gaussians.means.device
        if self.grad2d is None or len(self.grad2d) != n:
            self._reset_stats(n, dev)
        g = info["means2d"].grad
        if g is None:
            raise SplatError("info['means2d'] has no grad; call step_pre_backward before backward")
        g = g.reshape(-1, 2)
        if len(g) != n:
            raise SplatError(f"means2d has {len(g)} rows for {n} Gaussians")
        scale = torch.tensor([info["width"] / 2.0, info["height"] / 2.0], dtype=g.dtype, device=g.device)
        radii = info["radii"].reshape(n)
        vis = radii > 0
        self.grad2d[vis] += (g[vis] * scale).norm(dim=-1).to(self.grad2d.dtype)
        self.count[vis] += 1
        self.max_radii[vis] = torch.maximum(self.max_radii[vis], radii[vis].to(self.max_radii.dtype))

    def step_post_backward(self, gaussians, optimizer, info: dict, step: int) -> dict:
        """Accumulate statistics, then clone/split/prune/reset on schedule.

        Returns ``{"cloned", "split", "pruned", "n", "reset"}``: Gaussians cloned, Gaussians split
        (each replaced by its kept children), pruned, the count afterwards, and whether the
        opacities were reset at this step.
        """
        c = self.cfg
        out = {"cloned": 0, "split": 0, "pruned": 0, "n": len(gaussians), "reset": False}
        if step >= c.refine_stop:
            return out
        self.update_state(gaussians, info)
        if step > c.refine_start and step % c.refine_every == 0:
            out.update(self.densify(gaussians, optimizer))
        if c.reset_every and step > 0 and step % c.reset_every == 0:
            reset_opacity(gaussians, optimizer, 0.01)
            self.n_resets += 1
            out["reset"] = True
        out["n"] = len(gaussians)
        return out

    # ---------------------------------------------------------------- operations
    @torch.no_grad()
    def densify(self, gaussians, optimizer) -> dict:
        """One refinement: clone, split, prune (3DGS ``densify_and_prune``); statistics restart."""
        c = self.cfg
        n = len(gaussians)
        if self.grad2d is None or len(self.grad2d) != n:
            self._reset_stats(n, gaussians.means.device)
        mean_grad = self.grad2d / self.count.clamp_min(1)
        big = mean_grad >= c.grad_threshold
        small = gaussians.log_scales.exp().max(-1).values <= c.percent_dense * self.scene_extent
        clone_idx = torch.nonzero(big & small).reshape(-1)
        split_idx = torch.nonzero(big & ~small).reshape(-1)
        clone_idx, split_idx = self._cap(clone_idx, split_idx, mean_grad, n)
        n_clone = self.clone(gaussians, optimizer, clone_idx)
        n_split = self.split(gaussians, optimizer, split_idx)
        n_pruned = self.prune(gaussians, optimizer)
        self._reset_stats(len(gaussians), gaussians.means.device)
        return {"cloned": n_clone, "split": n_split, "pruned": n_pruned}

    def _cap(self, clone_idx, split_idx, mean_grad, n):
        cap = self.cfg.max_gaussians
        if cap is None:
            return clone_idx, split_idx
        cost = torch.cat([torch.ones_like(clone_idx), torch.full_like(split_idx, self.cfg.split_n - 1)])
        idx = torch.cat([clone_idx, split_idx])
        order = torch.argsort(mean_grad[idx], descending=True, stable=True)
        ok = torch.cumsum(cost[order], 0) <= max(cap - n, 0)
        take = torch.zeros(len(idx), dtype=torch.bool, device=idx.device)
        take[order[ok]] = True
        nc = len(clone_idx)
        return clone_idx[take[:nc]], split_idx[take[nc:]]

    @torch.no_grad()
    def clone(self, gaussians, optimizer, idx: Tensor) -> int:
        """Append exact copies of Gaussians ``idx`` [K]."""
        if len(idx) == 0:
            return 0
        values = {name: getattr(gaussians, name).detach()[idx] for name in PARAM_NAMES}
        self._append(gaussians, optimizer, values, idx)
        return len(idx)

    def split_children(self, gaussians, idx: Tensor) -> tuple[Tensor, dict]:
        """``split_n`` children per Gaussian in ``idx``: means sampled from N(μ, Σ), scales / div.
        Returns (parent index [M], attribute → [M, ...])."""
        k = self.cfg.split_n
        p = idx.repeat_interleave(k)
        means, log_scales = gaussians.means.detach()[p], gaussians.log_scales.detach()[p]
        quats = gaussians.quats.detach()[p]
        # x = μ + R (s ⊙ ε), ε ~ N(0, I): a sample of N(μ, R S² Rᵀ)
        eps = torch.randn_like(means) * log_scales.exp()
        child = {"means": means + (quat_to_rotmat(quats) @ eps[..., None])[..., 0],
                 "log_scales": log_scales - math.log(self.cfg.split_scale_div),
                 "quats": quats,
                 "opacity_logits": gaussians.opacity_logits.detach()[p],
                 "colors": gaussians.colors.detach()[p]}
        return p, child

    @torch.no_grad()
    def split(self, gaussians, optimizer, idx: Tensor) -> int:
        """Replace Gaussians ``idx`` by their children kept by :meth:`filter_split`; a parent
        whose children are all vetoed stays as it is (no hole is opened)."""
        if len(idx) == 0:
            return 0
        p, child = self.split_children(gaussians, idx)
        ok = self.filter_split(gaussians, p, child).to(p.device).reshape(-1).bool()
        if len(ok) != len(p):
            raise SplatError(f"filter_split returned {len(ok)} flags for {len(p)} children")
        done = torch.zeros(len(gaussians), dtype=torch.bool, device=p.device)
        done[p[ok]] = True
        n_before = len(gaussians)
        if bool(ok.any()):
            self._append(gaussians, optimizer, {k: v[ok] for k, v in child.items()}, p[ok])
        keep = torch.ones(len(gaussians), dtype=torch.bool, device=p.device)
        keep[:n_before] = ~done
        self._keep(gaussians, optimizer, keep)
        return int(done.sum())

    @torch.no_grad()
    def prune_mask(self, gaussians) -> Tensor:
        """[N] bool: transparent, or (after the first opacity reset) too big on screen/in the world."""
        c = self.cfg
        mask = gaussians.opacities().detach() < c.prune_opacity
        if self.n_resets > 0:
            if c.max_screen_size is not None and self.max_radii is not None \
                    and len(self.max_radii) == len(gaussians):
                mask |= self.max_radii > c.max_screen_size
            mask |= gaussians.log_scales.detach().exp().max(-1).values > c.max_world_scale * self.scene_extent
        return mask

    @torch.no_grad()
    def prune(self, gaussians, optimizer) -> int:
        mask = self.prune_mask(gaussians)
        k = int(mask.sum())
        if k:
            self._keep(gaussians, optimizer, ~mask)
        return k

    # ---------------------------------------------------------------- internals
    def _append(self, gaussians, optimizer, values, src_idx):
        parent = None
        if getattr(gaussians, "parent", None) is not None:
            parent = gaussians.parent[src_idx.to(gaussians.parent.device)]  # the parent's parent
        append_gaussians(gaussians, optimizer, values, parent)
        if self.grad2d is not None:  # new rows start with empty statistics
            self._extend_stats(len(src_idx))
        self.on_added(gaussians, src_idx, len(src_idx))

    def _keep(self, gaussians, optimizer, keep):
        if bool(keep.all()):
            return
        keep_gaussians(gaussians, optimizer, keep)
        if self.grad2d is not None and len(self.grad2d) == len(keep):
            self.grad2d, self.count, self.max_radii = (a[keep] for a in (self.grad2d, self.count, self.max_radii))
        self.on_pruned(gaussians, keep)

    def _reset_stats(self, n, device):
        self.grad2d = torch.zeros(n, device=device)
        self.count = torch.zeros(n, device=device)
        self.max_radii = torch.zeros(n, device=device)

    def _extend_stats(self, m):
        z = lambda a: torch.cat([a, a.new_zeros(m)])  # noqa: E731
        self.grad2d, self.count, self.max_radii = z(self.grad2d), z(self.count), z(self.max_radii)
