"""Labelled real heads from the ICT-FaceKit model: identities ``~ N(0, I)``, expressions from
named presets and random sparse ARKit mixes, prompts that say both in words.

Every head gets

* an **expression** — one of :data:`PRESETS` (its blendshapes scaled by an intensity drawn
  in ``[0.6, 1]``), or, with probability ``mix_share``, a random mix of 1–3 blendshapes
  (``"mix"``) described blendshape by blendshape (:func:`describe_blendshapes`);
* **identity traits measured from the geometry** of its neutral face (never guessed): face
  width (landmarks 0–16, the jaw line at the ears), nose length (27–33, nasion to the base of
  the nose) and face height (27–8, nasion to chin), each put in a tercile of the dataset's own
  identities ("narrow" / "wide", "short nose" / "long nose", "short face" / "long face"; the
  middle tercile says nothing);
* a **prompt**: the expression, and for half the heads (seeded) the traits too, e.g.
  ``"smiling, a wide face with a long nose"``;
* a **split**: ``train`` or ``heldout``, by identity (``heldout_share`` of the identities).

:func:`ict_specs` returns, per head, the small picklable spec a dataset worker turns into a
mesh (:func:`head_from_spec`) and its labels; ``geoface dataset ict`` builds them into
geometry images through :func:`geoface.dataset.build_dataset`.

Examples
--------
>>> specs = ict_specs(4, seed=0)                # doctest: +SKIP
>>> specs[0]["labels"]["prompt"]                # doctest: +SKIP
'mouth wide open, a narrow face'
"""

from __future__ import annotations

import numpy as np

from ..errors import GeofaceError

__all__ = ["PRESETS", "PRESET_PROMPTS", "describe_blendshapes", "measure_traits", "ict_specs", "head_from_spec",
           "TRAIT_WORDS"]

#: named expressions: blendshape weights at full intensity, and the words a prompt uses.
#: ``_L`` acts on the subject's left (+x).
PRESETS: dict[str, tuple[dict, str]] = {
    "neutral": ({}, "a neutral expression"),
    "smile": ({"mouthSmile_L": 1.0, "mouthSmile_R": 1.0, "cheekSquint_L": 0.5, "cheekSquint_R": 0.5}, "smiling"),
    "mouth_open": ({"jawOpen": 0.9, "mouthLowerDown_L": 0.5, "mouthLowerDown_R": 0.5}, "mouth wide open"),
    "left_eye_closed": ({"eyeBlink_L": 1.0}, "left eye closed"),
    "right_eye_closed": ({"eyeBlink_R": 1.0}, "right eye closed"),
    "pout": ({"mouthPucker": 1.0, "mouthFunnel": 0.4}, "pouting"),
    "puffed_cheeks": ({"cheekPuff_L": 1.0, "cheekPuff_R": 1.0}, "puffed cheeks"),
    "raised_brows": ({"browInnerUp_L": 1.0, "browInnerUp_R": 1.0, "browOuterUp_L": 1.0, "browOuterUp_R": 1.0,
                      "eyeWide_L": 0.5, "eyeWide_R": 0.5}, "raised brows"),
    "frown": ({"browDown_L": 1.0, "browDown_R": 1.0, "mouthFrown_L": 1.0, "mouthFrown_R": 1.0}, "frowning"),
    "smile_left": ({"mouthSmile_L": 1.0, "cheekSquint_L": 0.5}, "smiling on the left side"),
    "smile_right": ({"mouthSmile_R": 1.0, "cheekSquint_R": 0.5}, "smiling on the right side"),
}
PRESET_PROMPTS = {k: v[1] for k, v in PRESETS.items()}

