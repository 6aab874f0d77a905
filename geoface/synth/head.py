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
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, fields

import numpy as np
from scipy import ndimage
from scipy.interpolate import PchipInterpolator

from ..errors import InvalidMeshError
from ..mesh.core import signed_uv_areas, vertex_adjacency, vertex_face_incidence

__all__ = [
    "EXPRESSION_NAMES",
    "LANDMARK_NAMES",
    "HeadExpression",
    "HeadIdentity",
    "HeadModel",
    "SynthHead",
    "procedural_head",
]

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


# ============================================================================ helpers
def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _gauss(a, b, sa, sb):
    return np.exp(-0.5 * ((a / sa) ** 2 + (b / sb) ** 2))


def _dirs(theta, phi):
    """Unit directions; theta from +Y, phi from +Z toward +X."""
    st = np.sin(theta)
    return np.stack([st * np.sin(phi), np.cos(theta), st * np.cos(phi)], axis=-1)


def _mix(C, col, w):
    """``C * (1 - w) + col * w`` (in place where ``w > 0``); ``col`` is (3,) or per-row (k, 3)."""
    w = np.asarray(w, dtype=np.float64)
    idx = np.flatnonzero(w > 0.0)
    if len(idx) == 0:
        return C
    col = np.asarray(col, dtype=np.float64)
    col = col[idx] if col.ndim == 2 else col
    wi = np.minimum(w[idx], 1.0)[:, None]
    C[idx] = C[idx] * (1.0 - wi) + col * wi
    return C


def _palette(t, stops):
    """Piecewise-linear colour ramp: ``stops`` = [(t, (r, g, b)), ...]."""
    ts = np.array([s[0] for s in stops])
    cs = np.array([s[1] for s in stops], dtype=np.float64)
    return np.array([np.interp(t, ts, cs[:, k]) for k in range(3)])


SKIN = [(0.0, (0.96, 0.81, 0.71)), (0.3, (0.87, 0.66, 0.53)), (0.6, (0.67, 0.46, 0.33)), (1.0, (0.36, 0.23, 0.16))]
HAIR = [(0.0, (0.05, 0.04, 0.035)), (0.35, (0.20, 0.12, 0.07)), (0.6, (0.42, 0.29, 0.17)),
        (0.8, (0.70, 0.55, 0.34)), (1.0, (0.86, 0.78, 0.60))]
IRIS = [(0.0, (0.30, 0.46, 0.64)), (0.35, (0.36, 0.44, 0.26)), (0.65, (0.43, 0.28, 0.13)), (1.0, (0.17, 0.10, 0.05))]

# canonical section profiles (metres): y -> value below the crown cap that starts at Y0
Y0, YTOP = 0.02, 0.125
PROFILES = {
    "w": [(0.02, 0.076), (0.0, 0.0745), (-0.015, 0.072), (-0.03, 0.068), (-0.05, 0.062), (-0.07, 0.0575),
          (-0.09, 0.056), (-0.11, 0.0555), (-0.14, 0.055), (-0.17, 0.0556), (-0.21, 0.062), (-0.3, 0.076)],
    "zf": [(0.02, 0.092), (0.008, 0.0895), (-0.01, 0.0875), (-0.03, 0.0875), (-0.05, 0.089), (-0.066, 0.089),
           (-0.08, 0.0855), (-0.095, 0.0835), (-0.104, 0.079), (-0.111, 0.068), (-0.116, 0.054), (-0.121, 0.043),
           (-0.13, 0.039), (-0.16, 0.040), (-0.21, 0.046), (-0.3, 0.052)],
    "zb": [(0.02, 0.106), (0.0, 0.1055), (-0.02, 0.102), (-0.04, 0.095), (-0.055, 0.086), (-0.068, 0.076),
           (-0.08, 0.071), (-0.1, 0.069), (-0.16, 0.069), (-0.21, 0.077), (-0.3, 0.092)],
    "nf": [(0.02, 2.2), (0.0, 2.4), (-0.02, 2.6), (-0.05, 2.4), (-0.07, 2.2), (-0.09, 1.8), (-0.105, 1.6),
           (-0.115, 1.8), (-0.125, 2.0), (-0.3, 2.0)],
    "nb": [(0.02, 2.1), (-0.05, 2.1), (-0.08, 2.0), (-0.3, 2.0)],
}
CAP_EXP = {"w": 2.4, "zf": 2.6, "zb": 2.2}

# mouth crease width (chart metres): the crease walls become the inside of the mouth when it opens;
# t = y - mouth_line: upper lip inside > T_UT > upper teeth > T_CU > cavity > T_CL > lower teeth > T_LT
SIG_C = 0.0015
T_UT, T_CU, T_CL, T_LT = 1.1 * SIG_C, 0.35 * SIG_C, -0.5 * SIG_C, -1.0 * SIG_C

