"""A person of the ICT-FaceKit model (built from scans of real people, :mod:`geoface.synth.ict`)
as both avatars' synthetic captures use it: lit skin maps, eyes, teeth and a mouth
(:class:`ICTPerson`), ARKit expression curves of speech and emotion (:func:`arkit_curves`) and a
rigid head motion (:func:`head_motion`). Units are metres (:data:`CM_TO_M` from the model's cm).
The captures themselves: :func:`geoface.hfm.ict.make_ict_hmd`, :func:`geoface.thgs.ict.make_ict_talking`.
"""
from __future__ import annotations


import numpy as np

from geoface.errors import AvatarError

__all__ = ["arkit_curves", "ICTPerson", "ICT_PARTS", "is_upper_blendshape", "head_motion"]

#: the model's parts that are rendered (and become Gaussians)
ICT_PARTS = ("skin", "eyes", "teeth", "mouth")
CM_TO_M = 0.01  # the model's centimetres → metres
# region numbers of ICTHead.labels (the order of geoface.synth.ict.REGIONS)
_MOUTH, _EYE_SOCKET, _GUMS, _TEETH, _EYEBALL = 3, 4, 5, 6, 7
_SOLIDS = {_MOUTH: ((0.30, 0.09, 0.09), 0.15), _GUMS: ((0.62, 0.27, 0.27), 0.4), _TEETH: ((0.86, 0.82, 0.70), 0.5)}
_HEADSET = ((0.10, 0.10, 0.11), 0.3)


def is_upper_blendshape(name: str) -> bool:
    """Blendshapes that move the face above the headset's edge (brows, lids, gaze)."""
    return name.startswith(("brow", "eye"))


def _smooth(x: np.ndarray, width: float) -> np.ndarray:
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(x, width, mode="nearest") if width > 0 else x


