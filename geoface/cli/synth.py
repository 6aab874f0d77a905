"""``geoface synth head | ict | pack-ict | surface``."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import GeofaceError, InvalidMeshError

from ._common import guard_outputs, mesh_outputs

# --------------------------------------------------------------------------- synth
def _parse_expression(text: str | None) -> dict:
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        if not item.strip():
            continue
        if "=" not in item:
            raise InvalidMeshError(f"expression items look like name=value; got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise InvalidMeshError(f"expression value for {k.strip()!r} is not a number: {v!r}") from None
    return out


def cmd_synth_head(args) -> int:
    from ..mesh.io import save_mesh
    from ..synth.head import procedural_head

    guard_outputs(args, [], [*mesh_outputs(args.output), args.meta])
    head = procedural_head(
        n_vertices=args.vertices, seed=args.seed, expression=_parse_expression(args.expression) or None, texture_size=args.texture_size
    )
    mesh = head.mesh(texture=Path(args.output).suffix.lower() in (".obj", ".glb", ".gltf"))
    save_mesh(args.output, mesh, overwrite=args.force)
    if args.meta:
        from .._io import atomic_write_text

        meta = {
            "seed": head.seed,
            "identity": head.identity.to_dict(),
            "expression": head.expression.to_dict(),
            "eye_line_y": float(head.eye_line_y),
            "landmarks": {k: int(v) for k, v in head.landmarks.items()},
            "face_mask": [int(i) for i in head.face_mask.nonzero()[0]],
        }
        atomic_write_text(args.meta, json.dumps(meta, indent=1))
    print(f"wrote {args.output}: {len(head.V)} vertices, {len(head.F)} faces (seed {head.seed})")
    return 0


def cmd_synth_ict(args) -> int:
    from ..mesh.io import Mesh, save_mesh
    from ..synth.ict import load_ict_model

    guard_outputs(args, [args.model], [*mesh_outputs(args.output), args.meta])
    model = load_ict_model(args.model)
    parts = tuple(p.strip() for p in args.parts.split(",") if p.strip())
    identity = args.seed if args.identity is None else _parse_weights(args.identity)
    head = model.head(identity, _parse_expression(args.expression), parts, n_identity=args.n_identity)
    save_mesh(args.output, Mesh(head.V, head.F, UV=head.UV, FUV=head.FUV), overwrite=args.force)
    if args.meta:
        from .._io import atomic_write_text

        atomic_write_text(args.meta, json.dumps({**head.meta(), "seed": None if args.identity else args.seed}, indent=1))
    expr = ", ".join(f"{k}={v:g}" for k, v in head.expression.items()) or "neutral"
    print(f"wrote {args.output}: {len(head.V)} vertices, {len(head.F)} faces ({', '.join(head.parts)}; "
          f"identity {'weights' if args.identity else f'seed {args.seed}'}; {expr})")
    return 0


def _parse_weights(text: str) -> list:
    import math

    try:
        w = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise GeofaceError(f"--identity must be comma-separated numbers; got {text!r}") from None
    if not w or len(w) > 100:
        raise GeofaceError(f"--identity needs 1 to 100 weights (one per identity component); got {len(w)}")
    if not all(math.isfinite(x) and abs(x) <= 10 for x in w):
        raise GeofaceError("--identity weights are in standard deviations: each must be finite and within ±10")
    return w


def cmd_synth_pack_ict(args) -> int:
    from ..synth.ict import load_ict_model, pack_ict

    guard_outputs(args, [args.clone], [args.output])
    out = pack_ict(args.clone, args.output, overwrite=args.force, quiet=bool(args.quiet))
    m = load_ict_model(out)
    print(f"wrote {out}: {len(m.vertices)} vertices, {m.n_identities} identity modes, {len(m.expression_names)} "
          f"expressions, regions {', '.join(m.available_regions)} ({out.stat().st_size / 2**20:.1f} MB)")
    return 0


#: synth surface --resolution: up to ~4M triangles
MAX_SURFACE_RESOLUTION = 2048

SURFACES = ("square", "disk", "flat-irregular", "cap", "hemisphere", "sphere", "cylinder", "torus", "genus2", "mobius")


def cmd_synth_surface(args) -> int:
    from ..mesh.io import save_mesh
    from ..synth import surfaces as S

    guard_outputs(args, [], mesh_outputs(args.output))
    n = args.resolution
    if not 2 <= n <= MAX_SURFACE_RESOLUTION:
        raise GeofaceError(f"--resolution must be in 2..{MAX_SURFACE_RESOLUTION}; got {n}")
    make = {
        "square": lambda: S.square_grid(n),
        "disk": lambda: S.disk_grid(max(n // 2, 1)),
        "flat-irregular": lambda: S.irregular_flat_patch(n * n, seed=args.seed),
        "cap": lambda: S.spherical_cap(1.0, 1.0, max(n // 2, 1)),
        "hemisphere": lambda: S.hemisphere(1.0, max(n // 2, 1)),
        "sphere": lambda: S.sphere(1.0, max(min(n // 8, 6), 1)),
        "cylinder": lambda: S.cylinder(1.0, 2.0, 2 * n, n),
        "torus": lambda: S.torus(1.0, 0.3, 2 * n, n),
        "genus2": lambda: S.genus2(max(n * 2, 16)),
        "mobius": lambda: S.mobius_strip(2 * n, max(n // 4, 2)),
    }[args.name]
    V, F = make()
    save_mesh(args.output, V=V, F=F, overwrite=args.force)
    print(f"wrote {args.output}: {args.name}, {len(V)} vertices, {len(F)} faces")
    return 0


def register(sub, common) -> None:
    """``geoface synth head|ict|pack-ict|surface``."""
    from .._args import SEED, number
    from ._common import verbs

    s = sub.add_parser("synth", help="write procedural test geometry")
    ss = verbs(s, common)
    h = ss.add_parser("head", help="the procedural expressive head")
    h.add_argument("-o", "--output", required=True, help="output mesh (obj with texture, ply with colours, ...)")
    h.add_argument("--vertices", type=number(int, 1000, 200_000), default=20000, help="about this many vertices")
    h.add_argument("--seed", type=SEED, default=0, help="draws the identity")
    h.add_argument("--expression", default=None, help="e.g. smile=0.8,jaw_open=0.3")
    h.add_argument("--texture-size", type=number(int, 16, 8192), default=512, help="texture image size in pixels")
    h.add_argument("--meta", default=None, help="also write identity, expression, landmarks and face mask as JSON")
    h.set_defaults(func=cmd_synth_head)
    i = ss.add_parser("ict", help="a real head of the ICT-FaceKit morphable model (identity, expression, parts)")
    i.add_argument("-o", "--output", required=True, help='output mesh (obj, ply, off, stl, glb)')
    i.add_argument("--seed", type=SEED, default=0, help="draws the identity weights ~ N(0, 1)")
    i.add_argument("--identity", default=None, metavar="W1,W2,...", help="identity weights instead of --seed (0,0 = the mean head)")
    i.add_argument("--n-identity", type=number(int, 0, 100), default=None, help="with --seed: draw only the first N modes")
    i.add_argument("--expression", default=None, help="ARKit blendshapes, e.g. mouthSmile_L=1,jawOpen=0.3 (weights in [0, 1])")
    i.add_argument("--parts", default="skin", help="skin (default: face, head and neck), face, head, eyes, teeth, mouth, "
                   "eye_extras or all; comma-separated")
    i.add_argument("--model", default=None, help="the model (.npz or an ICT-FaceKit clone; default: the copy shipped with geoface)")
    i.add_argument("--meta", default=None, help="also write weights, landmarks, face mask and regions as JSON (--roi for convert)")
    i.set_defaults(func=cmd_synth_ict)
    k = ss.add_parser("pack-ict", help="pack an ICT-FaceKit clone (FaceXModel/ OBJs) into one .npz")
    k.add_argument("clone", help="the clone (or its FaceXModel folder)")
    k.add_argument("-o", "--output", required=True, metavar="MODEL.npz", help='the packed model to write')
    k.set_defaults(func=cmd_synth_pack_ict)
    a = ss.add_parser("surface", help="an analytic surface")
    a.add_argument("name", choices=SURFACES, help='which surface')
    a.add_argument("-o", "--output", required=True, help='output mesh (obj, ply, off, stl, glb)')
    a.add_argument("--resolution", type=number(int, 2, 2048), default=24, help="grid resolution of the surface")
    a.add_argument("--seed", type=SEED, default=0, help="for the random surfaces")
    a.set_defaults(func=cmd_synth_surface)