# ============================================================================ shape
class _Shape:
    """Canonical head surface of one identity: ``X(d) = S (c + r(d) d)``."""

    centre = np.array([0.0, -0.025, -0.005])
    y_cut = -0.195
    _ny, _y_lo = 2048, -0.32

    def __init__(self, ident: HeadIdentity, ntheta: int = 144, nphi: int = 288):
        self.ident = ident
        m = ident.masculinity
        self.scale = ident.size * (1.0 + 0.03 * m) * np.array([ident.width, ident.height, ident.depth])
        self._features(ident)
        self._profiles(ident)
        self._table(ntheta, nphi)

    # ---------------------------------------------------------------- parameters
    def _features(self, ident):
        m = ident.masculinity
        L = 1.0 + 0.1 * ident.nose_length + 0.03 * m
        S = 1.0 + 0.15 * ident.nose_size + 0.08 * m
        self.nose = dict(yn=0.011, yt=0.011 - 0.037 * L, ys=0.011 - 0.054 * L, amp=0.021 * S * (0.9 + 0.1 * L),
                         w0=0.0052 * S, w1=0.0035 * S, ala=0.0145 * (1.0 + 0.12 * ident.nose_size + 0.04 * m))
        f = 1.0 + 0.25 * ident.lips - 0.15 * m
        self.mouth = dict(ym=-0.0655 - 0.001 * L, mw=0.026 * (1.0 + 0.03 * m), up=0.0045 * f, lo=0.0058 * f,
                          hu=0.0078 * (1.0 + 0.15 * ident.lips - 0.08 * m), hl=0.0095 * (1.0 + 0.15 * ident.lips - 0.08 * m))
        e = 1.0 + 0.08 * ident.eye_size - 0.05 * m
        self.eye = dict(x=0.0315, y=0.004, exi=-0.0152 * e, exo=0.0142 * e, hu=0.0063 * e, hl=0.0049 * e)
        self.brow = dict(amp=0.003 * max(1.0 + 0.5 * ident.brow + 0.5 * m, 0.15), y=0.021 - 0.0015 * m,
                         arch=0.0035 * (1.0 - 0.35 * m), thick=0.0032 * (1.0 + 0.25 * m))
        self.cheek = dict(amp=0.0035 * (1.0 + 0.5 * ident.cheekbones - 0.15 * m), y=-0.008 + 0.002 * ident.cheekbones,
                          fat=0.002 * (1.0 - 0.4 * m))
        self.chin = dict(amp=0.0075 * (1.0 + 0.4 * ident.chin + 0.25 * m), sx=0.014 * (1.0 + 0.25 * m))
        self.adam = 0.0045 * max(m, 0.0)
        hl = ident.hair_length
        self.hairp = dict(thick=0.003 + 0.009 * hl, nape=-0.068 - 0.05 * hl, behind=-0.015 - 0.045 * hl,
                         sideburn=0.012 - 0.02 * max(m, 0.0), curtain=_smoothstep((hl - 0.45) / 0.3),
                         bottom=-0.06 - 0.07 * hl)

    def _profiles(self, ident):
        m = ident.masculinity
        yg = np.linspace(self._y_lo, YTOP, self._ny)
        jaw = _smoothstep((-0.04 - yg) / 0.03) * _smoothstep((yg + 0.13) / 0.02)
        neck = _smoothstep((-0.105 - yg) / 0.02)
        chin = np.exp(-0.5 * ((yg + 0.1) / 0.01) ** 2)
        self.prof = {}
        for k, pts in PROFILES.items():
            pts = sorted(pts)
            f = PchipInterpolator([p[0] for p in pts], [p[1] for p in pts], extrapolate=True)
            v = f(np.minimum(yg, Y0))
            if k == "w":
                v = v * (1.0 + jaw * (0.05 * ident.jaw_width + 0.04 * m) + neck * 0.09 * m)
            elif k == "zf":
                v = v + chin * (0.003 * ident.chin + 0.002 * m) + neck * 0.004 * m
            elif k == "zb":
                v = v + neck * 0.004 * m
            elif k == "nf":
                v = v + jaw * (0.3 * m + 0.2 * ident.jaw_width)
            v = ndimage.gaussian_filter1d(v, {"nf": 35.0, "nb": 35.0, "w": 22.0}.get(k, 12.0), mode="nearest")
            if k in CAP_EXP:
                u = np.clip((yg - Y0) / (YTOP - Y0), 0.0, 1.0)
                v = v * (1.0 - u ** CAP_EXP[k]) ** (1.0 / CAP_EXP[k])
            self.prof[k] = v
        self._pack = np.stack([self.prof[k] for k in ("w", "zf", "zb", "nf", "nb")], axis=1)

    # ---------------------------------------------------------------- base (lofted sections)
    def section(self, y, sx, sz):
        """Horizontal radius of the section at height ``y`` toward unit (sx, sz)."""
        f = (np.clip(y, self._y_lo, YTOP) - self._y_lo) * ((self._ny - 1) / (YTOP - self._y_lo))
        i = np.minimum(f.astype(np.int64), self._ny - 2)
        u = (f - i)[:, None]
        p = self._pack[i] * (1.0 - u) + self._pack[i + 1] * u          # columns: w, zf, zb, nf, nb
        front = sz >= 0
        n = np.where(front, p[:, 3], p[:, 4])
        zz = np.where(front, p[:, 1], p[:, 2])
        s = (np.abs(sx) / np.maximum(p[:, 0], 1e-9)) ** n + (np.abs(sz) / np.maximum(zz, 1e-9)) ** n
        return np.maximum(s, 1e-300) ** (-1.0 / n)

    def _solve(self, theta, phi, lo=None, hi=None, iters=26):
        """Distance from the centre to the lofted surface along each ray (bisection in [lo, hi])."""
        st, ct = np.sin(theta), np.cos(theta)
        dx, dz = st * np.sin(phi), st * np.cos(phi)
        c = self.centre

        def outside(r):
            px, py, pz = c[0] + r * dx, c[1] + r * ct, c[2] + r * dz
            rh = np.maximum(np.hypot(px, pz), 1e-12)
            return (rh >= self.section(py, px / rh, pz / rh)) | (py >= YTOP)

        lo = np.zeros_like(theta) if lo is None else lo
        hi = np.full_like(theta, 0.7) if hi is None else hi
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            out = outside(mid)
            hi = np.where(out, mid, hi)
            lo = np.where(out, lo, mid)
        return 0.5 * (lo + hi)

    def _table(self, ntheta, nphi):
        self._th_top = np.deg2rad(177.0)
        pad = 6
        th = np.arange(-pad, ntheta + pad) * (self._th_top / (ntheta - 1))
        ph = np.arange(nphi) * (TWO_PI / nphi)
        T, P = np.meshgrid(th, ph, indexing="ij")
        T, P = np.abs(T).ravel(), np.where(T < 0, P + np.pi, P).ravel()
        # coarse solve on every 4th ray, then a bracketed refinement (falls back where it fails)
        sub = ((np.arange(len(th)) % 4 == 0)[:, None] & (np.arange(nphi) % 4 == 0)[None, :]).ravel()
        rc = self._solve(T[sub], P[sub]).reshape(-1, nphi // 4)
        I, J = np.meshgrid(np.arange(len(th)) / 4.0, np.arange(nphi) / 4.0, indexing="ij")
        guess = ndimage.map_coordinates(rc, [I.ravel(), J.ravel()], order=1, mode="nearest")
        lo, hi = np.maximum(guess - 0.008, 0.0), guess + 0.008
        r = self._solve(T, P, lo, hi, iters=13)
        bad = (r - lo < 1e-6) | (hi - r < 1e-6)
        if bad.any():
            r[bad] = self._solve(T[bad], P[bad])
        self._coef = ndimage.spline_filter(r.reshape(len(th), nphi), order=3, mode="grid-wrap")
        self._pad, self._nth, self._nph = pad, ntheta, nphi

    def base(self, d):
        """Base radius along unit directions ``d`` (bicubic spline of the lofted table)."""
        theta = np.arccos(np.clip(d[:, 1], -1.0, 1.0))
        phi = np.mod(np.arctan2(d[:, 0], d[:, 2]), TWO_PI)
        i = theta * ((self._nth - 1) / self._th_top) + self._pad
        j = phi * (self._nph / TWO_PI)
        return ndimage.map_coordinates(self._coef, [i, j], order=3, mode="grid-wrap", prefilter=False)

    # ---------------------------------------------------------------- features
    def mouth_corner(self, ax):
        """1 between the mouth corners, 0 beyond them."""
        return _smoothstep((self.mouth["mw"] + 0.0005 - ax) / 0.004)

    def mouth_line(self, x):
        return self.mouth["ym"] - 0.0018 * (x / self.mouth["mw"]) ** 2

    def lip_heights(self, x):
        mo = self.mouth
        ax = np.abs(x)
        hu = mo["hu"] * np.sqrt(np.maximum(1 - (x / mo["mw"]) ** 2, 0)) + 0.0012 * np.exp(-0.5 * ((ax - 0.005) / 0.003) ** 2) \
            - 0.0008 * np.exp(-0.5 * (x / 0.002) ** 2)
        hl = mo["hl"] * np.sqrt(np.maximum(1 - (x / (mo["mw"] + 0.0005)) ** 2, 0))
        return hu, hl

    def eye_frame(self, ax, y):
        """Eye-local coordinates, corner parameter ``u`` (-1 inner, +1 outer) and lid margins."""
        e = self.eye
        ex, ey = ax - e["x"], y - e["y"]
        u = (ex - 0.5 * (e["exi"] + e["exo"])) / (0.5 * (e["exo"] - e["exi"]))
        uc = np.clip(u, -1.0, 1.0)
        env = (1.0 - uc * uc) ** 0.75
        yc = -0.0005 + 0.001 * (uc + 1.0)
        up = yc + e["hu"] * env * (1.0 - 0.12 * uc)
        lo = yc - e["hl"] * env * (1.0 + 0.1 * uc)
        return ex, ey, u, up, lo

    def eye_opening(self, ax, y, closed, soft=0.0014):
        ex, ey, u, up, lo = self.eye_frame(ax, y)
        up = up + closed * (lo + 0.0004 - up)
        din = np.minimum(up - ey, ey - lo)
        return _smoothstep(din / soft + 0.3) * _smoothstep((1.0 - np.abs(u)) / 0.08), (ex, ey, u, up, lo)

    def eyes(self, ax, y, closed):
        opening, (ex, ey, u, up, lo) = self.eye_opening(ax, y, closed)
        socket = -0.0085 * _gauss(ex, ey - 0.002, 0.017, 0.0125)
        bulge = 0.0062 * _gauss(ex, ey, 0.0105, 0.0085)
        env = np.exp(-0.5 * (ex / 0.012) ** 4)
        _, _, _, up0, _ = self.eye_frame(ax, y)
        crease = -0.0011 * env * np.exp(-0.5 * ((ey - up0 - 0.0065) / 0.0016) ** 2)
        lower = 0.0005 * env * np.exp(-0.5 * ((ey - lo + 0.0025) / 0.0015) ** 2)
        return socket + bulge - 0.0019 * opening + crease + lower

    def _nose(self, x, y):
        n = self.nose
        prog = np.clip((n["yn"] - y) / (n["yn"] - n["yt"]), 0.0, 1.4)
        P = 0.001 + n["amp"] * prog ** 1.2
        cut = _smoothstep((y - (n["ys"] + 0.001)) / (n["yt"] - n["ys"] - 0.001))
        top = _smoothstep((0.02 - y) / 0.012)
        wid = n["w0"] + n["w1"] * np.clip(prog, 0, 1)
        dorsum = P * cut * top * np.exp(-0.5 * (x / wid) ** 2)
        ax = np.abs(x)
        yb = n["ys"] + 0.008
        tip = 0.0055 * _gauss(x, y - n["yt"] + 0.0015, 0.0078, 0.0068)
        alae = 0.0085 * _gauss(ax - n["ala"], y - yb, 0.0062, 0.006)
        nostril = -0.004 * _gauss(ax - 0.0063, y - yb + 0.0025, 0.003, 0.0022)
        crease = -0.0015 * _gauss(ax - n["ala"] - 0.0065, y - yb - 0.001, 0.0025, 0.007)
        return dorsum + tip + alae + nostril + crease

    def _mouth(self, x, y):
        mo = self.mouth
        ax = np.abs(x)
        ym = self.mouth_line(x)
        hu, _ = self.lip_heights(x)
        muzzle = 0.006 * _gauss(x, y - ym - 0.004, 0.028, 0.02)
        xenv = np.exp(-0.5 * (x / (mo["mw"] * 0.7)) ** 4)
        upper = mo["up"] * xenv * np.exp(-0.5 * ((y - ym - 0.004) / 0.0042) ** 2)
        border = 0.0007 * xenv * np.exp(-0.5 * ((y - ym - hu) / 0.001) ** 2)
        lower = mo["lo"] * np.exp(-0.5 * (x / (mo["mw"] * 0.64)) ** 4) * np.exp(-0.5 * ((y - ym + 0.0058) / 0.0052) ** 2)
        # exponential groove: steep walls down to the centre line, so rings of vertices land in every band
        crease = -0.009 * self.mouth_corner(ax) * np.exp(-np.sqrt((y - ym) ** 2 + 0.0002**2) / SIG_C)
        dimple = -0.0015 * _gauss(ax - mo["mw"] - 0.0005, y - ym, 0.003, 0.003)
        philtrum = (-0.0008 * np.exp(-0.5 * (x / 0.0025) ** 2) + 0.0005 * np.exp(-0.5 * ((ax - 0.0045) / 0.0015) ** 2)) \
            * _smoothstep((y - ym - hu) / 0.002) * _smoothstep((self.nose["ys"] - y) / 0.003)
        return muzzle + upper + border + lower + crease + dimple + philtrum

    def _ears(self, x, y, z):
        side = _smoothstep((np.abs(x) - 0.03) / 0.02)
        ze, ye, tilt = -0.012, -0.013, np.deg2rad(15.0)
        c, s = np.cos(tilt), np.sin(tilt)
        ez = c * (z - ze) + s * (y - ye)
        ey = -s * (z - ze) + c * (y - ye)
        a, b = 0.0165, 0.031
        q = np.sqrt((ez / a) ** 2 + (ey / b) ** 2)
        hf = 0.5 + 0.5 * _smoothstep(0.3 - ez / a)
        edge = 0.3 + 0.1 * _smoothstep(-ey / b * 2.0)             # the front attaches to the head
        back = _smoothstep(0.5 - ez / (0.6 * a))                  # blend front (attached) and back (free) edges
        body = back * _smoothstep((1.35 - q) / 0.45) + (1.0 - back) * _smoothstep((1.05 - q) / edge)
        rim = np.exp(-0.5 * ((q - 0.86) / 0.095) ** 2) * _smoothstep((ey + 0.6 * b) / (0.3 * b) + 0.5)
        concha = 0.008 * _gauss(ez - 0.004, ey + 0.004, 0.006, 0.01)
        tragus = 0.003 * _gauss(ez - 0.011, ey + 0.005, 0.003, 0.003)
        anti = 0.003 * np.exp(-0.5 * ((q - 0.55) / 0.07) ** 2) * _smoothstep(-ez / a + 0.3)
        return side * (hf * (0.010 * body + 0.004 * rim + anti) - concha + tragus)

    #: hairline height by azimuth (degrees from the front); None = set by the identity
    HAIRLINE = [(0, 0.077), (20, 0.075), (35, 0.066), (48, 0.056), (58, 0.042), (65, 0.024), (70, None),
                (74, None), (78, None), (83, 0.016), (90, 0.027), (98, 0.03), (108, 0.022), (117, None), (140, None),
                (160, None), (180, None)]

    def hair_mask(self, P):
        """Scalp hair coverage in [0, 1] at base points ``P``."""
        psi = np.degrees(np.abs(np.arctan2(P[:, 0], P[:, 2])))
        h = self.hairp
        sb = h["sideburn"]
        fill = {70: 0.006 + 0.5 * sb, 74: sb - 0.008, 78: 0.5 * sb - 0.002, 117: h["behind"],
                140: h["nape"] + 0.012, 160: h["nape"] + 0.003, 180: h["nape"]}
        k = np.array([(a, fill.get(a, b)) for a, b in self.HAIRLINE], dtype=np.float64)
        yh = np.interp(psi, k[:, 0], k[:, 1])
        return _smoothstep((P[:, 1] - yh) / 0.005 + 0.5)

    def hair(self, P):
        """(radial hair thickness, hair colour weight) at base points ``P``.

        Scalp hair is a layer over the hairline mask; long hair adds a curtain that falls
        from the widest part of the head behind the ears down toward the neck cut.
        """
        h = self.hairp
        hm = self.hair_mask(P)
        top = _smoothstep((P[:, 1] + 0.01) / 0.09)
        layer = h["thick"] * (0.55 + 0.45 * top) * hm
        if h["curtain"] <= 0:
            return layer, hm
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        rb = np.maximum(np.hypot(x, z), 1e-9)
        rtop = self.section(np.full(len(P), -0.005), x / rb, z / rb) + h["thick"] * (0.55 + 0.45 * _smoothstep(0.005 / 0.09))
        taper = 1.0 - 0.22 * _smoothstep((-0.005 - y) / 0.13)
        fill = np.maximum(rtop * taper - rb, 0.0) * _smoothstep((-0.005 - y) / 0.02 + 1.0)
        psi = np.degrees(np.abs(np.arctan2(x, z)))
        w = h["curtain"] * _smoothstep((psi - 100.0) / 35.0) * _smoothstep((y - h["bottom"]) / 0.03)
        horiz = np.maximum(np.hypot(x, z - self.centre[2]) / np.maximum(np.linalg.norm(P - self.centre, axis=1), 1e-9), 0.5)
        curtain = w * fill / horiz
        k = 0.004
        hh = np.clip(0.5 + 0.5 * (layer - curtain) / k, 0.0, 1.0)
        return curtain + (layer - curtain) * hh + k * hh * (1.0 - hh), np.maximum(hm, w * _smoothstep(fill / 0.004))

    def detail(self, P):
        """Neutral radial displacement ``(n,)`` of all features at base points ``P`` (canonical)."""
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        ax = np.abs(x)
        front = _smoothstep((z - 0.015) / 0.03)
        b = self.brow
        yb = b["y"] + b["arch"] * np.exp(-0.5 * ((ax - 0.034) / 0.012) ** 2)
        dr = b["amp"] * np.exp(-0.5 * ((y - yb) / 0.006) ** 2) * np.exp(-0.5 * ((ax - 0.028) / 0.02) ** 2)
        dr += 0.5 * b["amp"] * _gauss(x, y - 0.02, 0.01, 0.008)
        dr += 0.0015 * _gauss(ax - 0.025, y - 0.055, 0.02, 0.02)
        dr += self.eyes(ax, y, 0.0)
        ck = self.cheek
        dr += ck["amp"] * _gauss(ax - 0.05, y - ck["y"], 0.014, 0.009) + ck["fat"] * _gauss(ax - 0.038, y + 0.045, 0.014, 0.016)
        dr -= 0.0015 * _gauss(ax - 0.027, y + 0.013, 0.011, 0.005)
        dr += self._nose(x, y) + self._mouth(x, y)
        dr += -0.002 * _gauss(x, y - self.mouth["ym"] + 0.019, 0.014, 0.004)
        dr += self.chin["amp"] * _gauss(x, y + 0.099, self.chin["sx"], 0.011)
        out = front * dr
        out -= 0.003 * _gauss(ax - 0.06, y - 0.03, 0.02, 0.015) * np.exp(-0.5 * ((z - 0.045) / 0.02) ** 2)
        out += self.adam * _gauss(x, y + 0.14, 0.007, 0.012) * _smoothstep((z - 0.0) / 0.02)
        out += self._ears(x, y, z)
        out += self.hair(P)[0]
        return out

    # ---------------------------------------------------------------- evaluation
    def neutral(self, d):
        """(base point P0, neutral point Pn) in canonical coordinates, both ``(k, 3)``."""
        r0 = self.base(d)
        P0 = self.centre + r0[:, None] * d
        return P0, P0 + self.detail(P0)[:, None] * d

    def position(self, d):
        """World position of the neutral surface along unit directions ``d``."""
        return self.neutral(d)[1] * self.scale

    # ---------------------------------------------------------------- expressions
    hinge = np.array([0.0, -0.012, -0.005])

    def jaw_weight(self, P0, split=False):
        """1 on the lower jaw (below the lips), 0 above; sharp across the lips, soft on the cheeks.

        ``split=True`` returns ``(w_lips, falloff)`` whose product is the weight.
        """
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        ax = np.abs(x)
        mw = self.mouth["mw"]
        yj = np.where(ax < mw, self.mouth_line(x), self.mouth_line(mw) + 0.25 * (ax - mw))
        spread = 0.7 * np.maximum(ax - mw + 0.002, 0.0)
        w = _smoothstep((yj + T_CU + spread - y) / (T_CU - T_CL + 2.0 * spread))
        # gentle falloffs toward the back and down the neck: the rotation moves points back by up to ~4 cm,
        # so a weight slope above ~1/0.04 per metre along z would fold the surface
        fall = _smoothstep((z + 0.03) / 0.09) * _smoothstep((y + 0.17) / 0.065)
        return (w, fall) if split else w * fall

    def displacement(self, P0, Pn, d, e):
        """Canonical expression displacement ``(k, 3)`` for weights ``e`` (10,) in NAMES order.

        Bulges and furrows move along the ray ``d`` (radial, so they cannot fold the surface);
        the jaw rotates about a hinge axis in front of the ears; everything else is a smooth
        vector field with gentle gradients.
        """
        smile, jaw, pl, pr, pk, cl, cr, puff, br, fr = (float(v) for v in e)
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        ax = np.abs(x)
        front = _smoothstep((z - 0.015) / 0.03)
        ym = self.mouth_line(x)
        mw = self.mouth["mw"]
        D = np.zeros_like(Pn)

        def add(w, vec):
            D[:] += w[:, None] * np.asarray(vec, dtype=np.float64)

        if smile:
            for sg in (1.0, -1.0):
                add(smile * front * _gauss(x - sg * mw, y - ym, 0.012, 0.011), (sg * 0.0045, 0.0065, -0.003))
                add(smile * front * _gauss(x - sg * 0.038, y + 0.03, 0.016, 0.015), (sg * 0.001, 0.0035, 0.0025))
            D[:, 0] += smile * 0.15 * x * front * _gauss(x, y - ym, 0.032, 0.012)
            lipw = smile * front * np.exp(-0.5 * (x / 0.02) ** 4)
            above = _smoothstep((y - ym) / 0.002 + 0.5)
            D[:, 1] += lipw * (0.0016 * above * np.exp(-0.5 * ((y - ym) / 0.008) ** 2)
                               - 0.0010 * (1 - above) * np.exp(-0.5 * ((y - ym) / 0.008) ** 2))
            ex, ey, u, up, lo = self.eye_frame(ax, y)
            D[:, 1] += smile * front * 0.0012 * _gauss(ex, ey - lo + 0.003, 0.012, 0.004)
            fold = self._fold_distance(ax, y)
            D -= (smile * front * 0.0018 * np.exp(-0.5 * (fold / 0.0025) ** 2))[:, None] * d
        if jaw:
            wl, fall = self.jaw_weight(P0, split=True)
            w = wl * fall
            c, s = np.cos(0.28 * jaw), np.sin(0.28 * jaw)
            R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
            Q = (Pn - self.hinge) @ R.T + self.hinge
            D += w[:, None] * (Q - Pn)
            # the opening: the crease walls become the inside of the mouth.  The push is a smooth bump over
            # the walls (wider than a mesh row) and peaks where the lips split, so every column of the
            # opening is a graph over (w, push) and cannot fold
            t = y - ym - 0.5 * (T_CU + T_CL)
            band = jaw * 0.022 * front * self.mouth_corner(ax) * np.exp(-0.5 * (t / 0.0022) ** 2)
            D -= band[:, None] * d
        for sg, amount in ((1.0, pl), (-1.0, pr)):
            if amount:
                wl = amount * front * _gauss(x, y - ym, 0.03, 0.014)
                add(wl, (sg * 0.006, 0.0, 0.0035))
                add(wl * _smoothstep(sg * x / 0.02 + 0.5), (0.0, 0.0005, 0.003))
        if pk:
            D[:, 2] += pk * 0.011 * front * _gauss(x, y - ym, 0.02, 0.012)
            D[:, 0] -= pk * 0.33 * x * front * _gauss(x, y - ym, 0.034, 0.016)
            D -= (pk * 0.002 * front * _gauss(ax - 0.04, y + 0.045, 0.014, 0.016))[:, None] * d
        if cl or cr:
            closed = np.where(x > 0, cl, cr)
            dr = front * (self.eyes(ax, y, closed) - self.eyes(ax, y, 0.0))
            D += dr[:, None] * d
        if puff:
            D += (puff * 0.012 * front * _gauss(ax - 0.043, y + 0.052, 0.017, 0.017))[:, None] * d
            D[:, 2] += puff * 0.002 * front * _gauss(x, y - ym, 0.02, 0.012)
        if br:
            w = br * front * _smoothstep((y - 0.006) / 0.014) * (1.0 - _smoothstep((y - 0.04) / 0.05)) \
                * np.exp(-0.5 * (ax / 0.055) ** 4)
            add(w, (0.0, 0.008, 0.001))
            fold = 0.5 * (1.0 - np.cos(TWO_PI * (y - 0.036) / 0.0105)) * _smoothstep((y - 0.036) / 0.004) \
                * _smoothstep((0.075 - y) / 0.01) * np.exp(-0.5 * (x / 0.045) ** 4)
            D -= (br * 0.0005 * front * fold)[:, None] * d
        if fr:
            for sg in (1.0, -1.0):
                add(fr * front * _gauss(x - sg * 0.017, y - 0.021, 0.012, 0.009), (-sg * 0.004, -0.004, 0.0012))
            add(fr * front * _gauss(ax - 0.042, y - 0.024, 0.012, 0.008), (0.0, -0.0012, 0.0))
            furrow = np.exp(-0.5 * ((ax - 0.0055) / 0.0013) ** 2) * _smoothstep((y - 0.01) / 0.004) \
                * _smoothstep((0.032 - y) / 0.004)
            D -= (fr * 0.0007 * front * furrow)[:, None] * d
        return D

    def _fold_distance(self, ax, y):
        """Distance to the nasolabial fold segment (ala -> beside the mouth corner)."""
        a = np.array([self.nose["ala"] + 0.006, self.nose["ys"] + 0.006])
        b = np.array([self.mouth["mw"] + 0.008, self.mouth["ym"] - 0.004])
        ab = b - a
        t = np.clip(((ax - a[0]) * ab[0] + (y - a[1]) * ab[1]) / (ab @ ab), 0.0, 1.0)
        return np.hypot(ax - a[0] - t * ab[0], y - a[1] - t * ab[1])

    # ---------------------------------------------------------------- colours
    def colors(self, P0, e=None, regions=False):
        """Per-point colours ``(k, 3)`` in [0, 1] at base points ``P0`` for expression weights ``e``.

        With ``regions=True`` also returns soft region masks (hair, brow, eye, lip, beard, skin)
        that the texture uses to place its fine detail.
        """
        e = np.zeros(len(EXPRESSION_NAMES)) if e is None else np.asarray(e, dtype=np.float64)
        ident = self.ident
        skin = _palette(ident.skin_tone, SKIN)
        hair = _palette(ident.hair_color, HAIR)
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        n = len(P0)
        C = np.tile(skin, (n, 1))
        C *= (1.0 - 0.07 * _smoothstep((-0.12 - y) / 0.07))[:, None]
        red = skin * np.array([1.0, 0.80, 0.78])
        ear = _smoothstep((np.abs(x) - 0.05) / 0.015) * _gauss(z + 0.012, y + 0.013, 0.02, 0.035)
        C = _mix(C, red, 0.3 * ear)
        reg = {k: np.zeros(n) for k in ("brow", "eye", "lip", "beard")}
        face = np.flatnonzero(z > -0.02)                 # the facial colours live on the front only
        Cf, rf = self._face_colors(P0[face], C[face], e, skin, hair, red)
        C[face] = Cf
        for k, v in rf.items():
            reg[k][face] = v
        hm = self.hair(P0)[1]
        C = np.clip(_mix(C, hair, hm), 0.0, 1.0)
        if regions:
            reg.update(hair=hm, skin=(1 - hm) * (1 - reg["eye"]))
            return C, reg
        return C

    def _face_colors(self, P0, C, e, skin, hair, red):
        ident = self.ident
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        ax = np.abs(x)
        front = _smoothstep((z - 0.015) / 0.03)
        C = _mix(C, red, front * (0.30 * _gauss(ax - 0.042, y + 0.03, 0.015, 0.014)
                                  + 0.2 * _gauss(x, y - self.nose["yt"], 0.008, 0.008)))
        # beard shadow
        ym = self.mouth_line(x)
        hu, hl = self.lip_heights(x)
        lip = front * np.where(y > ym, _smoothstep((ym + hu - y) / 0.0012 + 0.5),
                               _smoothstep((y - ym + hl) / 0.0016 + 0.5)) * np.exp(-0.5 * (x / (self.mouth["mw"] + 0.002)) ** 8)
        side_w = _smoothstep((ax - 0.012) / 0.014)                   # beard top: under the nose, then the cheek line
        beard_top = (1.0 - side_w) * (self.nose["ys"] - 0.002) + side_w * (-0.03 + 0.35 * np.maximum(ax - 0.035, 0.0))
        beard = _smoothstep((beard_top - y) / 0.012 + 0.2) * _smoothstep((y + 0.15) / 0.03) \
            * _smoothstep((z + 0.02) / 0.03) * _smoothstep((0.078 - ax) / 0.01)
        beard = beard * (1.0 - 0.7 * _gauss(x, y - self.mouth["ym"] + 0.014, 0.006, 0.004)) * (1.0 - lip)
        C = _mix(C, 0.6 * skin + 0.4 * (0.5 * hair + 0.06), 0.4 * ident.stubble * beard)
        # lips, mouth interior and teeth
        lipcol = skin * np.array([0.80, 0.58, 0.60]) + np.array([0.07, 0.02, 0.04])
        C = _mix(C, lipcol, 0.8 * lip)
        corner = front * self.mouth_corner(ax)
        t = y - ym
        inner = corner * _smoothstep((0.0035 - np.abs(t)) / 0.0015)
        C = _mix(C, skin * np.array([0.62, 0.36, 0.38]), inner)                  # inside of the lips
        C = _mix(C, [0.16, 0.04, 0.05], 0.6 * e[1] * inner)                       # shadowed when open
        C = _mix(C, [0.16, 0.04, 0.05], corner * _smoothstep((T_CU - t) / 0.0004 + 0.5) * _smoothstep((t - T_CL) / 0.0004 + 0.5))
        teeth = np.clip(3.0 * e[1] + 1.2 * e[0], 0.0, 1.0)
        if teeth > 0:
            band = lambda a, b: _smoothstep((t - a) / 0.0003 + 0.5) * _smoothstep((b - t) / 0.0003 + 0.5)  # noqa: E731
            tw = band(T_CU, T_UT) + np.clip(2.0 * e[1] - 0.6, 0.0, 1.0) * band(T_LT, T_CL)
            C = _mix(C, [0.86, 0.84, 0.77], teeth * corner * tw * np.exp(-0.5 * (x / 0.019) ** 6))
        # nostrils
        C = _mix(C, skin * 0.4, front * 0.8 * _gauss(ax - 0.0063, y - self.nose["ys"] - 0.005, 0.0024, 0.0017))
        # eyebrows: a tapered arch from the head (medial) to the tail (lateral)
        b = self.brow
        yb = b["y"] + b["arch"] * np.exp(-0.5 * ((ax - 0.034) / 0.012) ** 2) - 0.0015 * _smoothstep((ax - 0.04) / 0.012)
        s_ = np.clip((ax - 0.012) / 0.04, 0.0, 1.0)
        thick = b["thick"] * (1.25 - 0.85 * s_ ** 1.5)
        brow = front * _smoothstep((thick - np.abs(y - yb)) / 0.0018 + 0.5) \
            * _smoothstep((ax - 0.0115) / 0.004) * _smoothstep((0.053 - ax) / 0.006)
        C = _mix(C, hair * 0.75 + 0.05 * skin, brow * (0.85 - 0.3 * s_))
        # eyes: sclera (shaded toward the corners), iris, pupil; lash line on the upper lid margin
        closed = np.where(x > 0, e[5], e[6])
        opening, (ex, ey, u, up, lo) = self.eye_opening(ax, y, closed, soft=0.0008)
        opening = opening * front
        rho = np.hypot(ex + 0.0003, ey + 0.0002)
        eye = np.tile([0.88, 0.85, 0.80], (len(P0), 1))
        eye *= (1.0 - 0.22 * _smoothstep((np.abs(u) - 0.45) / 0.5))[:, None]
        eye = _mix(eye, [0.83, 0.55, 0.52], _smoothstep((-0.8 - u) / 0.15))
        iris = _palette(ident.eye_color, IRIS)
        ic = iris[None, :] * (0.7 + 0.5 * _smoothstep((rho - 0.0022) / 0.0035))[:, None]
        eye = _mix(eye, ic, _smoothstep((0.006 - rho) / 0.0005 + 0.5))
        eye = _mix(eye, [0.02, 0.02, 0.02], _smoothstep((0.0023 - rho) / 0.0003 + 0.5))
        C = _mix(C, eye, opening)
        lash = front * np.exp(-0.5 * ((ey - up - 0.0005) / 0.0008) ** 2) * _smoothstep((1.05 - np.abs(u)) / 0.15)
        C = _mix(C, 0.25 * hair + 0.1 * skin, (0.6 + 0.2 * max(-ident.masculinity, 0.0)) * lash)
        return C, dict(brow=brow, eye=opening, lip=lip, beard=beard)


# ============================================================================ parameter disk
class _Param:
    """Map between the parameter disk ``p`` (|p| <= 1) and the surface.

    ``(t, phi)``: ``t`` runs from the crown (0) to the neck cut (1) along the meridian of
    azimuth ``phi``; ``theta = t * theta_max(phi)`` with ``theta_max`` where that meridian
    crosses ``y = y_cut``.  ``rho(t, phi)`` is the normalised 3D arc length along the meridian
    and ``p = rho (sin phi, -cos phi)`` (the UV layout is ``0.5 + 0.49 p``).
    """

    t_ext = 1.04

    def __init__(self, shape: _Shape, nt: int, nphi: int):
        self.shape = shape
        self.nt, self.nphi = nt, nphi
        phi = np.arange(nphi) * (TWO_PI / nphi)
        self.phi_grid = phi
        self.theta_max = self._theta_max(phi)
        t = np.linspace(0.0, self.t_ext, nt)
        self.t_grid = t
        X = shape.position(_dirs(t[:, None] * self.theta_max[None, :], phi[None, :]).reshape(-1, 3)).reshape(nt, nphi, 3)
        seg = np.linalg.norm(np.diff(X, axis=0), axis=2)
        s = np.concatenate([np.zeros((1, nphi)), np.cumsum(seg, axis=0)], axis=0)
        i1 = int(np.searchsorted(t, 1.0))
        w = (1.0 - t[i1 - 1]) / (t[i1] - t[i1 - 1])
        self.L = s[i1 - 1] * (1 - w) + s[i1] * w
        self.rho_tab = s / self.L[None, :]
        self.rho_ext = float(self.rho_tab[-1].min()) - 1e-9
        self.nrho = nt
        rq = np.linspace(0.0, self.rho_ext, self.nrho)
        off = 4.0 * np.arange(nphi)                      # invert every column at once
        xp = (self.rho_tab + off[None, :]).T.ravel()
        xq = (rq[:, None] + off[None, :]).T.ravel()
        self.t_tab = np.interp(xq, xp, np.tile(t, nphi)).reshape(nphi, self.nrho).T
        self.X_grid = X
        # UV radius R(rho): a blend of linear and equal-area, so the face gets more texels
        self.uv_rho = np.linspace(0.0, 1.0, 257)
        curves = self.ring_curves(self.uv_rho)
        circ = np.linalg.norm(np.roll(curves, -1, axis=1) - curves, axis=2).sum(1)
        A = np.concatenate([[0.0], np.cumsum(0.5 * (circ[1:] + circ[:-1]) * np.diff(self.uv_rho))])
        self.area = float(A[-1] * self.L.mean())
        self.uv_R = 0.49 * (0.4 * self.uv_rho + 0.6 * np.sqrt(A / A[-1]))

    def ring_curves(self, rhos):
        """Approximate positions ``(len(rhos), nphi, 3)`` on the rings rho = const (grid interpolation)."""
        nphi, tg = self.nphi, self.t_grid
        T = self._bilinear(self.t_tab, self.rho_ext, np.repeat(rhos, nphi), np.tile(self.phi_grid, len(rhos)))
        f = np.clip(T, 0, tg[-1]) * ((self.nt - 1) / tg[-1])
        i0 = np.minimum(np.floor(f).astype(np.int64), self.nt - 2)
        u = (f - i0)[:, None]
        j = np.tile(np.arange(nphi), len(rhos))
        X = self.X_grid[i0, j] * (1 - u) + self.X_grid[i0 + 1, j] * u
        return X.reshape(len(rhos), nphi, 3)

    #: Moebius shift of the UV disk toward the face (magnifies the face about 1.5x, conformally)
    uv_shift = -0.45j

    def uv_of_p(self, p):
        rho = np.hypot(p[:, 0], p[:, 1])
        R = np.interp(rho, self.uv_rho, self.uv_R) / 0.49
        w = (p[:, 0] + 1j * p[:, 1]) * (R / np.maximum(rho, 1e-12))
        a = self.uv_shift
        z = (w - a) / (1.0 - np.conj(a) * w)
        return 0.5 + 0.49 * np.stack([z.real, z.imag], axis=1)

    def p_of_uv(self, uv):
        z = (uv[:, 0] - 0.5 + 1j * (uv[:, 1] - 0.5)) / 0.49
        a = self.uv_shift
        z = np.where(np.abs(z) > 1.0, z / np.maximum(np.abs(z), 1e-12), z)
        w = (z + a) / (1.0 + np.conj(a) * z)
        R = np.minimum(np.abs(w), 1.0) * 0.49
        rho = np.interp(R, self.uv_R, self.uv_rho)
        q = np.stack([w.real, w.imag], axis=1)
        return q * (rho / np.maximum(np.abs(w), 1e-12))[:, None]

    def _theta_max(self, phi):
        """Polar angle where the meridian of azimuth ``phi`` crosses the neck cut (bisection)."""
        lo = np.full(phi.shape, np.deg2rad(110.0))
        hi = np.full(phi.shape, np.deg2rad(176.0))
        y_cut = self.shape.y_cut * self.shape.scale[1]
        for _ in range(48):
            mid = 0.5 * (lo + hi)
            above = self.shape.position(_dirs(mid, phi))[:, 1] > y_cut
            lo = np.where(above, mid, lo)
            hi = np.where(above, hi, mid)
        return 0.5 * (lo + hi)

    def _phi_index(self, phi):
        f = np.mod(phi, TWO_PI) * (self.nphi / TWO_PI)
        j0 = np.floor(f).astype(np.int64)
        w = f - j0
        j0 = np.mod(j0, self.nphi)
        return j0, np.mod(j0 + 1, self.nphi), w

    def _bilinear(self, tab, ext, a, phi):
        j0, j1, w = self._phi_index(phi)
        n = tab.shape[0]
        f = np.clip(a, 0.0, ext) * ((n - 1) / ext)
        i0 = np.minimum(np.floor(f).astype(np.int64), n - 2)
        u = f - i0
        lo = tab[i0, j0] * (1 - u) + tab[i0 + 1, j0] * u
        hi = tab[i0, j1] * (1 - u) + tab[i0 + 1, j1] * u
        return lo * (1 - w) + hi * w

    def theta_max_at(self, phi):
        j0, j1, w = self._phi_index(phi)
        return self.theta_max[j0] * (1 - w) + self.theta_max[j1] * w

    def dirs_of_p(self, p):
        rho = np.hypot(p[:, 0], p[:, 1])
        phi = np.mod(np.arctan2(p[:, 0], -p[:, 1]), TWO_PI)
        t = self._bilinear(self.t_tab, self.rho_ext, rho, phi)
        return _dirs(t * self.theta_max_at(phi), phi)

    def p_of_dirs(self, d):
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        theta = np.arccos(np.clip(d[:, 1], -1, 1))
        phi = np.mod(np.arctan2(d[:, 0], d[:, 2]), TWO_PI)
        rho = self._bilinear(self.rho_tab, self.t_ext, theta / self.theta_max_at(phi), phi)
        return np.stack([rho * np.sin(phi), -rho * np.cos(phi)], axis=1)

    def X_of_p(self, p):
        return self.shape.position(self.dirs_of_p(p))


def _ring_layout(par: _Param, n_target: int):
    """Rings of vertices at constant rho, equally spaced in 3D along each ring; exactly ``n_target`` vertices."""
    Lbar = float(par.L.mean())
    h = np.sqrt(2.0 * par.area / (np.sqrt(3.0) * n_target))
    for _ in range(4):
        K = max(int(round(Lbar / (h * np.sqrt(3.0) / 2.0))), 4)
        rhos = np.arange(K + 1) / K
        curves = par.ring_curves(rhos)
        segl = np.linalg.norm(np.roll(curves, -1, axis=1) - curves, axis=2)
        C = segl.sum(1)
        n_k = np.maximum(np.round(C / h).astype(np.int64), 3)
        n_k[0] = 1
        h *= np.sqrt(int(n_k.sum()) / n_target)
    resid = n_target - int(n_k.sum())
    order = np.argsort(-C[1:], kind="stable") + 1
    while resid != 0:
        step = int(np.sign(resid))
        k = min(abs(resid), len(order))
        n_k[order[:k]] += step
        resid -= step * k
    cum = np.concatenate([np.zeros((K + 1, 1)), np.cumsum(segl, axis=1)], axis=1)
    ring_id = np.repeat(np.arange(K + 1), n_k)
    start = np.concatenate([[0], np.cumsum(n_k)[:-1]])
    local = np.arange(int(n_k.sum())) - start[ring_id]
    target = (local + 0.5 * (ring_id % 2)) / n_k[ring_id] * C[ring_id]
    big = 10.0 * (C.max() + 1.0)
    xp = (cum + big * np.arange(K + 1)[:, None]).ravel()
    phi = np.interp(target + big * ring_id, xp, np.tile(np.append(par.phi_grid, TWO_PI), K + 1))
    phi = np.mod(phi, TWO_PI)
    phi[0] = 0.0
    return rhos[ring_id], phi, ring_id, n_k, start


def _stitch(phi, n_k, start):
    """Triangulate the annuli between consecutive rings (vectorised merge of segment mid-angles).

    Segment ``i`` of a ring joins vertex ``i`` to ``i + 1``; it is closed by the vertex of the
    neighbouring ring that lies between the mid-angles of that ring's segments around it.
    """
    K1 = len(n_k)
    ring_id = np.repeat(np.arange(K1), n_k)
    nxt = np.arange(len(phi)) + 1
    nxt[start + n_k - 1] = start
    gap = np.mod(phi[nxt] - phi, TWO_PI)
    gap[start[n_k == 1]] = TWO_PI
    mid = np.mod(phi + 0.5 * gap, TWO_PI)
    order = np.lexsort((mid, ring_id))
    skey = (ring_id * 8.0 + mid)[order]

    def apex(v, k_other, side):
        c = np.searchsorted(skey, k_other * 8.0 + mid[v], side=side) - start[k_other]
        prev = np.where(c == 0, n_k[k_other] - 1, c - 1)
        seg = order[start[k_other] + prev] - start[k_other]
        return start[k_other] + np.mod(seg + 1, n_k[k_other])

    vA = np.flatnonzero((ring_id < K1 - 1) & (n_k[ring_id] > 1))     # segments of the upper ring
    vB = np.flatnonzero(ring_id > 0)                                  # segments of the lower ring
    FA = np.stack([nxt[vA], vA, apex(vA, ring_id[vA] + 1, "left")], axis=1)
    FB = np.stack([vB, nxt[vB], apex(vB, ring_id[vB] - 1, "right")], axis=1)
    return np.concatenate([FA, FB], axis=0).astype(np.int64)


def _vertex_normals(X, F):
    N = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    out = np.stack([sum(np.bincount(F[:, k], weights=N[:, c], minlength=len(X)) for k in range(3))
                    for c in range(3)], axis=1)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)