def arkit_curves(T: int, rng, *, fps: float = 25.0, loudness=None, talk: float = 1.0, emote: float = 1.0,
                 blink: bool = True, rom: float = 0.0) -> list[dict]:
    """``T`` frames of ARKit blendshape weights in [0, 1] (a list of dicts, model names).

    * speech: phrases of 1–3 s with pauses; within a phrase syllables at 3–5 per second open the
      jaw and part the lips, and slower vowels round (funnel, pucker) or stretch the mouth; with
      ``loudness`` ([T] ≥ 0, e.g. an audio envelope per frame) the jaw follows it instead;
    * emotions: surprise, smile and anger, smooth and often at rest, each coupling upper and lower
      face; ``emote`` scales them, ``talk`` the speech;
    * blinks every 2–6 s (both eyes, 0.2 s);
    * with ``rom`` > 0 seconds, a range of motion first (from 0.2 s on, as a registration session asks
      of a person): surprise, smile and anger in turn, each rising to its full weight, held and
      released in a third of ``rom``, without speech; speech and the free emotions ease in over the
      next 0.5 s.  The random draws are the same with or without it."""
    t = np.arange(T) / fps
    # phrases: on/off spans
    on = np.zeros(T)
    s = rng.uniform(0, 1.0)
    while s < t[-1] + 1 if T else False:
        d = rng.uniform(1.0, 3.0)
        on[(t >= s) & (t < s + d)] = 1
        s += d + rng.uniform(0.3, 1.2)
    on = _smooth(on, 0.08 * fps)
    if loudness is not None:
        loud = np.asarray(loudness, np.float64)
        if loud.shape != (T,):
            raise AvatarError(f"loudness must have one value per frame ({T}); got shape {loud.shape}")
        syl = np.clip(loud / max(float(np.percentile(loud, 95)), 1e-9), 0, 1.2)
        on = np.clip(_smooth(syl, 0.25 * fps) * 3, 0, 1)
    else:
        rate = rng.uniform(3.0, 5.0)
        phase = 2 * np.pi * np.cumsum(rate * (1 + 0.25 * _smooth(rng.standard_normal(T), fps * 0.3))) / fps
        syl = np.clip(np.sin(phase), 0, None) ** 1.5 * on * rng.uniform(0.6, 1.0, T).clip(0, 1)
        syl = _smooth(syl, 0.04 * fps)
    vowel = _smooth(rng.standard_normal(T), 0.15 * fps)
    vowel /= max(float(np.abs(vowel).max()), 1e-9)
    # emotions: sums of slow sinusoids, often at rest (as hfm_data._drivers, but per second)
    emo = np.zeros((T, 3))
    for k in range(3):
        f = rng.uniform(0.08, 0.25, 3)
        ph = rng.uniform(0, 2 * np.pi, 3)
        w = sum(np.sin(2 * np.pi * f[j] * t + ph[j]) / (j + 1) for j in range(3))
        emo[:, k] = np.clip((w - 0.3) / 1.1, 0, 1) ** 1.2
    if rom > 0:
        from geoface.avatar.template import smoothstep as _ease

        free = _ease((t - 0.2 - rom) / 0.5)
        seg = rom / 3
        ramp = [_ease((t - 0.2 - k * seg) / (0.3 * seg)) * (1 - _ease((t - 0.2 - (k + 0.7) * seg) / (0.3 * seg)))
                for k in range(3)]
        emo = emo * free[:, None] + np.stack(ramp, 1)
        on, syl = on * free, syl * free
    sur, smi, ang = (emote * emo).T
    blinks = np.zeros(T)
    if blink:
        s = rng.uniform(0.5, 3.0)
        while s < t[-1] if T else False:
            blinks = np.maximum(blinks, np.exp(-0.5 * ((t - s) / 0.05) ** 2))
            s += rng.uniform(2.0, 6.0)
    talk_open = talk * syl
    jaw = np.clip(0.55 * talk_open + 0.45 * sur, 0, 1)
    out = []
    for i in range(T):
        rnd, wide = max(vowel[i], 0.0) * talk * on[i], max(-vowel[i], 0.0) * talk * on[i]
        e = {"jawOpen": jaw[i], "mouthClose": 0.25 * talk * on[i] * (1 - syl[i]) * (jaw[i] > 0.05),
             "mouthFunnel": 0.5 * rnd, "mouthPucker": 0.35 * rnd, "mouthStretch_L": 0.3 * wide, "mouthStretch_R": 0.3 * wide,
             "mouthLowerDown_L": 0.3 * talk_open[i], "mouthLowerDown_R": 0.3 * talk_open[i],
             "mouthUpperUp_L": 0.2 * talk_open[i], "mouthUpperUp_R": 0.2 * talk_open[i],
             "browInnerUp_L": 0.9 * sur[i], "browInnerUp_R": 0.9 * sur[i], "browOuterUp_L": sur[i], "browOuterUp_R": sur[i],
             "eyeWide_L": 0.6 * sur[i], "eyeWide_R": 0.6 * sur[i],
             "mouthSmile_L": smi[i], "mouthSmile_R": smi[i], "cheekSquint_L": 0.6 * smi[i], "cheekSquint_R": 0.6 * smi[i],
             "eyeSquint_L": 0.5 * smi[i], "eyeSquint_R": 0.5 * smi[i],
             "browDown_L": ang[i], "browDown_R": ang[i], "mouthFrown_L": 0.7 * ang[i], "mouthFrown_R": 0.7 * ang[i],
             "noseSneer_L": 0.4 * ang[i], "noseSneer_R": 0.4 * ang[i], "mouthPress_L": 0.3 * ang[i], "mouthPress_R": 0.3 * ang[i],
             "eyeBlink_L": blinks[i], "eyeBlink_R": blinks[i]}
        out.append({k: float(np.clip(v, 0, 1)) for k, v in e.items()})
    return out


