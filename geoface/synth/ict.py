"""Real heads from the ICT-FaceKit morphable model (USC Institute for Creative Technologies,
MIT licence): a generic neutral head built from light-stage scans of real people, 100
identity modes and 53 ARKit-style expression blendshapes, 68 landmarks and a UV layout.

A head is ``neutral + Σ_k a_k · identity_k + Σ_e b_e · expression_e`` with identity weights
``a_k ~ N(0, 1)`` (the model's own convention) and expression weights ``b_e ∈ [0, 1]``.
Coordinates are centimetres, +y up, +z forward; ``_L`` blendshapes act on the subject's left
(+x).

The model is made of parts (vertex ranges of the model, see :data:`REGIONS`): the skin — the
face and the head and neck, a surface open at the neck, the eyes and the mouth — is what
:meth:`ICTFaceModel.head` returns by default; the eyes, the teeth and the mouth interior come
on request (``parts=("skin", "eyes", "teeth", "mouth")`` or ``parts="all"``).

Where the model comes from (the packed ``.npz`` shipped with geoface, a path, an ICT-FaceKit
clone, ``$GEOFACE_ICT_FACEKIT``) and packing a clone: :mod:`geoface.synth.ict_files`.

>>> from geoface.synth.ict import load_ict_model
>>> model = load_ict_model()                                       # doctest: +SKIP
>>> head = model.head(identity=3, expression={"mouthSmile_L": 1.0, "jawOpen": 0.3})  # doctest: +SKIP
>>> head.V.shape, head.landmarks.shape                               # doctest: +SKIP
((11248, 3), (68,))
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import GeofaceError
from .ict_files import find_model, obj_folder, pack_from_folder, pack_ict, read_obj_polygons

__all__ = ["ICTFaceModel", "ICTModel", "ICTHead", "find_model", "load_ict_model", "ict_head", "random_expression",
           "pack_ict", "read_obj_polygons", "REGIONS", "PART_GROUPS", "DEFAULT_PARTS", "HEAD_POLYGONS",
           "FACE_VERTICES"]

#: polygons 0..11143 of the full model: the face plus head and neck
HEAD_POLYGONS = 11144
#: the model's face area (vertex indices 0..9408; 0..6705 is the narrow face)
FACE_VERTICES = 9409

#: the model's regions as vertex ranges ``[start, stop)`` (from the model's documentation); a
#: polygon belongs to the region of its highest vertex index (mouth-socket polygons share the
#: lip vertices of the skin)
REGIONS = {
    "narrow_face": (0, 6706),
    "outer_face": (6706, 9409),
    "head": (9409, 11248),
    "mouth_socket": (11248, 13294),
    "eye_sockets": (13294, 14062),
    "gums_tongue": (14062, 17039),
    "teeth": (17039, 21451),
    "eyeballs": (21451, 24591),
    "eye_extras": (24591, 26719),  # lacrimal fluid, eye blend, eye occlusion, eyelashes
}
#: names accepted by ``parts=`` besides the region names
PART_GROUPS = {
    "skin": ("narrow_face", "outer_face", "head"),
    "face": ("narrow_face", "outer_face"),
    "mouth": ("mouth_socket", "gums_tongue"),
    "eyes": ("eyeballs", "eye_sockets"),
    "all": tuple(REGIONS),
}
DEFAULT_PARTS = ("skin",)


def _triangulate(P: np.ndarray, Q: np.ndarray, QUV: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quads (or -1-padded triangles) → triangles, quads split along the shorter diagonal;
    the triangles of each polygon stay in polygon order."""
    tri = Q[:, 3] < 0
    d02 = np.linalg.norm(P[Q[:, 0]] - P[Q[:, 2]], axis=1)
    d13 = np.linalg.norm(P[np.maximum(Q[:, 3], 0)] - P[Q[:, 1]], axis=1)
    a = ~tri & (d02 <= d13)
    b = ~tri & ~a
    F = np.concatenate([Q[tri][:, :3], Q[a][:, [0, 1, 2]], Q[a][:, [0, 2, 3]], Q[b][:, [0, 1, 3]], Q[b][:, [1, 2, 3]]])
    FU = np.concatenate([QUV[tri][:, :3], QUV[a][:, [0, 1, 2]], QUV[a][:, [0, 2, 3]], QUV[b][:, [0, 1, 3]], QUV[b][:, [1, 2, 3]]])
    return F.astype(np.int64), FU.astype(np.int64)


