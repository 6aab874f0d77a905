"""Real heads from the ICT-FaceKit morphable model (the small copy in tests/data)."""

from __future__ import annotations

import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.mesh.topology import topology_report
from geoface.synth.ict import find_model, ict_head, load_ict_model, random_expression


@pytest.fixture(scope="module")
def model():
    return load_ict_model()


def test_skin_surface_open_at_neck_eyes_and_mouth(model):
    assert model.neutral.shape == (11248, 3) and model.F.shape[1] == 3
    rep = topology_report(model.neutral, model.F)
    # the face, head and neck: one surface, genus 0, open at the neck, both eyes and the mouth
    assert rep.components == 1 and rep.genus == 0 and rep.boundary_loops == 4 and rep.nonmanifold_edges == 0
    # the neck is the longest loop; centimetres, +y up: the neck rim is at the bottom
    from geoface.mesh.core import boundary_loops

    P = model.neutral
    loops = boundary_loops(model.F)
    neck = max(loops, key=lambda lp: np.linalg.norm(P[np.roll(lp, -1)] - P[lp], axis=1).sum())
    assert model.neutral[neck, 1].mean() < model.neutral[:, 1].mean() - 5.0
    assert 20 < np.ptp(model.neutral[:, 1]) < 50  # a head is 20-50 cm tall
    assert model.face_mask.sum() == 9409 and model.face_mask[:9409].all()
    assert model.landmarks.shape == (68,) and (model.landmarks < len(model.neutral)).all()
    # the nose tip (Multi-PIE landmark 30) is the most forward landmark
    assert np.argmax(model.neutral[model.landmarks, 2]) in (30, 31, 32, 33, 34, 35)


def test_heads_are_the_model_and_deterministic(model):
    a = ict_head(model, seed=4)
    b = ict_head(model, seed=4)
    assert np.array_equal(a.V, b.V) and np.array_equal(a.identity, b.identity)
    c = ict_head(model, seed=5)
    assert np.abs(a.V - c.V).max() > 0.1  # different people differ by millimetres or more
    neutral = ict_head(model, identity=np.zeros(3))
    assert np.array_equal(neutral.V, model.neutral)
    # one identity mode with weight 1 adds that mode exactly
    one = ict_head(model, identity=[1.0])
    assert np.allclose(one.V - model.neutral, model.identity_modes[0], atol=1e-6)
    # expressions add their blendshapes, scaled
    name = model.expression_names.index("jawOpen")
    jaw = ict_head(model, identity=np.zeros(0), expression={"jawOpen": 0.5})
    assert np.allclose(jaw.V - model.neutral, 0.5 * model.expression_modes[name], atol=1e-6)
    chin = model.landmarks[8]  # Multi-PIE 8: the chin tip; an open jaw lowers it by centimetres
    assert jaw.V[chin, 1] < model.neutral[chin, 1] - 0.5


def test_random_expression_and_bad_weights(model):
    rng = np.random.default_rng(0)
    e = random_expression(rng, model.expression_names, count=3)
    assert len(e) == 3 and all(0 <= w <= 1 for w in e.values())
    with pytest.raises(GeofaceError, match="unknown expression"):
        ict_head(model, expression={"smile": 0.5})
    with pytest.raises(GeofaceError, match=r"\[0, 1\]"):
        ict_head(model, expression={"jawOpen": 1.5})
    with pytest.raises(GeofaceError, match="finite"):
        ict_head(model, identity=[np.nan])


def test_missing_model_is_a_clear_error(tmp_path):
    with pytest.raises(GeofaceError, match="not found"):
        find_model(tmp_path / "nowhere.npz")
    assert find_model(tmp_path / "nowhere.npz", required=False) is None
    bad = tmp_path / "ict_facekit.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(GeofaceError, match="cannot read"):
        load_ict_model(bad)


