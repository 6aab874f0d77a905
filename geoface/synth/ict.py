"""Real heads from the ICT-FaceKit morphable model (USC Institute for Creative Technologies,
MIT licence): a generic neutral head built from light-stage scans of real people, 100
identity modes and 53 ARKit-style expression blendshapes.

A head is ``neutral + Σ_k a_k · identity_k + Σ_e b_e · expression_e`` with identity weights
``a_k ~ N(0, 1)`` (the model's own convention) and expression weights ``b_e ∈ [0, 1]``.  Only
the skin surface is used — the face, head and neck (polygons 0–11143 of the model), open at
the neck, the eyes and the mouth; the eyeballs, teeth, gums and lashes are dropped.
Coordinates are centimetres, +y up, +z forward.

The model file (``ict_facekit.npz``, packed from the ICT-FaceKit repository) is found from
the ``path`` argument, the environment variable ``GEOFACE_ICT_FACEKIT``, or the project's
data folders; :func:`find_model` says where it looked.

>>> from geoface.synth.ict import ict_head, find_model
>>> head = ict_head(seed=0) if find_model(required=False) else None   # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import GeofaceError

__all__ = ["ICTModel", "ICTHead", "find_model", "load_ict_model", "ict_head", "random_expression", "HEAD_POLYGONS",
           "FACE_VERTICES"]

#: polygons 0..11143 of the model: the face plus head and neck
HEAD_POLYGONS = 11144
#: the model's face area (vertex indices 0..9408 of the full model; 0..6705 is the narrow face)
FACE_VERTICES = 9409

_ENV = "GEOFACE_ICT_FACEKIT"
_NAME = "ict_facekit.npz"


def _candidates() -> list[Path]:
    here = Path(__file__).resolve()
    repo = here.parents[2]
    out = []
    if os.environ.get(_ENV):
        out.append(Path(os.environ[_ENV]))
    out += [repo.parent / "shared" / "data" / "ict_facekit" / _NAME, repo / "data" / "ict_facekit" / _NAME,
            repo / "tests" / "data" / "ict_facekit" / "ict_facekit_head_small.npz"]
    return out


def find_model(path: str | os.PathLike | None = None, *, required: bool = True) -> Path | None:
    """The model file: ``path`` (a file, or a folder holding ``ict_facekit.npz``), else
    ``$GEOFACE_ICT_FACEKIT``, else the project's data folders.  Raises :class:`GeofaceError`
    naming the places tried when none exists (or returns None with ``required=False``)."""
    tried = []
    for p in ([Path(path)] if path is not None else _candidates()):
        p = p / _NAME if p.is_dir() else p
        tried.append(str(p))
        if p.is_file():
            return p
    if required:
        raise GeofaceError(f"the ICT-FaceKit model was not found (tried {', '.join(tried)}); pass its path or set {_ENV}")
    return None


@dataclass(frozen=True)
class ICTModel:
    """The skin surface of the model.

    neutral : (n, 3) float64 cm; F : (m, 3) int64 triangles (quads split along the shorter
    diagonal of the neutral head); UV : (t, 2), FUV : (m, 3) texture coordinates;
    identity_modes : (k, n, 3) float32; expression_modes : (e, n, 3) float32;
    expression_names : e names; face_mask : (n,) bool, the model's face area;
    landmarks : (68,) Multi-PIE landmark vertex indices (into ``neutral``)."""

    neutral: np.ndarray
    F: np.ndarray
    UV: np.ndarray
    FUV: np.ndarray
    identity_modes: np.ndarray
    expression_modes: np.ndarray
    expression_names: tuple
    face_mask: np.ndarray
    landmarks: np.ndarray
    source: str = field(default="", compare=False)

    @property
    def n_identities(self) -> int:
        return int(self.identity_modes.shape[0])


def _triangulate(P: np.ndarray, Q: np.ndarray, QUV: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quads (or -1-padded triangles) → triangles, quads split along the shorter diagonal."""
    tri = Q[:, 3] < 0
    d02 = np.linalg.norm(P[Q[:, 0]] - P[Q[:, 2]], axis=1)
    d13 = np.linalg.norm(P[np.maximum(Q[:, 3], 0)] - P[Q[:, 1]], axis=1)
    a = ~tri & (d02 <= d13)
    b = ~tri & ~a
    F = np.concatenate([Q[tri][:, :3], Q[a][:, [0, 1, 2]], Q[a][:, [0, 2, 3]], Q[b][:, [0, 1, 3]], Q[b][:, [1, 2, 3]]])
    FU = np.concatenate([QUV[tri][:, :3], QUV[a][:, [0, 1, 2]], QUV[a][:, [0, 2, 3]], QUV[b][:, [0, 1, 3]], QUV[b][:, [1, 2, 3]]])
    return F.astype(np.int64), FU.astype(np.int64)