def _region_of(idx: np.ndarray) -> np.ndarray:
    """Region number (index into :data:`REGIONS`) of full-model vertex indices."""
    stops = np.array([r[1] for r in REGIONS.values()])
    return np.minimum(np.searchsorted(stops, idx, side="right"), len(stops) - 1)


def _resolve_parts(parts) -> tuple[str, ...]:
    if isinstance(parts, str):
        parts = (parts,)
    out: list[str] = []
    for p in parts:
        names = PART_GROUPS.get(p, (p,) if p in REGIONS else None)
        if names is None:
            raise GeofaceError(f"unknown part {p!r}; parts are {', '.join([*PART_GROUPS, *REGIONS])}")
        out += [n for n in names if n not in out]
    if not out:
        raise GeofaceError("parts must name at least one part")
    return tuple(n for n in REGIONS if n in out)


@dataclass(frozen=True)
class _PartView:
    """The selected regions as one triangle mesh (compact vertex numbering)."""

    vertex_ids: np.ndarray  # (n,) indices into the full model
    F: np.ndarray
    FUV: np.ndarray
    neutral: np.ndarray
    identity_modes: np.ndarray
    expression_modes: np.ndarray
    face_mask: np.ndarray
    landmarks: np.ndarray  # compact indices, -1 where a landmark is not in the parts
    labels: np.ndarray  # region number per vertex


@dataclass(frozen=True)
class ICTHead:
    """A head of the model.

    ``V (n, 3)`` cm, ``F (m, 3)``, texture coordinates ``UV``/``FUV``; ``face_mask (n,)`` (the
    model's face area, the region of interest for OT); ``landmarks (68,)`` vertex indices (the
    Multi-PIE 68; -1 where the parts lack one); ``labels (n,)`` region number of each vertex
    (names in ``region_names``); ``vertex_ids`` the model's own vertex numbers; the weights
    that made it."""

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray
    FUV: np.ndarray
    face_mask: np.ndarray
    landmarks: np.ndarray
    identity: np.ndarray
    expression: dict
    labels: np.ndarray = field(default=None)
    vertex_ids: np.ndarray = field(default=None)
    parts: tuple = DEFAULT_PARTS
    region_names: tuple = tuple(REGIONS)

    def mesh(self):
        """As a :class:`geoface.mesh.io.Mesh` (with the model's UVs)."""
        from ..mesh.io import Mesh

        return Mesh(self.V, self.F, UV=self.UV, FUV=self.FUV)

    def meta(self) -> dict:
        """JSON-ready description: weights, landmarks, face mask (the ``--meta`` file; its
        ``face_mask`` is read by ``geoface convert --roi`` and ``dataset build``)."""
        return {"source": "ict-facekit", "parts": list(self.parts), "identity": [float(x) for x in self.identity],
                "expression": {k: float(v) for k, v in self.expression.items()},
                "landmarks": [int(i) for i in self.landmarks], "face_mask": [int(i) for i in np.flatnonzero(self.face_mask)],
                "regions": {n: int(np.sum(self.labels == k)) for k, n in enumerate(self.region_names) if np.any(self.labels == k)}}


