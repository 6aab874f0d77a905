"""Templates for template-driven Gaussian avatars (THGS): canonical mesh, joint tree, skinning
weights, expression basis, head mask and mouth region — and their loaders.

* :func:`procedural_template` — from the procedural head (:mod:`geoface.synth.head`): joints
  root (base of the neck), neck, head and jaw (the synthetic jaw's own hinge), skinning weights
  from the head's jaw weight and smooth neck/head blends, and an expression basis of its nine
  non-jaw expressions (jaw opening is the jaw joint's job).
* :func:`load_smplx` — an SMPL-X model file (``SMPLX_NEUTRAL.npz`` as distributed; the user
  supplies it: its licence does not let it ship with us). Read with ``numpy.load`` and
  ``allow_pickle=False`` — the ``.pkl`` variant is refused (pickle). Uses ``v_template``, ``f``,
  ``J_regressor``, ``kintree_table``, ``weights`` and the expression directions
  ``shapedirs[:, :, 300:]`` (SMPL-X: 300 shape then expression components).
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from geoface.errors import AvatarError

__all__ = ["Template", "procedural_template", "load_smplx", "SMPLX_SHAPE_DIM"]

SMPLX_SHAPE_DIM = 300
SMPLX_HEAD_JOINTS = (15, 22, 23, 24)  # head, jaw, left eye, right eye
SMPLX_JAW = 22


@dataclass
class Template:
    """A skinned template. Shapes: V (n, 3), F (m, 3), joints (J, 3) rest positions, parents (J,)
    with −1 for the root (a parent precedes its children), weights (n, J) rows summing to 1,
    expr_basis (K, n, 3), head_mask (n,) bool, mouth_box (2, 3) min/max corner of the mouth
    and teeth region, joint_names (J,); optionally the vertices at named face landmarks
    (``landmark_names`` [L], ``landmark_vertices`` [L], e.g. the iBUG-68 names of
    :data:`geoface.avatar.capture.IBUG68_NAMES`), which a capture's ``landmarks.json`` supervises."""

    V: np.ndarray
    F: np.ndarray
    joints: np.ndarray
    parents: np.ndarray
    weights: np.ndarray
    expr_basis: np.ndarray
    head_mask: np.ndarray
    mouth_box: np.ndarray
    joint_names: list
    jaw: int = -1  # index of the jaw joint (-1: none)
    landmark_names: list = field(default_factory=list)
    landmark_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __post_init__(self):
        self.V = np.asarray(self.V, np.float64)
        self.F = np.asarray(self.F, np.int64)
        self.joints = np.asarray(self.joints, np.float64)
        self.parents = np.asarray(self.parents, np.int64)
        self.weights = np.asarray(self.weights, np.float64)
        self.expr_basis = np.asarray(self.expr_basis, np.float64)
        self.head_mask = np.asarray(self.head_mask, bool)
        self.mouth_box = np.asarray(self.mouth_box, np.float64)
        self.landmark_names = [str(x) for x in self.landmark_names]
        self.landmark_vertices = np.asarray(self.landmark_vertices, np.int64).reshape(-1)
        n, J = len(self.V), len(self.joints)
        checks = [
            (self.V.ndim == 2 and self.V.shape[1] == 3, f"V must be (n, 3); got {self.V.shape}"),
            (self.F.ndim == 2 and self.F.shape[1] == 3 and (len(self.F) == 0 or (self.F.min() >= 0 and self.F.max() < n)),
             "F must be (m, 3) indices into V"),
            (self.joints.shape == (J, 3) and J >= 1, f"joints must be (J, 3); got {self.joints.shape}"),
            (self.parents.shape == (J,) and self.parents[0] == -1
             and all(-1 <= p < j for j, p in enumerate(self.parents)) and (self.parents[1:] >= 0).all(),
             "parents must be (J,), −1 for joint 0 only, each parent before its child"),
            (self.weights.shape == (n, J), f"weights must be (n={n}, J={J}); got {self.weights.shape}"),
            (self.expr_basis.ndim == 3 and self.expr_basis.shape[1:] == (n, 3),
             f"expr_basis must be (K, n, 3); got {self.expr_basis.shape}"),
            (self.head_mask.shape == (n,), "head_mask must be (n,)"),
            (self.mouth_box.shape == (2, 3) and bool((self.mouth_box[1] > self.mouth_box[0]).all()),
             "mouth_box must be (2, 3) with max > min"),
            (len(self.joint_names) == J, "one joint name per joint"),
            (len(self.landmark_names) == len(self.landmark_vertices) and len(set(self.landmark_names)) ==
             len(self.landmark_names) and all(0 <= v < n for v in self.landmark_vertices),
             "landmark_names and landmark_vertices: one distinct name per vertex index into V"),
        ]
        for ok, msg in checks:
            if not ok:
                raise AvatarError(f"template: {msg}")
        if not np.isfinite(self.V).all() or not np.isfinite(self.weights).all():
            raise AvatarError("template: non-finite vertices or weights")
        if (self.weights < -1e-9).any() or not np.allclose(self.weights.sum(1), 1.0, atol=1e-6):
            raise AvatarError("template: skinning weights must be non-negative and sum to 1 per vertex")

    @property
    def n_expr(self) -> int:
        return len(self.expr_basis)

    def save(self, path) -> None:
        np.savez(path, V=self.V, F=self.F, joints=self.joints, parents=self.parents, weights=self.weights,
                 expr_basis=self.expr_basis, head_mask=self.head_mask, mouth_box=self.mouth_box,
                 joint_names=np.array(self.joint_names), jaw=np.array(self.jaw),
                 landmark_names=np.array(self.landmark_names, dtype=str), landmark_vertices=self.landmark_vertices)

    @classmethod
    def load(cls, path) -> "Template":
        try:
            with np.load(path, allow_pickle=False) as d:
                lm = ([str(s) for s in d["landmark_names"]], d["landmark_vertices"]) if "landmark_names" in d.files else ()
                return cls(d["V"], d["F"], d["joints"], d["parents"], d["weights"], d["expr_basis"],
                           d["head_mask"], d["mouth_box"], [str(s) for s in d["joint_names"]], int(d["jaw"]), *lm)
        except (OSError, KeyError, ValueError, EOFError, TypeError, IndexError, zipfile.BadZipFile) as e:
            raise AvatarError(f"{path}: not a geoface template ({type(e).__name__}: {e})") from None


