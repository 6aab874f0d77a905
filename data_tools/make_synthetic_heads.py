#!/usr/bin/env python
"""Write a labelled set of procedural heads for dataset building and text-conditioned training.

    python data_tools/make_synthetic_heads.py OUT_DIR [--count 100] [--vertices 3000] [--seed 0]

For each head ``head_{i:04d}``: a random identity (``HeadIdentity.random``) and one expression
at a random strength in [0.5, 1] (or neutral), written as

* ``head_XXXX.ply`` — the mesh with per-vertex colours,
* ``head_XXXX.json`` — the metadata ``geoface synth head --meta`` writes (seed, identity,
  expression, landmarks, ``face_mask``), which ``geoface dataset build`` uses as the ROI,

and one line per head in ``labels.jsonl``: ``name``, ``seed``, ``identity``, ``expression``
(the weights), ``gender``, ``expression_name`` and a prompt in the head paper's style, made
from the sampled parameters: "a smiling female", "a male with mouth pouting to the left",
"a frowning person with long blond hair", ...  The same seed gives the same files.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: expression -> (adjective before the noun, or None; phrase after "with", or None)
PHRASES = {
    "smile": ("smiling", None),
    "jaw_open": (None, "mouth wide open"),
    "pout_left": (None, "mouth pouting to the left"),
    "pout_right": (None, "mouth pouting to the right"),
    "pucker": (None, "puckered lips"),
    "eyes_closed_left": (None, "the left eye closed"),
    "eyes_closed_right": (None, "the right eye closed"),
    "cheek_puff": (None, "puffed cheeks"),
    "brow_raise": ("surprised-looking", "raised eyebrows"),
    "frown": ("frowning", None),
}
NEUTRAL_SHARE = 1.0 / 11.0


def gender_of(identity: dict) -> str:
    m = identity["masculinity"]
    return "male" if m > 0.25 else "female" if m < -0.25 else "person"


def hair_of(identity: dict) -> str | None:
    """A hair phrase for clearly long or clearly light hair, else None."""
    c, length = identity["hair_color"], identity["hair_length"]
    colour = "platinum" if c > 0.9 else "blond" if c > 0.72 else "black" if c < 0.12 else None
    size = "long" if length > 0.7 else "short" if length < 0.15 else None
    if colour is None and size is None:
        return None
    return " ".join(w for w in (size, colour) if w) + " hair"


def prompt_of(identity: dict, expression: dict) -> tuple[str, str]:
    """(expression name or "neutral", prompt) for sampled parameters."""
    name, weight = max(expression.items(), key=lambda kv: kv[1])
    noun = gender_of(identity)
    withs = []
    adjective = None
    if weight < 0.3:
        name = "neutral"
        adjective = "neutral-looking"
    else:
        adjective, phrase = PHRASES[name]
        if adjective is None or (phrase is not None and noun == "person"):
            adjective = None
            withs.append(phrase)
    hair = hair_of(identity)
    if hair:
        withs.append(hair)
    head = f"{adjective} {noun}" if adjective else noun
    article = "an" if head[0] in "aeiou" else "a"
    text = f"{article} {head}"
    if withs:
        text += " with " + " and ".join(withs)
    return name, text


def sample(i: int, seed: int) -> dict:
    from geoface.synth.head import EXPRESSION_NAMES, HeadIdentity

    rng = np.random.default_rng([seed, i])
    identity = HeadIdentity.random(rng).to_dict()
    expression = {n: 0.0 for n in EXPRESSION_NAMES}
    if rng.random() >= NEUTRAL_SHARE:
        expression[EXPRESSION_NAMES[int(rng.integers(len(EXPRESSION_NAMES)))]] = float(rng.uniform(0.5, 1.0))
    name, prompt = prompt_of(identity, expression)
    return {"name": f"head_{i:04d}", "seed": int(seed * 100003 + i), "identity": identity, "expression": expression,
            "gender": gender_of(identity), "expression_name": name, "prompt": prompt}


def write_head(out: Path, label: dict, n_vertices: int) -> None:
    from geoface._io import atomic_path
    from geoface.mesh.io import Mesh, save_mesh
    from geoface.synth.head import HeadExpression, HeadIdentity, procedural_head

    head = procedural_head(n_vertices, seed=label["seed"] % (2**31), identity=HeadIdentity.from_dict(label["identity"]),
                           expression=HeadExpression.from_dict(label["expression"]), texture_size=64)
    save_mesh(out / f"{label['name']}.ply", Mesh(head.V, head.F, colors=head.colors))
    meta = {"seed": head.seed, "identity": head.identity.to_dict(), "expression": head.expression.to_dict(),
            "eye_line_y": float(head.eye_line_y), "landmarks": {k: int(v) for k, v in head.landmarks.items()},
            "face_mask": [int(i) for i in head.face_mask.nonzero()[0]]}
    with atomic_path(out / f"{label['name']}.json") as tmp:
        Path(tmp).write_text(json.dumps(meta))


def make_synthetic_heads(out_dir, count: int = 100, n_vertices: int = 3000, seed: int = 0, quiet: bool = True) -> list[dict]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    labels = [sample(i, seed) for i in range(count)]
    for k, lab in enumerate(labels):
        write_head(out, lab, n_vertices)
        if not quiet:
            print(f"[{k + 1}/{count}] {lab['name']}: {lab['prompt']}", file=sys.stderr)
    (out / "labels.jsonl").write_text("".join(json.dumps(lab) + "\n" for lab in labels))
    return labels


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out_dir")
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--vertices", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-q", "--quiet", action="store_true")
    a = ap.parse_args(argv)
    if a.count < 1:
        ap.error("--count must be at least 1")
    make_synthetic_heads(a.out_dir, a.count, a.vertices, a.seed, quiet=a.quiet)
    print(f"wrote {a.count} heads and labels.jsonl to {a.out_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