class ICTFaceModel:
    """The ICT-FaceKit model (see module docs).  Build with :func:`load_ict_model` or
    ``ICTFaceModel.load(path)``.

    Attributes of the whole model: ``vertices (N, 3)``, ``polygons (P, 4)`` (-1 pads
    triangles), ``uv``, ``polygon_uv``, ``expression_names``, ``identity_names``,
    ``landmark_ids (68,)``, ``source``.  The default parts (the skin) are also reachable as
    ``neutral``, ``F``, ``UV``, ``FUV``, ``identity_modes``, ``expression_modes``,
    ``face_mask`` and ``landmarks``."""

    def __init__(self, vertices, polygons, uv, polygon_uv, identity_modes, expression_modes, expression_names,
                 landmark_ids, identity_names=None, source: str = ""):
        self.vertices = np.asarray(vertices, np.float64)
        self.polygons = np.asarray(polygons, np.int64)
        self.uv = np.asarray(uv, np.float64)
        self.polygon_uv = np.asarray(polygon_uv, np.int64)
        self._identity_modes = np.asarray(identity_modes)
        self._expression_modes = np.asarray(expression_modes)
        self.expression_names = tuple(str(x) for x in expression_names)
        self.identity_names = tuple(str(x) for x in (identity_names if identity_names is not None else
                                                     [f"identity{k:03d}" for k in range(len(self._identity_modes))]))
        self.landmark_ids = np.asarray(landmark_ids, np.int64)
        self.source = str(source)
        self._views: dict = {}
        n = len(self.vertices)
        if self.polygons.ndim != 2 or self.polygons.shape[1] != 4 or self.polygons.max(initial=-1) >= n:
            raise GeofaceError(f"{source}: polygons must be (P, 4) vertex indices below {n}")
        for name, M, k in (("identity", self._identity_modes, None), ("expression", self._expression_modes, len(self.expression_names))):
            if M.ndim != 3 or M.shape[1:] != (n, 3) or (k is not None and len(M) != k):
                raise GeofaceError(f"{source}: {name} modes of shape {M.shape} do not fit {n} vertices")
        if self.landmark_ids.shape != (68,) or (self.landmark_ids < 0).any() or (self.landmark_ids >= n).any():
            raise GeofaceError(f"{source}: 68 landmark vertex indices expected")
        self._polygon_region = _region_of(self.polygons.max(axis=1))

    # -- loading
    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> "ICTFaceModel":
        return load_ict_model(path)

    @classmethod
    def _from_arrays(cls, z: dict, source: str, landmarks_beside: Path | None = None) -> "ICTFaceModel":
        try:
            lm = z.get("landmarks")
            if lm is None and landmarks_beside is not None and landmarks_beside.is_file():
                lm = json.loads(landmarks_beside.read_text())["multi_pie_68"]
            if lm is None:
                raise GeofaceError(f"{source}: no landmarks in the model and no landmarks.json beside it")
            return cls(z["neutral"], z["faces"], z["uv"], z["face_uv"], z["identity_modes"], z["expression_modes"],
                       z["expression_names"], lm, z.get("identity_names"), source=source)
        except KeyError as e:
            raise GeofaceError(f"{source} is not an ICT-FaceKit model: no {e} array") from None

    @property
    def n_identities(self) -> int:
        return int(self._identity_modes.shape[0])

    @property
    def available_regions(self) -> tuple[str, ...]:
        names = list(REGIONS)
        return tuple(names[k] for k in sorted(set(self._polygon_region.tolist())))

    # -- parts
    def resolve_parts(self, parts=DEFAULT_PARTS) -> tuple[str, ...]:
        """The regions ``parts`` names in this model: a group (``skin``, ``eyes``, ...) gives
        those of its regions the model has (at least one), a region name must exist."""
        have = self.available_regions
        out: list[str] = []
        for p in ((parts,) if isinstance(parts, str) else tuple(parts)):
            names = [n for n in _resolve_parts(p) if n in have]
            if not names:
                raise GeofaceError(f"{self.source} holds no {p} (it has {', '.join(have)})")
            out += [n for n in names if n not in out]
        if not out:
            raise GeofaceError("parts must name at least one part")
        return tuple(n for n in REGIONS if n in out)

    def view(self, parts=DEFAULT_PARTS) -> _PartView:
        names = self.resolve_parts(parts)
        if names in self._views:
            return self._views[names]
        want = np.isin(self._polygon_region, [list(REGIONS).index(n) for n in names])
        Q, QUV = self.polygons[want], self.polygon_uv[want]
        used = np.unique(Q[Q >= 0])
        remap = np.full(len(self.vertices), -1, np.int64)
        remap[used] = np.arange(len(used))
        Qc = np.where(Q >= 0, remap[np.maximum(Q, 0)], -1)
        P = self.vertices[used]
        F, FUV = _triangulate(P, Qc, QUV)
        v = _PartView(vertex_ids=used, F=F, FUV=FUV, neutral=P, identity_modes=self._identity_modes[:, used].astype(np.float32),
                      expression_modes=self._expression_modes[:, used].astype(np.float32), face_mask=used < FACE_VERTICES,
                      landmarks=remap[self.landmark_ids], labels=_region_of(used))
        self._views[names] = v
        return v

    # the skin, for convenience (and the attributes the first version of this module had)
    neutral = property(lambda self: self.view().neutral)
    F = property(lambda self: self.view().F)
    FUV = property(lambda self: self.view().FUV)
    UV = property(lambda self: self.uv)
    identity_modes = property(lambda self: self.view().identity_modes)
    expression_modes = property(lambda self: self.view().expression_modes)
    face_mask = property(lambda self: self.view().face_mask)
    landmarks = property(lambda self: self.view().landmarks)

    # -- heads
    def identity_weights(self, identity=None, *, n_identity: int | None = None) -> np.ndarray:
        """Identity weights from ``identity``: None → all zeros (the mean head), an int → a
        seed for ``N(0, 1)`` weights (the first ``n_identity`` modes, default all), an array →
        itself (checked)."""
        if identity is None:
            return np.zeros(0)
        if isinstance(identity, (int, np.integer)) and not isinstance(identity, bool):
            k = self.n_identities if n_identity is None else int(n_identity)
            if not 0 <= k <= self.n_identities:
                raise GeofaceError(f"n_identity must be in 0..{self.n_identities}; got {n_identity}")
            if identity < 0:
                raise GeofaceError(f"an identity seed must be >= 0; got {identity}")
            return np.random.default_rng(int(identity)).standard_normal(k)
        try:
            a = np.asarray(identity, np.float64).ravel()
        except (TypeError, ValueError):
            raise GeofaceError(f"identity must be a seed or a list of weights; got {identity!r}") from None
        if len(a) > self.n_identities or not np.isfinite(a).all():
            raise GeofaceError(f"identity must hold at most {self.n_identities} finite weights; got {len(a)}")
        return a

    def check_expression(self, expression: dict | None) -> dict:
        out = {}
        for name, w in dict(expression or {}).items():
            if name not in self.expression_names:
                raise GeofaceError(f"unknown expression {name!r}; the model has {', '.join(self.expression_names)}")
            try:
                w = float(w)
            except (TypeError, ValueError):
                raise GeofaceError(f"expression weight of {name} must be a number; got {w!r}") from None
            if not (np.isfinite(w) and 0.0 <= w <= 1.0):
                raise GeofaceError(f"expression weight of {name} must be in [0, 1]; got {w!r}")
            out[name] = w
        return out

    def shape(self, identity=None, expression: dict | None = None, parts=DEFAULT_PARTS, *, n_identity=None) -> np.ndarray:
        """Only the vertex positions of :meth:`head` (``(n, 3)`` cm)."""
        v = self.view(parts)
        a = self.identity_weights(identity, n_identity=n_identity)
        V = v.neutral + np.tensordot(a, v.identity_modes[: len(a)], axes=1) if len(a) else v.neutral.copy()
        return self.add_expression(V, expression, parts)

    def add_expression(self, V: np.ndarray, expression: dict | None, parts=DEFAULT_PARTS) -> np.ndarray:
        """``V`` (a shape of ``parts``, cm) with the blendshapes of ``expression`` added: what
        :meth:`shape` does after the identity, for callers that pose one identity many times."""
        v = self.view(parts)
        for name, w in self.check_expression(expression).items():
            V = V + w * v.expression_modes[self.expression_names.index(name)]
        return V

    def head(self, identity=None, expression: dict | None = None, parts=DEFAULT_PARTS, *, n_identity: int | None = None) -> ICTHead:
        """A head: ``identity`` (None: the mean head; an int: a seed for ``N(0, 1)`` weights;
        an array: the weights of the first modes), ``expression`` ({blendshape: weight in [0,
        1]}), ``parts`` (default the skin; names in :data:`REGIONS` and :data:`PART_GROUPS`)."""
        v = self.view(parts)
        a = self.identity_weights(identity, n_identity=n_identity)
        ex = self.check_expression(expression)
        V = self.shape(a, ex, parts)
        return ICTHead(V=V, F=v.F.copy(), UV=self.uv, FUV=v.FUV, face_mask=v.face_mask.copy(), landmarks=v.landmarks.copy(),
                       identity=a, expression=ex, labels=v.labels.copy(), vertex_ids=v.vertex_ids, parts=self.resolve_parts(parts))


