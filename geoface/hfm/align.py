"""Usage head poses aligned with the image: each frame's pose corrected so that the avatar's
render matches the pixels the headset leaves visible (:mod:`geoface.hfm.usage`).

The lower-landmark poses that HFM-GS fits in use (``--poses landmarks``) miss the frame the
avatar learned in registration where an expression moves the landmarks they are fitted to.
The avatar itself says where it is: driven by the frame's lower-face crop and posed, it is
rendered, and the pose's correction is found by gradient descent on the squared error against
the frame outside the headset mask (the lower face, the jaw's and ears' outline, the neck)."""
from __future__ import annotations

import numpy as np
import torch

from geoface.errors import AvatarError

__all__ = ["align_poses"]


def align_poses(model, video, pose, *, steps: int = 20, lr: float = 2e-3, translation: bool = False,
                smooth: float = 1.5, quiet: bool | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Correct the head pose ``pose`` = (R [T, 3, 3], t [T, 3], pivot [3]) of each frame of
    ``video`` (an :class:`~geoface.hfm.data.HMDVideo` with ``hmd_masks``) by the image.

    For frame ``f`` the avatar is deformed once by the frame's crop; then ``steps`` Adam steps
    (rate ``lr`` radians) move a rotation about the head's centre, applied before the pose,
    against the squared colour error over the pixels outside the headset mask; each frame starts
    from the previous frame's correction. With ``translation`` a translation in the head's frame
    is learned too (rate ``lr`` × half the head's size). The corrections are then smoothed over
    time by a Gaussian of ``smooth`` frames (0: not smoothed). A progress bar unless ``quiet``
    (None: the global setting). Returns the corrected (R, t, pivot), float64."""
    from scipy.ndimage import gaussian_filter1d
    from scipy.spatial.transform import Rotation

    from geoface.progress import progress
    from geoface.avatar.corrections import corrected_pose
    from geoface.splat.gaussians import GaussianTensors
    from geoface.hfm.data import frame_input
    from geoface.splat.rasterizer import rasterize

    if video.hmd_masks is None:
        raise AvatarError("aligning the poses with the image needs the usage folder's hmd_masks/ (which pixels to match)")
    if steps < 1 or not lr > 0 or smooth < 0:
        raise AvatarError(f"pose alignment: steps >= 1, lr > 0, smooth >= 0; got {steps}, {lr}, {smooth}")
    R0, t0, piv = (np.asarray(a, dtype=np.float64) for a in pose)
    dev = model.center.device
    f32 = dict(dtype=torch.float32, device=dev)
    p = torch.tensor(piv, **f32)
    bg = torch.zeros(3, **f32)
    boxes = video.boxes()
    d_rot, d_t = torch.zeros(3, **f32), torch.zeros(3, **f32)
    rots, moves = [], []
    for f in progress(range(len(video)), "aligning the head poses with the image", quiet=quiet, unit="frame"):
        R, t = torch.tensor(R0[f], **f32), torch.tensor(t0[f], **f32)
        target = torch.tensor(video.frames[f], **f32)
        seen = torch.tensor(~video.hmd_masks[f], **f32)
        with torch.no_grad():  # the frame's avatar, fixed (its opacities and colours are the model's own tensors)
            g = model.deform(model.encoder(*(a.to(dev) for a in frame_input(video, f, model.cfg.crop, boxes))),
                             None, read_pose=False)
            g = GaussianTensors(*(a.detach() for a in (g.means, g.log_scales, g.quats, g.opacity_logits, g.colors)))
        d_rot = d_rot.clone().requires_grad_(True)
        d_t = d_t.clone().requires_grad_(translation)
        groups = [{"params": [d_rot], "lr": lr}]
        if translation:
            groups.append({"params": [d_t], "lr": lr * 0.5 * float(model.scale)})
        opt = torch.optim.Adam(groups)
        for _ in range(steps):
            Rn, tn, _ = corrected_pose(R, t, p, d_rot, d_t, model.center)
            img = rasterize(g.rigidly_moved(Rn, tn, p), video.camera, background=bg)[0]
            loss = (((img - target) ** 2).sum(-1) * seen).sum() / seen.sum().clamp_min(1.0)
            opt.zero_grad()
            loss.backward()
            opt.step()
        d_rot, d_t = d_rot.detach(), d_t.detach()
        with torch.no_grad():
            Rn, tn, _ = corrected_pose(R, t, p, d_rot, d_t, model.center)
        rots.append(d_rot.double().cpu().numpy())  # the pose is R0 times its rotation
        moves.append(tn.double().cpu().numpy() - t0[f])
    rots, moves = np.asarray(rots), np.asarray(moves)
    if smooth > 0:  # corrections vary slowly; a frame's own is noisy
        rots = gaussian_filter1d(rots, smooth, axis=0, mode="nearest")
        moves = gaussian_filter1d(moves, smooth, axis=0, mode="nearest")
    R = R0 @ Rotation.from_rotvec(rots).as_matrix()
    return R, t0 + moves, piv