def _min_angles(X, F):
    """Smallest corner angle (radians) of each triangle."""
    e = [X[F[:, (k + 1) % 3]] - X[F[:, k]] for k in range(3)]
    L = [np.linalg.norm(v, axis=1) + 1e-300 for v in e]
    cos = [np.einsum("ij,ij->i", e[k], -e[(k + 2) % 3]) / (L[k] * L[(k + 2) % 3]) for k in range(3)]
    return np.arccos(np.clip(np.max(cos, axis=0), -1.0, 1.0))


def _snap_landmarks(par, p, F, fixed, dirs, candidates=8):
    """Move one vertex exactly onto each landmark; ``p`` and ``fixed`` are updated in place.

    Among the nearest free vertices (in the parameter disk) the one whose move leaves the
    best smallest 3D angle in its fan, without flipping a triangle, is chosen.
    """
    names = list(dirs)
    tp = par.p_of_dirs(np.array([dirs[k] for k in names]))
    Xt = par.X_of_p(tp)
    X = par.X_of_p(p)
    n = len(p)
    fan = vertex_face_incidence(F, n)
    out = {}
    for k, name in enumerate(names):
        dist = np.hypot(p[:, 0] - tp[k, 0], p[:, 1] - tp[k, 1])
        dist[fixed] = np.inf
        best, best_q = int(np.argmin(dist)), -1.0
        for v in np.argsort(dist, kind="stable")[:candidates]:
            if not np.isfinite(dist[v]):
                break
            faces = F[fan[v].indices]
            pp, XX = p.copy(), X
            pp[v] = tp[k]
            if (signed_uv_areas(faces, pp) <= 1e-14).any():
                continue
            XX = X.copy()
            XX[v] = Xt[k]
            q = float(_min_angles(XX, faces).min())
            if q > best_q + 1e-9:
                best, best_q = int(v), q
        if best_q > 0:
            p[best], X[best] = tp[k], Xt[k]
        fixed[best] = True
        out[name] = best
    return out


