"""Procedural, expressive, textured human head: the embedded demo mesh and training-data source.

The head is one analytic surface, a topological disk whose only boundary loop is the cut at
the bottom of the neck.  It is built in three layers:

1. **Base shape.**  Horizontal cross-sections (super-ellipses with separate front/back
   semi-axes and exponents) whose parameters are smooth profiles of the height ``y``
   (cranium cap, face, jaw, chin, neck), lofted and read back as a radial function
   ``r(d)`` of the unit direction ``d`` seen from a centre inside the head.
2. **Features.**  Smooth radial displacements in face-chart coordinates of the base
   surface (brow ridge, eye sockets with eyeballs and lids, nose with bridge, tip, alae
   and nostrils, lips with the mouth crease, cheeks, chin, ears, Adam's apple, hair).
   A radial displacement keeps the surface star-shaped, so the map is injective.
3. **Expressions.**  Vector displacements of the neutral surface (a hinge rotation of
   the lower jaw that opens the mouth crease into a dark cavity, smiles, pouts, lids, brows).

The mesh: rings of vertices at constant normalised meridian arc length, equally spaced in
3D along each ring, stitched by a vectorised merge, then relaxed tangentially *in the
parameter disk* (3D umbrella updates pulled back through the numerical Jacobian), so the
triangles are near-isotropic while every vertex stays exactly on the analytic surface.
The parameter disk doubles as a seamless UV layout.

Conventions: metres, ``Y`` up, the face looks toward ``+Z``, the subject's left is ``+X``;
``F`` is counter-clockwise seen from outside.  Connectivity, UVs, masks and landmark
indices depend only on ``(n_vertices, identity)``; expressions change ``V`` and colours.

Examples
--------
>>> from geoface.synth.head import HeadModel, procedural_head
>>> head = procedural_head(n_vertices=3000, seed=1, expression={"smile": 1.0})
>>> head.V.shape[1], head.F.shape[1], head.texture.dtype.name
(3, 3, 'uint8')
>>> model = HeadModel(n_vertices=3000, seed=1)
>>> neutral, open_ = model.mesh(), model.mesh({"jaw_open": 1.0})
>>> bool((neutral.F == open_.F).all())
True
>>> model.blendshapes().shape[0]
10

The code: :mod:`geoface.synth.head_types` (identity, expression, the result),
:mod:`geoface.synth.head_shape` (the analytic surface and its colours),
:mod:`geoface.synth.head_mesh` (meshing and fine texture detail), and here the model that
ties them together.
"""
from __future__ import annotations

from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import InvalidMeshError
from .head_mesh import ValueNoise3D, DiskParam, relax_tangential, ring_layout, snap_landmarks, stitch_rings, texture_detail
from .head_colors import head_colors
from .head_shape import sphere_dirs, HeadShape
from .head_types import (EXPRESSION_NAMES, LANDMARK_NAMES, MAX_VERTICES, MIN_VERTICES, HeadExpression, HeadIdentity,
                         SynthHead)

__all__ = [
    "EXPRESSION_NAMES",
    "LANDMARK_NAMES",
    "HeadExpression",
    "HeadIdentity",
    "HeadModel",
    "SynthHead",
    "head_model",
    "procedural_head",
]


def _check_int(name, value, lo, hi):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InvalidMeshError(f"{name} must be an integer in [{lo}, {hi}]; got {value!r}")
    if not lo <= int(value) <= hi:
        raise InvalidMeshError(f"{name} must be in [{lo}, {hi}]; got {int(value)}")
    return int(value)