#: words for one blendshape; ``{side}`` takes "left " / "right " from the ``_L``/``_R`` suffix
_PHRASES = {
    "browDown": "{side}brow lowered", "browInnerUp": "{side}inner brow raised", "browOuterUp": "{side}outer brow raised",
    "cheekPuff": "{side}cheek puffed", "cheekSquint": "{side}cheek raised", "eyeBlink": "{side}eye closed",
    "eyeLookDown": "{side}eye looking down", "eyeLookIn": "{side}eye looking inward", "eyeLookOut": "{side}eye looking outward",
    "eyeLookUp": "{side}eye looking up", "eyeSquint": "{side}eye squinting", "eyeWide": "{side}eye wide open",
    "jawForward": "jaw pushed forward", "jawLeft": "jaw shifted to the left", "jawOpen": "mouth open",
    "jawRight": "jaw shifted to the right", "mouthClose": "lips closed", "mouthDimple": "{side}mouth corner dimpled",
    "mouthFrown": "{side}mouth corner turned down", "mouthFunnel": "lips funnelled", "mouthLeft": "mouth pulled to the left",
    "mouthLowerDown": "lower lip lowered on the {side}side", "mouthPress": "lips pressed on the {side}side",
    "mouthPucker": "lips puckered", "mouthRight": "mouth pulled to the right", "mouthRollLower": "lower lip rolled in",
    "mouthRollUpper": "upper lip rolled in", "mouthShrugLower": "lower lip pushed up", "mouthShrugUpper": "upper lip pushed up",
    "mouthSmile": "{side}mouth corner smiling", "mouthStretch": "{side}mouth corner stretched",
    "mouthUpperUp": "upper lip raised on the {side}side", "noseSneer": "nose sneering on the {side}side",
}
#: blendshapes a random mix never draws (mouthClose only makes sense over an open jaw)
_NOT_IN_MIXES = ("mouthClose",)

#: trait → (words for the lowest tercile, for the highest)
TRAIT_WORDS = {"face_width": ("narrow", "wide"), "face_height": ("short", "long"), "nose_length": ("short", "long")}
_TRAIT_LANDMARKS = {"face_width": (0, 16), "nose_length": (27, 33), "face_height": (27, 8)}


def describe_blendshapes(expression: dict, *, top: int = 3) -> str:
    """Words for a blendshape mix, strongest first (``"slightly"`` below 0.5), e.g.
    ``{"eyeBlink_L": 0.9, "jawLeft": 0.3}`` → ``"left eye closed and jaw slightly shifted to the left"``."""
    items = sorted(((w, n) for n, w in expression.items() if w > 0.05), reverse=True)[:top]
    if not items:
        return PRESET_PROMPTS["neutral"]
    words = []
    for w, name in items:
        base, side = (name[:-2], {"_L": "left ", "_R": "right "}[name[-2:]]) if name[-2:] in ("_L", "_R") else (name, "")
        phrase = _PHRASES.get(base, base)
        if w < 0.5:  # "left eye slightly closed", "mouth slightly open"
            for noun in ("brow", "eye", "cheek", "corner", "lip", "lips", "jaw", "mouth", "nose"):
                k = phrase.find(noun + " ")
                if k >= 0:
                    phrase = phrase[: k + len(noun) + 1] + "slightly " + phrase[k + len(noun) + 1:]
                    break
        words.append(phrase.replace("{side}", side).replace("the side", "both sides"))
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def measure_traits(model, identities: np.ndarray) -> dict[str, np.ndarray]:
    """Trait values in cm (``{name: (n,)}``) of the neutral heads with the given identity
    weights ``(n, k)``: distances between landmarks (see :data:`TRAIT_WORDS`)."""
    v = model.view()
    lm = v.landmarks
    idx = sorted({lm[i] for pair in _TRAIT_LANDMARKS.values() for i in pair})
    pos = {j: k for k, j in enumerate(idx)}
    base = v.neutral[idx]  # (p, 3)
    modes = v.identity_modes[:, idx]  # (K, p, 3)
    A = np.asarray(identities, np.float64)
    P = base[None] + np.tensordot(A, modes[: A.shape[1]], axes=1)  # (n, p, 3)
    return {name: np.linalg.norm(P[:, pos[lm[a]]] - P[:, pos[lm[b]]], axis=1) for name, (a, b) in _TRAIT_LANDMARKS.items()}