def _relax(par, p, F, fixed, iters, lam=0.6, eps=1e-5):
    """Tangential umbrella smoothing in 3D, pulled back to the parameter disk (no flips)."""
    A = vertex_adjacency(F, len(p))
    deg = np.asarray(A.sum(1)).ravel()
    for _ in range(iters):
        X = par.X_of_p(p)
        delta = (A @ X) / deg[:, None] - X
        N = _vertex_normals(X, F)
        delta -= np.einsum("ij,ij->i", delta, N)[:, None] * N
        J1 = (par.X_of_p(p + [eps, 0.0]) - X) / eps
        J2 = (par.X_of_p(p + [0.0, eps]) - X) / eps
        g11, g12, g22 = (np.einsum("ij,ij->i", a, b) for a, b in ((J1, J1), (J1, J2), (J2, J2)))
        b1, b2 = np.einsum("ij,ij->i", J1, delta), np.einsum("ij,ij->i", J2, delta)
        det = np.maximum(g11 * g22 - g12 * g12, 1e-30)
        dp = np.stack([g22 * b1 - g12 * b2, g11 * b2 - g12 * b1], axis=1) / det[:, None]
        dp[fixed] = 0.0
        new = p + lam * dp
        for _k in range(10):
            bad = signed_uv_areas(F, new) <= 1e-14
            if not bad.any():
                break
            vb = F[bad].ravel()
            new[vb] = p[vb]
        p = new
    return p