def head_motion(T: int, rng, fps: float, scale: float, jitter: float, ramp: int):
    """[T, 3] yaw/pitch/roll (radians) and [T, 3] translation (m): slow sinusoids (yaw ±10°,
    pitch ±5°, roll ±3°, ±6 mm) plus a per-frame camera shake (``jitter`` × 0.3°, 0.5 mm); the
    first ``ramp`` frames ease in from rest."""
    t = np.arange(T) / fps
    amp_r = np.radians([10.0, 5.0, 3.0]) * scale
    ang = np.stack([amp_r[k] * sum(np.sin(2 * np.pi * f * t + p) / (j + 1) for j, (f, p) in
                                   enumerate(zip(rng.uniform(0.1, 0.5, 2), rng.uniform(0, 2 * np.pi, 2)))) / 1.5
                    for k in range(3)], 1)
    tr = np.stack([0.006 * scale * np.sin(2 * np.pi * rng.uniform(0.1, 0.4) * t + rng.uniform(0, 2 * np.pi))
                   for _ in range(3)], 1)
    ang += jitter * np.radians(0.3) * rng.standard_normal((T, 3))
    tr += jitter * 0.0005 * rng.standard_normal((T, 3))
    if ramp:
        from geoface.avatar.template import smoothstep

        w = smoothstep(np.arange(T) / ramp)
        ang *= w[:, None]
        tr *= w[:, None]
    return ang, tr