@lru_cache(maxsize=2)
def _load(path: str) -> ICTModel:
    try:
        z = np.load(path, allow_pickle=False)
        faces = np.asarray(z["faces"], np.int64)
        face_uv = np.asarray(z["face_uv"], np.int64)
        neutral = np.asarray(z["neutral"], np.float64)
        uv = np.asarray(z["uv"], np.float64)
        idm = np.asarray(z["identity_modes"], np.float32)
        exm = np.asarray(z["expression_modes"], np.float32)
        names = tuple(str(x) for x in z["expression_names"])
        lm = np.asarray(z["landmarks"], np.int64) if "landmarks" in z.files else None
    except (OSError, KeyError, ValueError) as e:
        raise GeofaceError(f"cannot read the ICT-FaceKit model {path}: {e}") from None
    if lm is None:
        import json

        lp = Path(path).with_name("landmarks.json")
        if not lp.is_file():
            raise GeofaceError(f"{path}: no landmarks in the file and no landmarks.json beside it")
        lm = np.asarray(json.loads(lp.read_text())["multi_pie_68"], np.int64)
    Q = faces[:HEAD_POLYGONS] if len(faces) > HEAD_POLYGONS else faces
    QUV = face_uv[: len(Q)]
    used = np.unique(Q[Q >= 0])
    remap = np.full(len(neutral), -1, np.int64)
    remap[used] = np.arange(len(used))
    Qc = np.where(Q >= 0, remap[np.maximum(Q, 0)], -1)
    P = neutral[used]
    F, FUV = _triangulate(P, Qc, QUV)
    face_mask = used < FACE_VERTICES
    lm_c = remap[lm]
    if (lm_c < 0).any():
        raise GeofaceError(f"{path}: landmarks outside the head surface")
    return ICTModel(neutral=P, F=F, UV=uv, FUV=FUV, identity_modes=idm[:, used], expression_modes=exm[:, used],
                    expression_names=names, face_mask=face_mask, landmarks=lm_c, source=path)


def load_ict_model(path: str | os.PathLike | None = None) -> ICTModel:
    """The model's skin surface (see module docs); cached per file."""
    return _load(str(find_model(path)))


@dataclass(frozen=True)
class ICTHead:
    """A head of the model: ``V (n, 3)`` cm, ``F (m, 3)``, texture coordinates ``UV``/``FUV``,
    ``face_mask (n,)`` (the model's face area, the natural region of interest),
    ``landmarks (68,)`` vertex indices, and the weights that made it."""

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray
    FUV: np.ndarray
    face_mask: np.ndarray
    landmarks: np.ndarray
    identity: np.ndarray
    expression: dict

    def mesh(self):
        """As a :class:`geoface.mesh.io.Mesh` (with the model's UVs)."""
        from ..mesh.io import Mesh

        return Mesh(self.V, self.F, UV=self.UV, FUV=self.FUV)


def random_expression(rng: np.random.Generator, names, *, count: int = 3, strength: float = 1.0) -> dict:
    """``count`` different blendshapes with weights uniform in ``[0, strength]``."""
    names = list(names)
    pick = rng.choice(len(names), size=min(count, len(names)), replace=False)
    return {names[i]: float(rng.uniform(0.0, strength)) for i in sorted(pick)}


def ict_head(model: ICTModel | None = None, *, identity=None, expression: dict | None = None, seed: int | None = 0,
             n_identity: int | None = None) -> ICTHead:
    """One head of the model.

    Parameters
    ----------
    model : from :func:`load_ict_model` (default: the model found by :func:`find_model`)
    identity : (k,) weights of the first k identity modes; None draws ``N(0, 1)`` weights for
        all of them (or the first ``n_identity``) from ``seed``
    expression : {blendshape name: weight in [0, 1]}; None is neutral (use
        :func:`random_expression` for a random one)
    """
    m = load_ict_model() if model is None else model
    rng = np.random.default_rng(seed)
    if identity is None:
        k = m.n_identities if n_identity is None else int(n_identity)
        if not 0 <= k <= m.n_identities:
            raise GeofaceError(f"n_identity must be in 0..{m.n_identities}; got {n_identity}")
        identity = rng.standard_normal(k)
    a = np.asarray(identity, np.float64).ravel()
    if len(a) > m.n_identities or not np.isfinite(a).all():
        raise GeofaceError(f"identity must hold at most {m.n_identities} finite weights; got {len(a)}")
    V = m.neutral + np.tensordot(a, m.identity_modes[: len(a)].astype(np.float64), axes=1)
    expression = dict(expression or {})
    for name, w in expression.items():
        if name not in m.expression_names:
            raise GeofaceError(f"unknown expression {name!r}; the model has {', '.join(m.expression_names)}")
        if not (np.isfinite(w) and 0.0 <= w <= 1.0):
            raise GeofaceError(f"expression weight of {name} must be in [0, 1]; got {w!r}")
        V = V + float(w) * m.expression_modes[m.expression_names.index(name)].astype(np.float64)
    return ICTHead(V=V, F=m.F.copy(), UV=m.UV, FUV=m.FUV, face_mask=m.face_mask.copy(), landmarks=m.landmarks.copy(),
                   identity=a, expression=expression)