# ----------------------------------------------------------------------------- the whole model
def test_packaged_model_parts_regions_and_landmarks():
    from geoface.synth.ict import REGIONS, ICTFaceModel, find_model

    path = find_model()
    assert path.name == "ict_facekit.npz" and (path.parent / "LICENSE").is_file()  # shipped with its MIT licence
    m = ICTFaceModel.load(path)
    assert m.available_regions == tuple(REGIONS) and m.n_identities == 100 and len(m.expression_names) == 53
    skin = m.head(7)
    assert skin.V.shape == (11248, 3) and set(np.unique(skin.labels)) == {0, 1, 2}
    full = m.head(7, parts="all")
    assert full.V.shape == (26719, 3) and np.array_equal(full.vertex_ids, np.arange(26719))
    # the skin of the full head is the skin head, vertex for vertex
    assert np.allclose(full.V[skin.vertex_ids], skin.V)
    eyes = m.head(7, parts=("skin", "eyes"))
    teeth = m.head(7, parts="teeth")
    assert len(skin.V) < len(eyes.V) < len(full.V)
    assert set(np.unique(teeth.labels)) <= {list(REGIONS).index("teeth"), list(REGIONS).index("gums_tongue")} | {0, 1, 2}
    # the eyeballs sit in the eye openings: their centroids are within 2 cm of the eye landmarks
    eb = full.V[full.labels == list(REGIONS).index("eyeballs")]
    left = eb[eb[:, 0] > 0].mean(0)
    lm = full.V[full.landmarks]
    eye_l = lm[42:48].mean(0)  # Multi-PIE 42-47: the subject's left eye (+x)
    assert eye_l[0] > 0 and np.linalg.norm(left - eye_l) < 2.0
    # landmarks lie on the surface: vertices of the mesh, carried by the expression
    used = np.unique(skin.F)
    assert np.isin(skin.landmarks, used).all()
    smile = m.head(7, {"jawOpen": 1.0})
    assert np.allclose(smile.V[smile.landmarks], smile.V[smile.landmarks.clip(0)])
    assert smile.V[smile.landmarks[8], 1] < skin.V[skin.landmarks[8], 1] - 1.0  # the chin drops with the jaw
    meta = skin.meta()
    assert len(meta["face_mask"]) == 9409 and meta["regions"]["head"] == 1839


def test_heads_are_linear_in_the_weights():
    from geoface.synth.ict import load_ict_model

    m = load_ict_model()
    rng = np.random.default_rng(3)
    a, b = rng.standard_normal(100), rng.standard_normal(100)
    ea, eb = {"jawOpen": 0.3, "mouthSmile_L": 0.5}, {"jawOpen": 0.2, "eyeBlink_R": 0.9}
    n0 = m.neutral
    ha, hb = m.shape(a, ea) - n0, m.shape(b, eb) - n0
    both = m.shape(a + b, {"jawOpen": 0.5, "mouthSmile_L": 0.5, "eyeBlink_R": 0.9}) - n0
    assert np.abs(both - (ha + hb)).max() < 1e-6 * max(1.0, np.abs(both).max())  # float32 modes
    half = m.shape(0.5 * a) - n0
    assert np.allclose(2 * half, m.shape(a) - n0, atol=1e-6)
    # an identity posed many times: its shape once, each expression added to it
    assert np.array_equal(m.add_expression(m.shape(a), ea), m.shape(a, ea))
    assert not np.array_equal(m.add_expression(m.shape(a), eb), m.shape(a, ea))
    with pytest.raises(GeofaceError, match="unknown expression"):
        m.add_expression(m.shape(a), {"wink": 1.0})
    # a seed is the N(0, 1) draw
    assert np.array_equal(m.identity_weights(5), np.random.default_rng(5).standard_normal(100))
    with pytest.raises(GeofaceError, match="unknown part"):
        m.head(parts="ears")


def _write_obj(path, V, P=None, UV=None, PUV=None):
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in V]
    if UV is not None:
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in UV]
    for k, p in enumerate(P if P is not None else []):
        ids = [i for i in p if i >= 0]
        if PUV is not None:
            lines.append("f " + " ".join(f"{i + 1}/{t + 1}" for i, t in zip(ids, PUV[k])))
        else:
            lines.append("f " + " ".join(str(i + 1) for i in ids))
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture
def tiny_clone(tmp_path):
    """A folder in the ICT-FaceKit repository's layout: a 5x5-vertex quad patch (plus one
    triangle), two identity modes, two expressions, vertex_indices.json."""
    import json

    n = 5
    g = np.stack(np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float)), -1).reshape(-1, 2)
    V = np.c_[g, np.zeros(len(g))]
    UV = g / (n - 1)
    quads = [[r * n + c, r * n + c + 1, (r + 1) * n + c + 1, (r + 1) * n + c] for r in range(n - 1) for c in range(n - 2)]
    tris = [[r * n + n - 2, r * n + n - 1, (r + 1) * n + n - 1] for r in range(n - 1)]
    tris += [[r * n + n - 2, (r + 1) * n + n - 1, (r + 1) * n + n - 2] for r in range(n - 1)]
    P = np.array([q for q in quads] + [t + [-1] for t in tris])
    fx = tmp_path / "ICT-FaceKit" / "FaceXModel"
    fx.mkdir(parents=True)
    _write_obj(fx / "generic_neutral_mesh.obj", V, P, UV, np.where(P >= 0, P, -1))
    rng = np.random.default_rng(0)
    modes = {"identity000": rng.normal(0, 0.1, V.shape), "identity001": rng.normal(0, 0.1, V.shape),
             "jawOpen": np.c_[np.zeros(len(V)), -0.05 * g[:, 1], np.zeros(len(V))], "eyeBlink_L": rng.normal(0, 0.02, V.shape)}
    for name, d in modes.items():
        _write_obj(fx / f"{name}.obj", V + d)
    (fx / "vertex_indices.json").write_text(json.dumps({"expressions": ["jawOpen", "eyeBlink_L"],
                                                        "idx_to_landmark_verts": [int(i) % len(V) for i in range(68)]}))
    return fx.parent, V, modes


