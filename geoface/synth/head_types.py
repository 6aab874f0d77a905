"""The procedural head's parameters and result: identity, expression, the head mesh with its
labels (:mod:`geoface.synth.head`)."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from ..errors import InvalidMeshError

__all__ = ["EXPRESSION_NAMES", "LANDMARK_NAMES", "HeadIdentity", "HeadExpression", "SynthHead"]

TWO_PI = 2.0 * np.pi
MIN_VERTICES, MAX_VERTICES = 1000, 200_000

EXPRESSION_NAMES = (
    "smile", "jaw_open", "pout_left", "pout_right", "pucker",
    "eyes_closed_left", "eyes_closed_right", "cheek_puff", "brow_raise", "frown",
)
LANDMARK_NAMES = (
    "head_top", "forehead", "brow_left", "brow_right", "eye_left_center", "eye_right_center",
    "eye_left_inner", "eye_left_outer", "eye_right_inner", "eye_right_outer", "nose_bridge",
    "nose_tip", "mouth_left", "mouth_right", "upper_lip", "lower_lip", "chin", "ear_left", "ear_right",
)


# ============================================================================ parameters
def _check_float(name: str, value, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InvalidMeshError(f"{name} must be a number in [{lo}, {hi}]; got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < lo or v > hi:
        raise InvalidMeshError(f"{name} must be in [{lo}, {hi}]; got {value!r}")
    return v


def _from_dict(cls, d, what):
    if isinstance(d, cls):
        return d
    if not isinstance(d, dict):
        raise InvalidMeshError(f"{what} must be a {cls.__name__}, a dict or None; got {type(d).__name__}")
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise InvalidMeshError(f"unknown {what} parameter(s) {unknown}; valid: {sorted(names)}")
    return cls(**d)


@dataclass(frozen=True)
class HeadIdentity:
    """Who the head is: shape, proportions and colouring (all floats, validated ranges).

    Attributes
    ----------
    size : float in [0.92, 1.08]
        Overall scale (1 = average adult; chin-to-crown about 0.23-0.24 m).
    width, depth, height : float in [0.9, 1.1]
        Extra scale along X (ear to ear), Z (face to back) and Y (chin to crown).
    jaw_width : float in [-1, 1]
        Narrow, tapered jaw (-1) to wide, square jaw (+1).
    chin : float in [-1, 1]
        Receding, small chin (-1) to prominent chin (+1).
    nose_size : float in [-1, 1]
        Narrow, low nose (-1) to wide, projecting nose (+1).
    nose_length : float in [-1, 1]
        Short (-1) to long (+1) nose (nasion to tip).
    brow : float in [-1, 1]
        Flat (-1) to prominent (+1) brow ridge.
    lips : float in [-1, 1]
        Thin (-1) to full (+1) lips.
    eye_size : float in [-1, 1]
        Small (-1) to large (+1) eye openings.
    cheekbones : float in [-1, 1]
        Flat (-1) to high, prominent (+1) cheekbones.
    masculinity : float in [-1, 1]
        Feminine (-1) to masculine (+1): jaw width and squareness, brow ridge, chin, lip
        fullness, eyebrow thickness, neck width, Adam's apple, overall size.
    skin_tone : float in [0, 1]
        Light (0) to dark (1) skin.
    eye_color : float in [0, 1]
        Blue (0), green/hazel (0.35), light brown (0.65), dark brown (1).
    hair_color : float in [0, 1]
        Black (0), dark brown (0.35), light brown (0.6), blond (0.8), platinum (1).
    hair_length : float in [0, 1]
        Buzz cut (0) to long, voluminous hair covering the nape (1).
    stubble : float in [0, 1]
        Beard shadow (texture and vertex colour only).
    freckles : float in [0, 1]
        Freckle density on nose and cheeks (texture only).
    """

    size: float = 1.0
    width: float = 1.0
    depth: float = 1.0
    height: float = 1.0
    jaw_width: float = 0.0
    chin: float = 0.0
    nose_size: float = 0.0
    nose_length: float = 0.0
    brow: float = 0.0
    lips: float = 0.0
    eye_size: float = 0.0
    cheekbones: float = 0.0
    masculinity: float = 0.0
    skin_tone: float = 0.3
    eye_color: float = 0.6
    hair_color: float = 0.35
    hair_length: float = 0.3
    stubble: float = 0.0
    freckles: float = 0.0

    RANGES = {
        "size": (0.92, 1.08), "width": (0.9, 1.1), "depth": (0.9, 1.1), "height": (0.9, 1.1),
        "jaw_width": (-1.0, 1.0), "chin": (-1.0, 1.0), "nose_size": (-1.0, 1.0), "nose_length": (-1.0, 1.0),
        "brow": (-1.0, 1.0), "lips": (-1.0, 1.0), "eye_size": (-1.0, 1.0), "cheekbones": (-1.0, 1.0),
        "masculinity": (-1.0, 1.0), "skin_tone": (0.0, 1.0), "eye_color": (0.0, 1.0), "hair_color": (0.0, 1.0),
        "hair_length": (0.0, 1.0), "stubble": (0.0, 1.0), "freckles": (0.0, 1.0),
    }

    def __post_init__(self):
        for f in fields(self):
            lo, hi = self.RANGES[f.name]
            object.__setattr__(self, f.name, _check_float(f"HeadIdentity.{f.name}", getattr(self, f.name), lo, hi))

    @classmethod
    def random(cls, rng) -> "HeadIdentity":
        """Sample a plausible identity from ``rng`` (a ``numpy.random.Generator`` or an int seed)."""
        rng = np.random.default_rng(rng)
        m = float(rng.uniform(-1.0, 1.0))

        def nrm(sd, lo=-1.0, hi=1.0, mu=0.0):
            return float(np.clip(rng.normal(mu, sd), lo, hi))

        skin = float(rng.uniform(0.0, 1.0))
        return cls(
            size=nrm(0.02, 0.95, 1.05, 1.0), width=nrm(0.025, 0.94, 1.06, 1.0), depth=nrm(0.025, 0.94, 1.06, 1.0),
            height=nrm(0.02, 0.95, 1.05, 1.0), jaw_width=nrm(0.4), chin=nrm(0.4), nose_size=nrm(0.4),
            nose_length=nrm(0.4), brow=nrm(0.4), lips=nrm(0.4), eye_size=nrm(0.4), cheekbones=nrm(0.4),
            masculinity=m, skin_tone=skin,
            eye_color=float(np.clip(0.85 * skin + rng.uniform(-0.2, 0.6), 0.0, 1.0)),
            hair_color=float(np.clip(rng.uniform(0.0, 1.0) * (1.0 - 0.8 * skin), 0.0, 1.0)),
            hair_length=float(rng.uniform(0.0, 0.35) if m > 0 else rng.uniform(0.45, 1.0)),
            stubble=float(rng.uniform(0.0, 0.8) if m > 0.25 else 0.0),
            freckles=float(rng.uniform(0.0, 1.0) ** 2 * (1.0 - skin)),
        )

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "HeadIdentity":
        return _from_dict(cls, d, "identity")


@dataclass(frozen=True)
class HeadExpression:
    """Expression weights, each a float in [0, 1] (0 = neutral).

    Attributes
    ----------
    smile : mouth corners up, out and back, cheeks raised, lips slightly parted (teeth).
    jaw_open : lower jaw rotates down about a hinge in front of the ears; the lips part
        and the mouth crease opens into a dark cavity with teeth.
    pout_left, pout_right : lips pushed forward and shifted toward the subject's left/right.
    pucker : lips pushed forward, mouth narrowed (corners drawn together).
    eyes_closed_left, eyes_closed_right : the upper lid lowers over the eyeball.
    cheek_puff : cheeks bulge outward.
    brow_raise : brows lift, forehead folds.
    frown : inner brows lowered and drawn together, vertical glabella furrows.
    """

    smile: float = 0.0
    jaw_open: float = 0.0
    pout_left: float = 0.0
    pout_right: float = 0.0
    pucker: float = 0.0
    eyes_closed_left: float = 0.0
    eyes_closed_right: float = 0.0
    cheek_puff: float = 0.0
    brow_raise: float = 0.0
    frown: float = 0.0

    NAMES = EXPRESSION_NAMES

    def __post_init__(self):
        for name in EXPRESSION_NAMES:
            object.__setattr__(self, name, _check_float(f"expression {name}", getattr(self, name), 0.0, 1.0))

    def as_array(self) -> np.ndarray:
        """Weights in ``NAMES`` order, ``(10,)`` float64."""
        return np.array([getattr(self, n) for n in EXPRESSION_NAMES], dtype=np.float64)

    @classmethod
    def from_array(cls, a) -> "HeadExpression":
        a = np.asarray(a, dtype=np.float64).ravel()
        if a.shape != (len(EXPRESSION_NAMES),):
            raise InvalidMeshError(f"expression array must have shape ({len(EXPRESSION_NAMES)},); got {a.shape}")
        return cls(**{n: float(v) for n, v in zip(EXPRESSION_NAMES, a)})

    def to_dict(self) -> dict:
        return {n: getattr(self, n) for n in EXPRESSION_NAMES}

    @classmethod
    def from_dict(cls, d: dict) -> "HeadExpression":
        return _from_dict(cls, d, "expression")


@dataclass(frozen=True)
class SynthHead:
    """One generated head.

    Attributes
    ----------
    V : (n, 3) float64, vertex positions in metres (Y up, face toward +Z, subject's left +X)
    F : (m, 3) int64, counter-clockwise (outward normals); one boundary loop (neck cut)
    colors : (n, 3) float64 in [0, 1], per-vertex colours
    UV : (n, 2) float64 in [0, 1], seamless polar layout of the parameter disk
    texture : (T, T, 3) uint8, row 0 is v = 1; pixel (i, j) centre <-> UV ((j+.5)/T, 1-(i+.5)/T)
    face_mask : (n,) bool, the face (forehead to chin, between the ears)
    upper_face_mask : (n,) bool, vertices above ``eye_line_y`` in the neutral pose
    eye_line_y : float, height of the eye centres (neutral pose)
    landmarks : dict name -> vertex index (see ``LANDMARK_NAMES``)
    identity : HeadIdentity
    expression : HeadExpression
    seed : int
    """

    V: np.ndarray
    F: np.ndarray
    colors: np.ndarray
    UV: np.ndarray
    texture: np.ndarray
    face_mask: np.ndarray
    upper_face_mask: np.ndarray
    eye_line_y: float
    landmarks: dict = field(default_factory=dict)
    identity: HeadIdentity = field(default_factory=HeadIdentity)
    expression: HeadExpression = field(default_factory=HeadExpression)
    seed: int = 0

    def landmark_positions(self) -> dict:
        """Landmark name -> ``(3,)`` position."""
        return {k: self.V[v].copy() for k, v in self.landmarks.items()}

    def mesh(self, texture: bool = True):
        """As a :class:`geoface.mesh.io.Mesh`: the UV layout and texture (``texture=True``) or
        the per-vertex colours (``texture=False``)."""
        from ..mesh.io import Mesh

        if texture:
            return Mesh.from_vertex_uv(self.V, self.F, self.UV, texture=self.texture)
        return Mesh(self.V, self.F, colors=self.colors)