# ============================================================================ texture detail
class _Noise:
    """Deterministic 3D value noise (hashed lattice, smooth trilinear), values in [-1, 1]."""

    def __init__(self, seed: int):
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x6EAD])
        perm = rng.permutation(256).astype(np.int64)
        self.perm = np.concatenate([perm, perm])
        self.vals = rng.uniform(-1.0, 1.0, 256)

    def __call__(self, P, scale, offset=0.0):
        q = (P + offset) / np.asarray(scale, dtype=np.float64)
        i = np.floor(q)
        f = q - i
        w = f * f * (3.0 - 2.0 * f)
        i = i.astype(np.int64) & 255
        pm, vals = self.perm, self.vals
        out = 0.0
        for cx in (0, 1):
            px = pm[(i[:, 0] + cx) & 255]
            wx = w[:, 0] if cx else 1.0 - w[:, 0]
            for cy in (0, 1):
                py = pm[px + ((i[:, 1] + cy) & 255)]
                wy = w[:, 1] if cy else 1.0 - w[:, 1]
                for cz in (0, 1):
                    wz = w[:, 2] if cz else 1.0 - w[:, 2]
                    out = out + vals[pm[py + ((i[:, 2] + cz) & 255)]] * wx * wy * wz
        return out


def _texture_detail(C, reg, P0, ident, noise, fine=True):
    """Modulate colours with skin, freckle, hair and stubble detail (``fine=False``: low frequency only).

    Noise is evaluated only where its region weight is non-zero.
    """
    mult = np.ones(len(P0))

    def add(w, fn, target=mult):
        idx = np.flatnonzero(w > 1e-3)
        if len(idx):
            target[idx] += w[idx] * fn(P0[idx])

    add(reg["skin"], lambda P: 0.045 * noise(P, 0.012, 3.7))
    if not fine:
        return np.clip(C * mult[:, None], 0.0, 1.0)
    add(reg["skin"], lambda P: 0.035 * noise(P, 0.0011, 1.3))
    add(reg["hair"], lambda P: 0.25 * (noise(P, (0.0009, 0.005, 0.0009), 2.2) + 0.6 * noise(P, (0.004, 0.0008, 0.004), 9.4)))
    add(reg["brow"], lambda P: 0.3 * noise(P, (0.0006, 0.002, 0.002), 6.6))
    add(reg["eye"], lambda P: 0.12 * noise(P, 0.0005, 8.8))
    C = C * mult[:, None]
    x, y = P0[:, 0], P0[:, 1]
    if ident.freckles > 0:
        region = np.clip(_gauss(np.abs(x) - 0.025, y + 0.018, 0.028, 0.02) + _gauss(x, y + 0.01, 0.01, 0.02), 0, 1) * reg["skin"]
        spot = np.zeros(len(P0))
        add(region, lambda P: _smoothstep((noise(P, 0.0019, 0.31) - (0.62 - 0.3 * ident.freckles)) / 0.1), spot)
        C = _mix(C, C * np.array([0.78, 0.62, 0.52]), spot * 0.7 * ident.freckles)
    if ident.stubble > 0:
        dots = np.zeros(len(P0))
        add(reg["beard"], lambda P: _smoothstep((noise(P, 0.0008, 7.7) - 0.1) / 0.3), dots)
        C = _mix(C, C * 0.55, dots * 0.6 * ident.stubble)
    return np.clip(C, 0.0, 1.0)