class HeadModel:
    """A procedural head of fixed connectivity that can wear any expression.

    Builds and caches the template once: the analytic surface of the identity, the ring
    mesh relaxed in the parameter disk, UVs, masks, landmark indices, neutral colours and
    texture.  :meth:`mesh` then only evaluates displacement fields, so generating many
    expressions (or :meth:`blendshapes`) is fast.

    Parameters
    ----------
    n_vertices : int in [1000, 200000]
        Requested vertex count (the mesh has exactly this many vertices).
    seed : int >= 0
        Seeds the identity (when ``identity`` is None) and the texture detail.
    identity : HeadIdentity, dict or None
        Who the head is; sampled from ``seed`` when None.
    texture_size : int in [16, 4096]
        Side ``T`` of the ``(T, T, 3)`` texture.

    Raises
    ------
    InvalidMeshError
        An argument is out of range or of the wrong type.

    Examples
    --------
    >>> model = HeadModel(n_vertices=2000, seed=3)
    >>> smile = model.mesh({"smile": 1.0})
    >>> smile.V.shape == model.mesh().V.shape
    True
    """

    def __init__(self, n_vertices: int = 20000, seed: int = 0, identity=None, texture_size: int = 512):
        self.n_vertices = _check_int("n_vertices", n_vertices, MIN_VERTICES, MAX_VERTICES)
        self.seed = _check_int("seed", seed, 0, 2**63 - 1)
        self.texture_size = _check_int("texture_size", texture_size, 16, 4096)
        if identity is None:
            identity = HeadIdentity.random(np.random.default_rng([self.seed, 1]))
        self.identity = HeadIdentity.from_dict(identity)
        self._noise = ValueNoise3D(self.seed)
        self._build()

    # ---------------------------------------------------------------- template
    def _build(self):
        n = self.n_vertices
        shape = HeadShape(self.identity)
        nt = int(np.clip(2.0 * np.sqrt(n), 200, 900))
        nphi = int(np.clip(np.sqrt(n), 128, 512))
        par = DiskParam(shape, nt, nphi)
        self._shape, self._par = shape, par
        # the neutral texture depends only on the surface: worker threads colour its row blocks
        # meanwhile (numpy releases the GIL); the blocks are assembled in order, so bytes are deterministic
        T = self.texture_size
        step = int(np.clip(-(-T // 4), 1, max(1, (1 << 18) // T)))
        with ThreadPoolExecutor(max_workers=2) as pool:
            blocks = [pool.submit(self._texture_block, np.arange(r, min(T, r + step))) for r in range(0, T, step)]
            self._build_mesh(shape, par, n)
            blocks = [b.result() for b in blocks]
        self._texture0 = np.concatenate([b[0] for b in blocks]).reshape(T, T, 3)
        self._tex_idx = np.concatenate([b[1] for b in blocks])
        self._tex_P0 = np.concatenate([b[2] for b in blocks])

    def _build_mesh(self, shape, par, n):
        rho, phi, ring_id, n_k, start = ring_layout(par, n)
        F = stitch_rings(phi, n_k, start)
        p = np.stack([rho * np.sin(phi), -rho * np.cos(phi)], axis=1)
        fixed = ring_id == ring_id[-1]
        landmarks = snap_landmarks(par, p, F, fixed, self._landmark_dirs(shape))
        p = relax_tangential(par, p, F, fixed, iters=4 if n <= 20000 else 6)
        d = par.dirs_of_p(p)
        bnd = np.flatnonzero(ring_id == ring_id[-1])          # exactly on the cut y = y_cut
        d[bnd] = sphere_dirs(par._theta_max(phi[bnd]), phi[bnd])
        P0, Pn = shape.neutral(d)
        self._F, self._p, self._d, self._P0, self._Pn = F, p, d, P0, Pn
        self._UV = par.uv_of_p(p)
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        self._face_mask = ((np.abs(x) / 0.068) ** 2.5 + (np.abs(y + 0.019) / 0.1) ** 2.5 < 1.0) & (z > 0.015)
        Vn = Pn * shape.scale
        self._landmarks = {k: landmarks[k] for k in LANDMARK_NAMES}
        self._eye_line_y = float(0.5 * (Vn[landmarks["eye_left_center"], 1] + Vn[landmarks["eye_right_center"], 1]))
        self._upper = Vn[:, 1] > self._eye_line_y
        C, reg = head_colors(shape, P0, regions=True)
        self._colors0 = texture_detail(C, reg, P0, self.identity, self._noise, fine=False)

    @staticmethod
    def _landmark_dirs(shape):
        """Ray directions of the landmarks (design points on the base chart)."""
        c = shape.centre
        e, mo, b, nz = shape.eye, shape.mouth, shape.brow, shape.nose
        hu, hl = shape.lip_heights(np.zeros(1))
        ym = float(shape.mouth_line(np.zeros(1))[0])
        front = {
            "forehead": (0.0, 0.058), "nose_bridge": (0.0, 0.0), "nose_tip": (0.0, nz["yt"] - 0.001),
            "upper_lip": (0.0, ym + 0.6 * float(hu[0])), "lower_lip": (0.0, ym - 0.6 * float(hl[0])), "chin": (0.0, -0.099),
        }
        for sg, side in ((1.0, "left"), (-1.0, "right")):
            front[f"brow_{side}"] = (sg * 0.032, b["y"] + b["arch"] * np.exp(-0.5 * (0.002 / 0.012) ** 2))
            front[f"eye_{side}_center"] = (sg * (e["x"] - 0.0003), e["y"] - 0.0002)
            front[f"eye_{side}_inner"] = (sg * (e["x"] + e["exi"] + 0.0005), e["y"] - 0.0005)
            front[f"eye_{side}_outer"] = (sg * (e["x"] + e["exo"] - 0.0005), e["y"] + 0.0015)
            front[f"mouth_{side}"] = (sg * mo["mw"], float(shape.mouth_line(np.array([mo["mw"]]))[0]))
        names = list(front)
        xy = np.array([front[k] for k in names])
        pts = np.column_stack([xy, np.full(len(xy), 0.085)])
        ear = np.array([[0.08, -0.011, -0.016], [-0.08, -0.011, -0.016]])
        for _ in range(8):   # fixed point: the base point with these chart (x, y) / (y, z) coordinates
            d = np.vstack([pts, ear]) - c
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            P0 = c + shape.base(d)[:, None] * d
            pts[:, 2] = P0[: len(pts), 2]
            ear[:, 0] = P0[len(pts):, 0]
        out = {"head_top": np.array([0.0, 1.0, 0.0])}
        out.update({k: d[i] for i, k in enumerate(names)})
        out["ear_left"], out["ear_right"] = d[len(pts)], d[len(pts) + 1]
        return out

    def _texels(self, rows):
        """Base points ``(len(rows) * T, 3)`` under the texel centres of the given texture rows."""
        T = self.texture_size
        u = (np.arange(T) + 0.5) / T
        U, Vv = np.meshgrid(u, 1.0 - (rows + 0.5) / T)          # row i <-> v = 1 - (i + 0.5) / T
        p = self._par.p_of_uv(np.stack([U.ravel(), Vv.ravel()], axis=1))
        d = self._par.dirs_of_p(p)
        return self._shape.centre + self._shape.base(d)[:, None] * d

    def _texture_colors(self, P0, e):
        C, reg = head_colors(self._shape, P0, e, regions=True)
        return texture_detail(C, reg, P0, self.identity, self._noise, fine=True)

    def _texture_block(self, rows):
        """Neutral colours of the texture rows ``rows``, plus the texels (flat indices, base points)
        that expressions recolour (eyes and mouth)."""
        T = self.texture_size
        P0 = self._texels(rows)
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        eye = (np.abs(np.abs(x) - 0.0315) < 0.022) & (np.abs(y - 0.004) < 0.013) & (z > 0.02)
        mouth = (np.abs(x) < 0.04) & (np.abs(y - self._shape.mouth["ym"]) < 0.012) & (z > 0.02)
        k = np.flatnonzero(eye | mouth)
        C = self._texture_colors(P0, np.zeros(len(EXPRESSION_NAMES))).astype(np.float32)
        return C, k + int(rows[0]) * T, P0[k]

    def _texture(self, e):
        tex = self._texture0.reshape(-1, 3).copy()
        if e[0] or e[1] or e[5] or e[6]:
            tex[self._tex_idx] = self._texture_colors(self._tex_P0, e)
        T = self.texture_size
        return np.round(tex.reshape(T, T, 3) * 255.0).astype(np.uint8)

    # ---------------------------------------------------------------- public
    @property
    def F(self) -> np.ndarray:
        """Faces ``(m, 3)`` int64 (shared by every expression; a copy)."""
        return self._F.copy()

    def _expression(self, expression) -> HeadExpression:
        if expression is None:
            return HeadExpression()
        return HeadExpression.from_dict(expression)

    def vertices(self, expression=None) -> np.ndarray:
        """Vertex positions ``(n, 3)`` for ``expression`` (HeadExpression, dict or None)."""
        e = self._expression(expression).as_array()
        D = self._shape.displacement(self._P0, self._Pn, self._d, e) if e.any() else 0.0
        return (self._Pn + D) * self._shape.scale

    def mesh(self, expression=None) -> SynthHead:
        """The head wearing ``expression`` (HeadExpression, dict of weights, or None for neutral).

        Returns
        -------
        SynthHead
            Same ``F``, ``UV``, masks and landmark indices for every expression.
        """
        expr = self._expression(expression)
        e = expr.as_array()
        V = self.vertices(expr)
        if e[0] or e[1] or e[5] or e[6]:
            C, reg = head_colors(self._shape, self._P0, e, regions=True)
            colors = texture_detail(C, reg, self._P0, self.identity, self._noise, fine=False)
        else:
            colors = self._colors0.copy()
        return SynthHead(
            V=V, F=self._F.copy(), colors=colors, UV=self._UV.copy(), texture=self._texture(e),
            face_mask=self._face_mask.copy(), upper_face_mask=self._upper.copy(), eye_line_y=self._eye_line_y,
            landmarks=dict(self._landmarks), identity=self.identity, expression=expr, seed=self.seed,
        )

    def blendshapes(self) -> np.ndarray:
        """``(10, n, 3)``: vertices with expression ``k`` at 1 minus the neutral vertices (NAMES order)."""
        V0 = self.vertices()
        out = np.empty((len(EXPRESSION_NAMES), len(V0), 3))
        for k, name in enumerate(EXPRESSION_NAMES):
            out[k] = self.vertices({name: 1.0}) - V0
        return out


#: the last few models built, per process, by their arguments (:func:`head_model`)
MODEL_CACHE_SIZE = 4
#: models with a larger texture than this are built each time, not kept
MODEL_CACHE_TEXTURE = 1024
_MODELS: OrderedDict = OrderedDict()


def head_model(n_vertices: int = 20000, seed: int = 0, identity=None, texture_size: int = 512) -> HeadModel:
    """The :class:`HeadModel` of these arguments, built once per process while it is among the
    last :data:`MODEL_CACHE_SIZE` asked for (a head asked for again, as a capture's template and
    then its frames, is not built twice; a texture above :data:`MODEL_CACHE_TEXTURE`² is not kept);
    a model is not changed by its methods, so the one returned is shared."""
    key = (_check_int("n_vertices", n_vertices, MIN_VERTICES, MAX_VERTICES), _check_int("seed", seed, 0, 2**63 - 1),
           None if identity is None else HeadIdentity.from_dict(identity),
           _check_int("texture_size", texture_size, 16, 4096))
    model = _MODELS.pop(key, None)
    if model is None:
        model = HeadModel(n_vertices=key[0], seed=key[1], identity=key[2], texture_size=key[3])
    if key[3] > MODEL_CACHE_TEXTURE:  # a large texture is not held on to (4096²: 200 MB a model)
        return model
    _MODELS[key] = model
    while len(_MODELS) > MODEL_CACHE_SIZE:
        _MODELS.popitem(last=False)
    return model


def procedural_head(n_vertices: int = 20000, seed: int = 0, identity=None, expression=None,
                    texture_size: int = 512) -> SynthHead:
    """Generate one procedural head (see :class:`HeadModel` for the parameters).

    Examples
    --------
    >>> head = procedural_head(2000, seed=0, expression={"jaw_open": 0.5})
    >>> len(head.V), head.UV.shape, sorted(head.landmarks)[:2]
    (2000, (2000, 2), ['brow_left', 'brow_right'])
    """
    return head_model(n_vertices, seed, identity, texture_size).mesh(expression)
