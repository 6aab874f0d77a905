"""Save / load Gaussians in the standard 3DGS PLY layout (binary little-endian float32).

Properties: x y z nx ny nz f_dc_0..2 f_rest_0..(3(K-1)-1) opacity scale_0..2 rot_0..3,
with f_rest stored channel-major (all R coefficients, then G, then B) as in 3DGS.
Written with numpy (no plyfile needed); atomically (temp file + rename).
"""
from __future__ import annotations

import os
import tempfile

import numpy as np
import torch

from geoface.splat.errors import GaussianPlyError
from geoface.splat.gaussians import Gaussians, rgb_to_sh0


def _fields(k: int) -> list[str]:
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(3 * (k - 1))]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def save_ply(g: Gaussians, path) -> None:
    """Write ``g`` to ``path`` in the 3DGS layout (plain RGB colours become SH degree 0)."""
    with torch.no_grad():
        sh = g.colors.detach().double().cpu()
        if sh.ndim == 2:
            sh = rgb_to_sh0(sh)[:, None]
        n, k, _ = sh.shape
        cols = [g.means.detach().cpu().numpy().astype(np.float32),
                np.zeros((n, 3), np.float32),
                sh[:, 0].numpy().astype(np.float32),
                sh[:, 1:].transpose(1, 2).reshape(n, -1).numpy().astype(np.float32),
                g.opacity_logits.detach().cpu().numpy().astype(np.float32)[:, None],
                g.log_scales.detach().cpu().numpy().astype(np.float32),
                g.quats.detach().cpu().numpy().astype(np.float32)]
    data = np.ascontiguousarray(np.concatenate(cols, 1), dtype="<f4")
    names = _fields(k)
    header = ("ply\nformat binary_little_endian 1.0\n" f"element vertex {n}\n"
              + "".join(f"property float {p}\n" for p in names) + "end_header\n")
    path = os.fspath(path)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), suffix=".ply.tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(header.encode("ascii"))
            f.write(data.tobytes())
        from geoface._io import default_mode

        os.chmod(tmp, default_mode())  # the user's umask, not mkstemp's 0600
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def load_ply(path, dtype=torch.float32) -> Gaussians:
    """Read a 3DGS PLY (binary little-endian, float properties) into :class:`Gaussians`."""
    with open(path, "rb") as f:
        raw = f.read()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise GaussianPlyError(f"{path}: not a PLY file")
    lines = raw[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise GaussianPlyError(f"{path}: only binary_little_endian PLY is supported")
    n, names = None, []
    for ln in lines:
        p = ln.split()
        if p[:2] == ["element", "vertex"]:
            n = int(p[2])
        elif p[:1] == ["property"]:
            if p[1] not in ("float", "float32"):
                raise GaussianPlyError(f"{path}: property {p[-1]} has type {p[1]}; expected float")
            names.append(p[2])
        elif p[:1] == ["element"] and n is not None:
            raise GaussianPlyError(f"{path}: extra element {p[1]} not supported")
    if n is None:
        raise GaussianPlyError(f"{path}: no vertex element")
    n_rest = sum(nm.startswith("f_rest_") for nm in names)
    k = n_rest // 3 + 1
    need = set(_fields(k)) - {"nx", "ny", "nz"}
    missing = sorted(need - set(names))
    if missing or n_rest % 3 or k not in (1, 4, 9, 16):
        raise GaussianPlyError(f"{path}: not in the 3DGS layout (missing {missing}, {n_rest} f_rest)")
    body = raw[end + len(b"end_header\n"):]
    if len(body) < 4 * n * len(names):
        raise GaussianPlyError(f"{path}: truncated ({len(body)} bytes for {n} vertices)")
    arr = np.frombuffer(body[:4 * n * len(names)], dtype="<f4").reshape(n, len(names))
    col = {nm: arr[:, i] for i, nm in enumerate(names)}
    get = lambda *ks: np.stack([col[q] for q in ks], 1)  # noqa: E731
    sh = np.zeros((n, k, 3), np.float32)
    sh[:, 0] = get("f_dc_0", "f_dc_1", "f_dc_2")
    if k > 1:
        sh[:, 1:] = get(*[f"f_rest_{i}" for i in range(n_rest)]).reshape(n, 3, k - 1).transpose(0, 2, 1)
    tt = lambda a: torch.tensor(np.ascontiguousarray(a), dtype=dtype)  # noqa: E731
    return Gaussians(tt(get("x", "y", "z")), tt(get("scale_0", "scale_1", "scale_2")),
                     tt(get("rot_0", "rot_1", "rot_2", "rot_3")), tt(col["opacity"]), tt(sh))