def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def procedural_template(n_vertices: int = 8000, seed: int = 0, identity=None) -> Template:
    """The procedural head as a skinned template (module doc); returns the Template."""
    from geoface.synth.head import EXPRESSION_NAMES, head_model

    model = head_model(n_vertices, seed, identity)
    h = model.mesh()
    V = h.V
    sc = model._shape.scale
    w_jaw = np.clip(model._shape.jaw_weight(model._P0), 0.0, 1.0)
    y = V[:, 1]
    lm = h.landmarks
    y_chin = float(V[lm["chin"], 1])
    y_min = float(y.min())
    # neck → head blend over the throat, root → neck over the bottom of the neck
    w_head = smoothstep((y - (y_chin - 0.035)) / 0.05)
    w_neck_all = smoothstep((y - (y_min + 0.01)) / 0.04)
    W = np.zeros((len(V), 4))
    W[:, 3] = w_jaw * w_head
    W[:, 2] = (1 - w_jaw) * w_head
    W[:, 1] = (1 - w_head) * w_neck_all
    W[:, 0] = (1 - w_head) * (1 - w_neck_all)
    W /= W.sum(1, keepdims=True)
    hinge = model._shape.hinge * sc
    joints = np.array([[0.0, y_min + 0.005, -0.01], [0.0, y_chin - 0.045, -0.015],
                       [0.0, y_chin - 0.01, -0.01], hinge])
    names = [n for n in EXPRESSION_NAMES if n != "jaw_open"]
    B = model.blendshapes()
    basis = np.stack([B[EXPRESSION_NAMES.index(n)] for n in names])
    head_mask = w_head > 0.5
    P = V[[lm["mouth_left"], lm["mouth_right"], lm["upper_lip"], lm["lower_lip"]]]
    lo, hi = P.min(0), P.max(0)
    lo = lo - [0.004, 0.006, 0.02]  # the teeth and the inner mouth lie behind the lips
    hi = hi + [0.004, 0.006, 0.004]
    return Template(V, h.F, joints, np.array([-1, 0, 1, 2]), W, basis, head_mask, np.stack([lo, hi]),
                    ["root", "neck", "head", "jaw"], jaw=3)


def load_smplx(path, n_expr: int = 10) -> Template:
    """An SMPL-X model file (.npz) as a Template (module doc)."""
    path = Path(path)
    if path.suffix.lower() == ".pkl":
        raise AvatarError(f"{path}: pickle model files are not read (unsafe); use the .npz release of SMPL-X")
    try:
        with np.load(path, allow_pickle=False) as d:
            V = np.asarray(d["v_template"], np.float64)
            F = np.asarray(d["f"], np.int64)
            Jreg = np.asarray(d["J_regressor"], np.float64)
            kin = np.asarray(d["kintree_table"], np.int64)
            W = np.asarray(d["weights"], np.float64)
            sd = np.asarray(d["shapedirs"], np.float64)
    except (OSError, KeyError, ValueError) as e:
        raise AvatarError(f"{path}: not an SMPL-X model file ({type(e).__name__}: {e})") from None
    if Jreg.ndim != 2 or Jreg.shape[1] != len(V):
        raise AvatarError(f"{path}: J_regressor must be (J, {len(V)}); got {Jreg.shape}")
    J = Jreg.shape[0]
    if kin.shape != (2, J):
        raise AvatarError(f"{path}: kintree_table must be (2, {J}); got {kin.shape}")
    parents = kin[0].copy()
    parents[0] = -1
    if sd.ndim != 3 or sd.shape[:2] != (len(V), 3) or sd.shape[2] <= SMPLX_SHAPE_DIM:
        raise AvatarError(f"{path}: shapedirs must be ({len(V)}, 3, >{SMPLX_SHAPE_DIM}) with expression directions")
    E = np.moveaxis(sd[:, :, SMPLX_SHAPE_DIM:SMPLX_SHAPE_DIM + n_expr], 2, 0)
    joints = Jreg @ V
    head_j = [j for j in SMPLX_HEAD_JOINTS if j < J]
    head = W[:, head_j].sum(1) > 0.5
    jaw = SMPLX_JAW if SMPLX_JAW < J else -1
    front = V[:, 2] > (joints[jaw, 2] if jaw >= 0 else V[:, 2].mean())
    mouth = (W[:, jaw] > 0.5) & front if jaw >= 0 else head
    if not mouth.any():
        mouth = head
    M = V[mouth]
    box = np.stack([M.min(0) - 0.005, M.max(0) + 0.005])
    names = [f"joint_{j}" for j in range(J)]
    return Template(V, F, joints, parents, W, E, head, box, names, jaw=jaw)