# ============================================================================ the model
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
        self._noise = _Noise(self.seed)
        self._build()

    # ---------------------------------------------------------------- template
    def _build(self):
        n = self.n_vertices
        shape = _Shape(self.identity)
        nt = int(np.clip(2.0 * np.sqrt(n), 200, 900))
        nphi = int(np.clip(np.sqrt(n), 128, 512))
        par = _Param(shape, nt, nphi)
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
        rho, phi, ring_id, n_k, start = _ring_layout(par, n)
        F = _stitch(phi, n_k, start)
        p = np.stack([rho * np.sin(phi), -rho * np.cos(phi)], axis=1)
        fixed = ring_id == ring_id[-1]
        landmarks = _snap_landmarks(par, p, F, fixed, self._landmark_dirs(shape))
        p = _relax(par, p, F, fixed, iters=4 if n <= 20000 else 6)
        d = par.dirs_of_p(p)
        bnd = np.flatnonzero(ring_id == ring_id[-1])          # exactly on the cut y = y_cut
        d[bnd] = _dirs(par._theta_max(phi[bnd]), phi[bnd])
        P0, Pn = shape.neutral(d)
        self._F, self._p, self._d, self._P0, self._Pn = F, p, d, P0, Pn
        self._UV = par.uv_of_p(p)
        x, y, z = P0[:, 0], P0[:, 1], P0[:, 2]
        self._face_mask = ((np.abs(x) / 0.068) ** 2.5 + (np.abs(y + 0.019) / 0.1) ** 2.5 < 1.0) & (z > 0.015)
        Vn = Pn * shape.scale
        self._landmarks = {k: landmarks[k] for k in LANDMARK_NAMES}
        self._eye_line_y = float(0.5 * (Vn[landmarks["eye_left_center"], 1] + Vn[landmarks["eye_right_center"], 1]))
        self._upper = Vn[:, 1] > self._eye_line_y
        C, reg = shape.colors(P0, regions=True)
        self._colors0 = _texture_detail(C, reg, P0, self.identity, self._noise, fine=False)

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
        C, reg = self._shape.colors(P0, e, regions=True)
        return _texture_detail(C, reg, P0, self.identity, self._noise, fine=True)

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
            C, reg = self._shape.colors(self._P0, e, regions=True)
            colors = _texture_detail(C, reg, self._P0, self.identity, self._noise, fine=False)
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


def procedural_head(n_vertices: int = 20000, seed: int = 0, identity=None, expression=None,
                    texture_size: int = 512) -> SynthHead:
    """Generate one procedural head (see :class:`HeadModel` for the parameters).

    Examples
    --------
    >>> head = procedural_head(2000, seed=0, expression={"jaw_open": 0.5})
    >>> len(head.V), head.UV.shape, sorted(head.landmarks)[:2]
    (2000, (2000, 2), ['brow_left', 'brow_right'])
    """
    return HeadModel(n_vertices=n_vertices, seed=seed, identity=identity, texture_size=texture_size).mesh(expression)