def test_model_from_a_clone_and_pack_ict(tiny_clone, tmp_path):
    from geoface.cli import main
    from geoface.synth.ict import load_ict_model

    clone, V, modes = tiny_clone
    m = load_ict_model(clone)  # read from the OBJ files directly
    assert m.n_identities == 2 and m.expression_names == ("jawOpen", "eyeBlink_L")
    assert m.neutral.shape == (25, 3) and m.F.shape == (2 * 12 + 8, 3)
    # heads are the modes: float16 storage keeps 1e-4 cm here
    h = m.head([1.0, -2.0], {"jawOpen": 0.5})
    want = V + modes["identity000"] - 2 * modes["identity001"] + 0.5 * modes["jawOpen"]
    assert np.abs(h.V - want).max() < 1e-3
    out = tmp_path / "packed.npz"
    assert main(["synth", "pack-ict", str(clone), "-o", str(out), "-q"]) == 0
    p = load_ict_model(out)
    assert np.array_equal(p.head([1.0, -2.0], {"jawOpen": 0.5}).V, h.V) and np.array_equal(p.F, m.F)
    assert main(["synth", "pack-ict", str(clone), "-o", str(out), "-q"]) == 2  # exists: needs --force
    assert main(["synth", "pack-ict", str(tmp_path), "-o", str(tmp_path / "x.npz"), "-q"]) == 2  # not a clone
    # the CLI writes a head of it, with its meta
    obj, meta = tmp_path / "h.obj", tmp_path / "h.json"
    assert main(["synth", "ict", "-o", str(obj), "--model", str(out), "--identity", "1,-2",
                 "--expression", "jawOpen=0.5", "--meta", str(meta), "-q"]) == 0
    import json

    d = json.loads(meta.read_text())
    assert d["identity"] == [1.0, -2.0] and d["expression"] == {"jawOpen": 0.5} and len(d["landmarks"]) == 68


def test_broken_clone_files_are_one_line_errors(tiny_clone):
    from geoface.synth.ict import _load, load_ict_model

    clone, V, modes = tiny_clone
    (clone / "FaceXModel" / "identity001.obj").write_text("v 0 0 0\n")
    _load.cache_clear()
    with pytest.raises(GeofaceError, match="1 vertices where the neutral mesh has 25"):
        load_ict_model(clone)
    (clone / "FaceXModel" / "jawOpen.obj").unlink()
    with pytest.raises(GeofaceError, match="missing: jawOpen"):
        load_ict_model(clone)


@pytest.mark.parametrize("seed", range(20))
def test_sampled_heads_repair_to_a_disk_and_convert(seed, tmp_path):
    """20 heads of random identities and random expressions: make_disk gives a disk, and the
    full pipeline (Ricci flow, OT with the face mask magnified) converts it fold-free.  Every
    head is repaired; one in four (seeds 0, 4, …, 16, still five different identities and
    expression mixes) also goes through the whole converter, which keeps the suite's time."""
    from geoface.mesh.topology import topology_report
    from geoface.pipeline import ConvertOptions, convert
    from geoface.repair import make_disk
    from geoface.synth.ict import ict_head, load_ict_model, random_expression

    m = load_ict_model()
    rng = np.random.default_rng(100 + seed)
    h = ict_head(m, seed=100 + seed, expression=random_expression(rng, m.expression_names, count=int(rng.integers(1, 4))))
    disk = make_disk(h.V, h.F)
    rep = topology_report(disk.V, disk.F)
    assert rep.components == 1 and rep.boundary_loops == 1 and rep.genus == 0 and rep.nonmanifold_edges == 0
    if seed % 4:
        return
    out = convert(h.mesh(), tmp_path / "g", ConvertOptions(res=32, roi=h.face_mask, preview=False, reconstruct=False), quiet=True)
    st = out["sets"][0]
    assert st["distortion"]["flipped"] == 0 and st["coverage"] == 1.0 and st["ot"]["path"].startswith("ot")
    assert st["ot"]["flipped_after"] == 0