#: the name the first version of this module used
ICTModel = ICTFaceModel


@lru_cache(maxsize=2)
def _load(path: str) -> ICTFaceModel:
    p = Path(path)
    if p.is_dir():
        folder = obj_folder(p)
        return ICTFaceModel._from_arrays(pack_from_folder(folder), source=str(folder))
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as e:
        raise GeofaceError(f"cannot read the ICT-FaceKit model {path}: {e}") from None
    return ICTFaceModel._from_arrays(arrays, source=path, landmarks_beside=p.with_name("landmarks.json"))


def load_ict_model(path: str | os.PathLike | None = None) -> ICTFaceModel:
    """The model (see :func:`find_model` for where it is looked for); cached per file."""
    return _load(str(find_model(path)))


def neck_pivot(V, landmarks, labels) -> np.ndarray:
    """The point a head turns about (the neck: 4 cm below the chin, midway back through the head,
    on the mid-plane), for a head ``V`` (metres, canonical) of the model's parts with its 68
    ``landmarks`` and region ``labels``: where the avatars' captures turn the ICT head."""
    V = np.asarray(V, np.float64)
    chin = V[landmarks[8]]
    return np.array([0.0, chin[1] - 0.04, float(V[np.asarray(labels) == 2, 2].mean())])


def upper_split(V, landmarks) -> float:
    """The height (y, in ``V``'s units) that divides the face under a headset from the face below
    it: 40% of the way from the eyes down to the nose tip."""
    L = np.asarray(V, np.float64)[landmarks]
    y_eye, y_nose = float(L[36:48, 1].mean()), float(L[30, 1])
    return y_eye - 0.4 * (y_eye - y_nose)


def random_expression(rng: np.random.Generator, names, *, count: int = 3, strength: float = 1.0) -> dict:
    """``count`` different blendshapes with weights uniform in ``[0, strength]``."""
    names = list(names)
    pick = rng.choice(len(names), size=min(count, len(names)), replace=False)
    return {names[i]: float(rng.uniform(0.0, strength)) for i in sorted(pick)}


def ict_head(model: ICTFaceModel | None = None, *, identity=None, expression: dict | None = None, seed: int | None = 0,
             n_identity: int | None = None, parts=DEFAULT_PARTS) -> ICTHead:
    """One head of the model: like :meth:`ICTFaceModel.head`, but ``identity=None`` draws
    ``N(0, 1)`` weights from ``seed`` (all modes, or the first ``n_identity``)."""
    m = load_ict_model() if model is None else model
    if identity is None:
        if seed is None:
            seed = int(np.random.SeedSequence().entropy % 2**32)
        identity = m.identity_weights(int(seed), n_identity=n_identity)
    return m.head(identity, expression, parts)