def _box_mean(a: np.ndarray, ss: int) -> np.ndarray:
    H, W = a.shape[:2]
    return a.reshape(H // ss, ss, W // ss, ss, *a.shape[2:]).mean((1, 3))


class ICTPerson:
    """One lit ICT-FaceKit person before a fixed camera (what the synthetic captures render).

    Built from ``rng`` (in this order: identity unless given, eyes, skin maps, lights), so a seed
    gives the same person.  :meth:`render` poses the model rigidly about the neck ``pivot``."""

    def __init__(self, rng, *, identity=None, res: int = 128, map_res: int = 512, supersample: int = 2):
        from geoface.camera import Camera, look_at
        from geoface.skin.render import ict_eyes, ict_source, random_lights, skin_maps, unweld_uv
        from geoface.avatar.capture import headset_mesh
        from geoface.synth.ict import neck_pivot, upper_split

        if supersample < 1 or res < 16:
            raise AvatarError(f"need res >= 16 and supersample >= 1; got {res}, {supersample}")
        model, regions = ict_source(map_res)
        if identity is None:
            ident = rng.standard_normal(model.n_identities)
        else:
            ident = np.zeros(model.n_identities)
            given = np.asarray(identity, np.float64).ravel()
            if len(given) > model.n_identities or not np.isfinite(given).all():
                raise AvatarError(f"identity: up to {model.n_identities} finite weights; got {len(given)}")
            ident[:len(given)] = given
        self.model, self.ident = model, ident
        self.rest = rest = model.head(identity=ident, parts=ICT_PARTS)
        lab = rest.labels
        self.V0 = V0 = rest.V * CM_TO_M
        Vu, self.Fu, self.UVu, self.src = unweld_uv(rest.V, rest.F, rest.UV, rest.FUV, with_source=True)
        self.V_identity = rest.V  # cm, the expressionless shape; every frame adds its expression to it
        self.eyes = ict_eyes(self.V_identity, self.src, rest, rng)
        self.maps = skin_maps(map_res, seed=int(rng.integers(1 << 31)), regions=regions)
        self.lights = random_lights(rng, int(rng.integers(2, 4)))
        self.solids = [(lab[self.src] == k, c, s) for k, (c, s) in _SOLIDS.items()]
        L0 = V0[rest.landmarks]
        y_eye = float(L0[36:48, 1].mean())
        chin = L0[8]
        self.y_split = upper_split(V0, rest.landmarks)
        self.front = float(V0[lab <= 1, 2].max())
        self.pivot = neck_pivot(V0, rest.landmarks, lab)  # the neck
        target = np.array([0.0, 0.5 * (y_eye + chin[1]) + 0.01, float(L0[:, 2].mean())])
        self.cam = cam = look_at(target + [0, 0, 0.45], target, width=res, height=res, fov_y_deg=36.0)
        self.ss = ss = int(supersample)
        self.cam_ss = Camera(cam.fx * ss, cam.fy * ss, cam.cx * ss, cam.cy * ss, res * ss, res * ss, cam.R, cam.t)
        self.hV, self.hF = headset_mesh(self.y_split, self.front)

    def shape(self, expr: dict) -> np.ndarray:
        """The person's vertices (metres, canonical pose) under ARKit weights ``expr``."""
        return self.model.add_expression(self.V_identity, expr, parts=ICT_PARTS) * CM_TO_M

    def render(self, expr: dict, R, tr, headset: bool = False):
        """→ (posed vertices, RGB [res, res, 3], alpha [res, res], headset mask or None): the
        person with expression ``expr`` turned by ``R`` about the neck and moved by ``tr``."""
        from geoface.mesh.core import vertex_normals
        from geoface.skin.render import render_skin_sample

        V = self.shape(expr)
        V = (V - self.pivot) @ np.asarray(R).T + self.pivot + tr
        src, Fu = self.src, self.Fu
        N = vertex_normals(V, self.rest.F)[src]
        Vr, Fr, UVr, Nr = V[src], Fu, self.UVu, N
        sol = list(self.solids)
        if headset:
            Vh = (self.hV - self.pivot) @ np.asarray(R).T + self.pivot + tr
            Vr = np.concatenate([Vr, Vh])
            Fr = np.concatenate([Fu, self.hF + len(src)])
            UVr = np.concatenate([UVr, np.zeros((len(Vh), 2))])
            Nr = np.concatenate([Nr, vertex_normals(Vh, self.hF)])
            sol = [(np.r_[m, np.zeros(len(Vh), bool)], c, s) for m, c, s in sol]
            sol.append((np.r_[np.zeros(len(src), bool), np.ones(len(Vh), bool)], *_HEADSET))
        ey = {k: (np.r_[v, np.zeros(len(Vr) - len(v), v.dtype)] if k in ("eyeball", "socket", "cos") else v)
              for k, v in self.eyes.items()}
        s = render_skin_sample(Vr, Fr, UVr, self.maps, self.cam_ss, self.lights, normals=Nr, eyes=ey, solids=sol)
        ss = self.ss
        alpha = _box_mean(s["mask"].astype(np.float32), ss)
        rgb = _box_mean(s["photo"].astype(np.float64) ** 2.2, ss) ** (1 / 2.2)
        hmd = _box_mean((s["face"] >= len(Fu)).astype(np.float32), ss) > 0.5 if headset else None
        return V, rgb.astype(np.float32), alpha, hmd

    def face_shape_error_mm(self, neutral) -> tuple[float, float]:
        """A fitted expressionless head's face (vertices of the ICT parts, metres, canonical)
        against this person's, mm (mean, 95th percentile), after the one similarity (scale, turn,
        shift: Umeyama) that best lays it on the truth — the face's shape alone, as
        face-reconstruction benchmarks score it."""
        from geoface.mesh.align import similarity_transform

        face = self.rest.labels == 0
        X, Y = np.asarray(neutral, np.float64)[face], self.V0[face]
        sc, Rm, tv = similarity_transform(X, Y)
        e = np.linalg.norm(sc * X @ Rm.T + tv - Y, axis=1) * 1000
        return float(e.mean()), float(np.percentile(e, 95))

    def init_mesh(self, target: int):
        """The canonical head for Gaussians: vertices, faces, colours (see :func:`_init_mesh`)."""
        return _init_mesh(self.V0, self.rest, self.src, self.UVu, self.maps, self.eyes, self.solids, target)




def _init_mesh(V0, head, src, UVu, maps, eyes, solids, target: int):
    """The canonical head for the Gaussians: the rendered mesh (welded) decimated to ``target``
    vertices, coloured by the albedo of its nearest original vertex."""
    from scipy.spatial import cKDTree

    from geoface.skin.render import sample_uv_map, eye_albedo
    from geoface.repair.remesh import remesh

    col_u = sample_uv_map(maps.stack()[..., :3], np.clip(UVu, 0, 1))
    ball = eyes["eyeball"]
    col_u[ball] = eye_albedo(eyes["cos"][ball], eyes["iris"])
    col_u[eyes["socket"]] = (0.55, 0.30, 0.27)
    for m, c, _ in solids:
        col_u[m] = c
    col = np.zeros((len(V0), 3))
    col[src] = col_u  # a seam vertex takes one of its copies' colours
    if target and target < len(V0):
        r = remesh(V0, head.F, target, method="decimate")
        V, F = np.asarray(r.V), np.asarray(r.F)
        _, nn = cKDTree(V0).query(V)
        col = col[nn]
    else:
        V, F = V0, head.F
    return V, F, np.clip(col, 0, 1)