def _trait_words(values: dict, lo: dict, hi: dict, i: int) -> tuple[dict, str]:
    """Tercile labels of head ``i`` and their words: ``"a wide, long face with a short nose"``."""
    labels, face, nose = {}, [], ""
    for name, (low_w, high_w) in TRAIT_WORDS.items():
        x = float(values[name][i])
        t = "low" if x <= lo[name] else ("high" if x >= hi[name] else "middle")
        labels[name] = {"cm": round(x, 3), "tercile": t}
        if t != "middle":
            word = low_w if t == "low" else high_w
            if name == "nose_length":
                nose = f"a {word} nose"
            else:
                face.append(word)
    if face:
        text = f"a {', '.join(face)} face" + (f" with {nose}" if nose else "")
    else:
        text = nose
    return labels, text


def ict_specs(count: int, *, seed: int = 0, model=None, model_path: str | None = None, mix_share: float = 0.3,
              heldout_share: float = 0.2, traits_share: float = 0.5, presets=None) -> list[dict]:
    """``count`` labelled heads: ``[{"name", "identity" (k,), "expression", "labels"}]``,
    deterministic for ``seed`` (see module docs).  ``presets``: the preset names to draw from
    (default all of :data:`PRESETS`)."""
    from .ict import load_ict_model

    if int(count) != count or count < 1:
        raise GeofaceError(f"count must be a positive integer; got {count!r}")
    for name, x in (("mix_share", mix_share), ("heldout_share", heldout_share), ("traits_share", traits_share)):
        if not 0.0 <= float(x) <= 1.0:
            raise GeofaceError(f"{name} must be in [0, 1]; got {x!r}")
    m = model if model is not None else load_ict_model(model_path)
    names = list(presets or PRESETS)
    bad = [n for n in names if n not in PRESETS]
    if bad:
        raise GeofaceError(f"unknown presets {bad}; presets are {', '.join(PRESETS)}")
    missing = sorted({b for n in names for b in PRESETS[n][0] if b not in m.expression_names})
    if missing:
        raise GeofaceError(f"the model lacks the blendshapes {', '.join(missing)} that the presets use")
    rng = np.random.default_rng(int(seed))
    count = int(count)
    ids = rng.standard_normal((count, m.n_identities))
    traits = measure_traits(m, ids)
    lo = {k: float(np.quantile(v, 1 / 3)) for k, v in traits.items()}
    hi = {k: float(np.quantile(v, 2 / 3)) for k, v in traits.items()}
    heldout = np.zeros(count, bool)
    heldout[rng.permutation(count)[: int(round(heldout_share * count))]] = True
    mixable = [n for n in m.expression_names if n not in _NOT_IN_MIXES]
    width = len(str(count - 1))
    out = []
    for i in range(count):
        if rng.random() < mix_share:
            k = int(rng.integers(1, 4))
            pick = rng.choice(len(mixable), size=k, replace=False)
            expr = {mixable[j]: round(float(rng.uniform(0.4, 1.0)), 4) for j in sorted(pick)}
            cls, words = "mix", describe_blendshapes(expr)
        else:
            cls = names[int(rng.integers(len(names)))]
            s = float(rng.uniform(0.6, 1.0))
            expr = {b: round(min(1.0, w * s), 4) for b, w in PRESETS[cls][0].items()}
            words = PRESETS[cls][1]
        tl, ttext = _trait_words(traits, lo, hi, i)
        with_traits = rng.random() < traits_share and ttext
        prompt = f"{words}, {ttext}" if with_traits else words
        out.append({"name": f"ict_{i:0{max(4, width)}d}", "identity": ids[i].tolist(), "expression": expr,
                    "labels": {"prompt": prompt, "expression_name": cls, "expression_words": words, "expression": expr,
                               "traits": tl, "split": "heldout" if heldout[i] else "train", "identity_index": i,
                               "seed": int(seed)}})
    return out


def head_from_spec(spec: dict, model=None):
    """The :class:`~geoface.synth.ict.ICTHead` of one spec of :func:`ict_specs`."""
    from .ict import load_ict_model

    m = model if model is not None else load_ict_model(spec.get("model"))
    return m.head(np.asarray(spec["identity"], np.float64), spec.get("expression") or {}, spec.get("parts", ("skin",)))
