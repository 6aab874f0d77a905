"""Tests for the procedural expressive head (geoface.synth.head)."""

from __future__ import annotations

import numpy as np
import pytest

from geoface.errors import GeofaceError, InvalidMeshError
from geoface.mesh.core import boundary_loops, face_normals, signed_volume, vertex_normals
from geoface.mesh.topology import topology_report
from geoface.synth.head import (
    EXPRESSION_NAMES,
    LANDMARK_NAMES,
    HeadExpression,
    HeadIdentity,
    HeadModel,
    SynthHead,
    procedural_head,
)


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def model():
    return HeadModel(n_vertices=6000, seed=3, texture_size=128)


@pytest.fixture(scope="module")
def neutral(model):
    return model.mesh()


@pytest.fixture(scope="module")
def expressed(model):
    return {name: model.mesh({name: 1.0}) for name in EXPRESSION_NAMES}


def _min_angles(V, F):
    """Smallest corner angle of every triangle, degrees."""
    e = [V[F[:, (k + 1) % 3]] - V[F[:, k]] for k in range(3)]
    ang = []
    for k in range(3):
        a, b = e[k], -e[(k + 2) % 3]
        c = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        ang.append(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
    return np.min(ang, axis=0)


def _closed_volume(V, F):
    """Signed volume after closing the neck boundary with a fan to its centroid."""
    (loop,) = boundary_loops(F)
    c = len(V)
    V2 = np.vstack([V, V[loop].mean(axis=0)])
    cap = np.stack([np.roll(loop, -1), loop, np.full(len(loop), c)], axis=1)
    return signed_volume(V2, np.vstack([F, cap]))


def _lm(head, name):
    return head.V[head.landmarks[name]]


# ---------------------------------------------------------------------------- topology and quality
@pytest.mark.parametrize("n", [1000, 10000])
def test_disk_topology_no_degenerate_faces(n):
    head = procedural_head(n_vertices=n, seed=1, texture_size=32)
    rep = topology_report(head.V, head.F)
    assert rep.is_disk
    assert rep.components == 1 and rep.genus == 0 and rep.boundary_loops == 1
    assert rep.nonmanifold_edges == 0 and rep.degenerate_faces == 0 and rep.duplicate_faces == 0
    assert rep.consistently_oriented


@pytest.mark.parametrize("n", [1000, 4321, 10000])
def test_vertex_count_within_tolerance(n):
    head = HeadModel(n_vertices=n, seed=2, texture_size=16).mesh()
    assert abs(len(head.V) - n) <= 0.03 * n
    assert head.V.dtype == np.float64 and head.F.dtype == np.int64
    assert head.V.shape == (len(head.V), 3) and head.F.shape[1] == 3


@pytest.mark.parametrize("n", [1000, 10000])
def test_triangle_quality(n):
    head = procedural_head(n_vertices=n, seed=4, texture_size=16)
    m = _min_angles(head.V, head.F)
    assert m.mean() > 40.0
    assert np.percentile(m, 1) > 20.0
    assert m.min() > 5.0


def test_neck_is_the_only_boundary_and_is_horizontal(neutral):
    (loop,) = boundary_loops(neutral.F)
    y = neutral.V[loop, 1]
    assert np.ptp(y) < 1e-6
    assert y.mean() < neutral.V[neutral.landmarks["chin"], 1] - 0.05


# ---------------------------------------------------------------------------- geometry
def test_outward_orientation(neutral):
    assert _closed_volume(neutral.V, neutral.F) > 0.002   # a head holds a few litres
    N = vertex_normals(neutral.V, neutral.F)
    assert N[neutral.landmarks["nose_tip"], 2] > 0.5
    assert N[neutral.landmarks["head_top"], 1] > 0.8
    assert N[neutral.landmarks["ear_left"], 0] > 0.3 and N[neutral.landmarks["ear_right"], 0] < -0.3


@pytest.mark.parametrize(
    "seed, identity",
    [(3, None), (0, None), (1, None), (0, {"hair_length": 1.0, "masculinity": -1.0}), (0, {"masculinity": 1.0, "jaw_width": 1.0})],
)
def test_neutral_surface_is_star_shaped(seed, identity):
    """Every triangle faces away from the centre: the neutral head is a radial graph, so it cannot self-intersect."""
    model = HeadModel(n_vertices=3000, seed=seed, identity=identity, texture_size=16)
    V, F = model.vertices(), model.F
    c = model._shape.centre * model._shape.scale
    centroid = V[F].mean(axis=1)
    assert (np.einsum("ij,ij->i", face_normals(V, F), centroid - c) > 0).all()
    (loop,) = boundary_loops(F)
    assert V[:, 1].min() >= V[loop, 1].min() - 1e-9           # nothing hangs below the neck cut


def test_bounding_box_plausible(neutral):
    V = neutral.V
    top, chin = V[:, 1].max(), _lm(neutral, "chin")[1]
    assert 0.21 < top - chin < 0.27               # chin to crown
    assert 0.13 < np.ptp(V[:, 0]) < 0.22          # ear to ear
    assert 0.17 < np.ptp(V[:, 2]) < 0.27          # nose tip to back of head
    assert (V.min(axis=0) < 0).all() and (V.max(axis=0) > 0).all()   # origin near the head centre
    assert np.linalg.norm(V.mean(axis=0)) < 0.06
    assert _lm(neutral, "nose_tip")[2] == pytest.approx(V[:, 2].max(), abs=0.01)


def test_landmarks(neutral):
    assert set(neutral.landmarks) == set(LANDMARK_NAMES)
    idx = np.array(list(neutral.landmarks.values()))
    assert len(np.unique(idx)) == len(idx) and idx.min() >= 0 and idx.max() < len(neutral.V)
    pos = neutral.landmark_positions()
    for name in ("brow", "eye_{}_center", "eye_{}_inner", "eye_{}_outer", "mouth", "ear"):
        left = pos[name.format("left") if "{}" in name else f"{name}_left"]
        right = pos[name.format("right") if "{}" in name else f"{name}_right"]
        assert left[0] > 0.005 and right[0] < -0.005            # subject's left is +X
        assert left[0] == pytest.approx(-right[0], abs=0.004)   # symmetric identity geometry
    assert pos["eye_left_inner"][0] < pos["eye_left_center"][0] < pos["eye_left_outer"][0]
    assert pos["head_top"][1] > pos["forehead"][1] > pos["brow_left"][1] > pos["eye_left_center"][1]
    assert pos["eye_left_center"][1] > pos["nose_tip"][1] > pos["upper_lip"][1] > pos["lower_lip"][1] > pos["chin"][1]
    assert pos["nose_bridge"][2] < pos["nose_tip"][2]


# ---------------------------------------------------------------------------- expressions
def test_expressions_keep_connectivity(neutral, expressed):
    for name, head in expressed.items():
        assert np.array_equal(head.F, neutral.F), name
        assert np.array_equal(head.UV, neutral.UV), name
        assert np.array_equal(head.face_mask, neutral.face_mask), name
        assert np.array_equal(head.upper_face_mask, neutral.upper_face_mask), name
        assert head.landmarks == neutral.landmarks, name
        assert head.V.shape == neutral.V.shape and not np.array_equal(head.V, neutral.V), name
        assert getattr(head.expression, name) == 1.0


def test_jaw_open(neutral, expressed):
    h = expressed["jaw_open"]
    d_chin = _lm(h, "chin") - _lm(neutral, "chin")
    assert d_chin[1] < -0.01 and np.linalg.norm(d_chin) < 0.05
    gap0 = _lm(neutral, "upper_lip")[1] - _lm(neutral, "lower_lip")[1]
    gap1 = _lm(h, "upper_lip")[1] - _lm(h, "lower_lip")[1]
    assert gap1 - gap0 > 0.01                                           # the lips part
    assert np.linalg.norm(_lm(h, "nose_tip") - _lm(neutral, "nose_tip")) < 1e-4
    assert np.linalg.norm(_lm(h, "upper_lip") - _lm(neutral, "upper_lip")) < 0.007   # the lower lip moves > 2 cm
    # the mouth interior is dark: vertices between the parted lips
    mouth = _mouth_interior(neutral, h)
    assert mouth.sum() >= 3
    assert h.colors[mouth].sum(axis=1).min() < 0.6                    # dark throat (teeth may show too)


def _mouth_interior(neutral, h):
    """Vertices of the open mouth: on the lips' midline band, pulled well behind the lips."""
    ul, ll = _lm(h, "upper_lip"), _lm(h, "lower_lip")
    V = h.V
    return (np.abs(V[:, 0]) < 0.015) & (V[:, 1] < ul[1] - 0.003) & (V[:, 1] > ll[1] + 0.003) & \
        (V[:, 2] < min(ul[2], ll[2]) - 0.004) & (V[:, 2] > ul[2] - 0.05) & neutral.face_mask


def test_smile_raises_mouth_corners(neutral, expressed):
    h = expressed["smile"]
    for side in ("left", "right"):
        d = _lm(h, f"mouth_{side}") - _lm(neutral, f"mouth_{side}")
        assert d[1] > 0.003
        assert abs(_lm(h, f"mouth_{side}")[0]) > abs(_lm(neutral, f"mouth_{side}")[0])   # corners pulled out
        assert d[2] < 0.0                                                                  # and back
    assert np.linalg.norm(_lm(h, "brow_left") - _lm(neutral, "brow_left")) < 1e-3


def test_brow_raise_and_frown(neutral, expressed):
    up = expressed["brow_raise"]
    for side in ("left", "right"):
        assert _lm(up, f"brow_{side}")[1] - _lm(neutral, f"brow_{side}")[1] > 0.004
    fr = expressed["frown"]
    for side in ("left", "right"):
        d = _lm(fr, f"brow_{side}") - _lm(neutral, f"brow_{side}")
        assert d[1] < -0.001                                                      # lowered
        assert abs(_lm(fr, f"brow_{side}")[0]) < abs(_lm(neutral, f"brow_{side}")[0])   # drawn together
    assert np.linalg.norm(_lm(fr, "chin") - _lm(neutral, "chin")) < 1e-6


def test_eyes_closed_covers_the_eye(neutral, expressed):
    h = expressed["eyes_closed_left"]
    c0 = neutral.colors[neutral.landmarks["eye_left_center"]]
    c1 = h.colors[h.landmarks["eye_left_center"]]
    assert c0.max() < 0.25                    # open: the pupil
    assert c1.mean() > 0.3                    # closed: lid skin over it
    assert np.allclose(h.colors[h.landmarks["eye_right_center"]], neutral.colors[neutral.landmarks["eye_right_center"]])
    # the lid lies on the eyeball: the eye centre moves outward a little, the other eye stays
    d = _lm(h, "eye_left_center") - _lm(neutral, "eye_left_center")
    assert 0.0005 < d[2] < 0.005
    assert np.linalg.norm(_lm(h, "eye_right_center") - _lm(neutral, "eye_right_center")) < 1e-9
    # texture: the eye region changed, the rest of the texture did not
    assert not np.array_equal(h.texture, neutral.texture)
    r = expressed["eyes_closed_right"]
    assert r.colors[r.landmarks["eye_right_center"]].mean() > 0.3


def test_pucker_and_pout(neutral, expressed):
    def width(h):
        return np.linalg.norm(_lm(h, "mouth_left") - _lm(h, "mouth_right"))

    pk = expressed["pucker"]
    assert width(neutral) - width(pk) > 0.006
    assert _lm(pk, "upper_lip")[2] - _lm(neutral, "upper_lip")[2] > 0.005
    pl, pr = expressed["pout_left"], expressed["pout_right"]
    assert _lm(pl, "upper_lip")[0] - _lm(neutral, "upper_lip")[0] > 0.003
    assert _lm(pr, "upper_lip")[0] - _lm(neutral, "upper_lip")[0] < -0.003
    assert _lm(pl, "lower_lip")[2] > _lm(neutral, "lower_lip")[2]


def test_cheek_puff_moves_cheeks_outward(neutral, expressed):
    h = expressed["cheek_puff"]
    N = vertex_normals(neutral.V, neutral.F)
    disp = np.einsum("ij,ij->i", h.V - neutral.V, N)
    assert disp.max() > 0.008
    k = np.argmax(disp)
    assert 0.02 < abs(neutral.V[k, 0]) < 0.07 and neutral.V[k, 1] < _lm(neutral, "nose_tip")[1]


@pytest.mark.parametrize("name", EXPRESSION_NAMES)
def test_expression_has_no_folds(neutral, expressed, name):
    """No face turns against its neighbourhood (a cheap self-intersection / fold check)."""
    h = expressed[name]
    Fn = face_normals(h.V, h.F)
    Vn = vertex_normals(h.V, h.F)
    avg = Vn[h.F].sum(axis=1)
    avg /= np.linalg.norm(avg, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", Fn, avg).min() > -0.2
    assert topology_report(h.V, h.F).degenerate_faces == 0
    assert _closed_volume(h.V, h.F) > 0.002


@pytest.mark.parametrize(
    "expr",
    [{"smile": 1.0, "jaw_open": 0.6}, {"pucker": 1.0, "cheek_puff": 1.0}, {"frown": 1.0, "pout_left": 1.0},
     {"jaw_open": 1.0, "brow_raise": 1.0, "eyes_closed_left": 1.0, "eyes_closed_right": 1.0}],
)
def test_combined_expressions_have_no_folds(model, neutral, expr):
    V = model.vertices(expr)
    Fn = face_normals(V, neutral.F)
    avg = vertex_normals(V, neutral.F)[neutral.F].sum(axis=1)
    avg /= np.linalg.norm(avg, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", Fn, avg).min() > -0.3
    np.testing.assert_array_equal(model.mesh(expr).V, V)


def test_expression_moves_only_its_region(neutral, expressed):
    far = neutral.V[:, 2] < -0.03             # back of the head and neck
    for name, h in expressed.items():
        assert np.abs(h.V[far] - neutral.V[far]).max() < 1e-3, name


def test_partial_expressions_interpolate(model, neutral):
    half = model.mesh({"jaw_open": 0.5})
    full = model.mesh(HeadExpression(jaw_open=1.0))
    dy_half = _lm(half, "chin")[1] - _lm(neutral, "chin")[1]
    dy_full = _lm(full, "chin")[1] - _lm(neutral, "chin")[1]
    assert dy_full < dy_half < 0.0
    combo = model.mesh({"smile": 0.7, "eyes_closed_left": 0.5, "brow_raise": 0.3})
    assert np.array_equal(combo.F, neutral.F)


def test_blendshapes(model, neutral, expressed):
    B = model.blendshapes()
    assert B.shape == (len(EXPRESSION_NAMES), len(neutral.V), 3)
    for k, name in enumerate(EXPRESSION_NAMES):
        np.testing.assert_allclose(B[k], expressed[name].V - neutral.V, atol=1e-12)
    assert np.linalg.norm(B[EXPRESSION_NAMES.index("jaw_open")], axis=1).max() > 0.015
    eye = np.linalg.norm(B[EXPRESSION_NAMES.index("eyes_closed_left")], axis=1)
    assert eye.max() > 0.0005 and (eye[neutral.V[:, 0] < -0.01] == 0).all()


# ---------------------------------------------------------------------------- masks, UV, texture
def test_face_mask(neutral):
    fm = neutral.face_mask
    assert fm.dtype == bool and fm.shape == (len(neutral.V),)
    for name in ("nose_tip", "nose_bridge", "eye_left_center", "eye_right_center", "mouth_left", "mouth_right",
                 "upper_lip", "lower_lip", "chin", "forehead", "brow_left"):
        assert fm[neutral.landmarks[name]], name
    for name in ("head_top", "ear_left", "ear_right"):
        assert not fm[neutral.landmarks[name]], name
    V = neutral.V
    assert not fm[V[:, 2] < -0.02].any()                              # back of the head
    assert not fm[V[:, 1] < _lm(neutral, "chin")[1] - 0.02].any()      # neck
    assert 0.08 < fm.mean() < 0.35


def test_upper_face_mask_splits_at_eye_line(neutral):
    y = neutral.V[:, 1]
    eye_y = 0.5 * (_lm(neutral, "eye_left_center")[1] + _lm(neutral, "eye_right_center")[1])
    assert neutral.eye_line_y == pytest.approx(eye_y)
    assert np.array_equal(neutral.upper_face_mask, y > neutral.eye_line_y)
    assert neutral.upper_face_mask[neutral.landmarks["forehead"]] and not neutral.upper_face_mask[neutral.landmarks["chin"]]


def test_uv_seamless_and_not_flipped(neutral):
    UV = neutral.UV
    assert UV.shape == (len(neutral.V), 2) and UV.dtype == np.float64
    assert UV.min() >= 0.0 and UV.max() <= 1.0
    a, b, c = UV[neutral.F[:, 0]], UV[neutral.F[:, 1]], UV[neutral.F[:, 2]]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    assert (area > 0).all()                                          # injective, counter-clockwise
    assert len(np.unique(np.round(UV, 12), axis=0)) == len(UV)


def test_texture_shape_and_consistency(neutral):
    T = 128
    tex = neutral.texture
    assert tex.shape == (T, T, 3) and tex.dtype == np.uint8
    # pixel (i, j) centre <-> UV ((j + .5) / T, 1 - (i + .5) / T): sample at the vertices
    j = np.clip(np.floor(neutral.UV[:, 0] * T).astype(int), 0, T - 1)
    i = np.clip(np.floor((1.0 - neutral.UV[:, 1]) * T).astype(int), 0, T - 1)
    sampled = tex[i, j] / 255.0
    err = np.abs(sampled - neutral.colors).mean(axis=1)
    assert np.median(err) < 0.04
    assert np.mean(err < 0.1) > 0.9


def test_colors(neutral):
    C = neutral.colors
    assert C.shape == (len(neutral.V), 3) and C.dtype == np.float64
    assert C.min() >= 0.0 and C.max() <= 1.0
    lips = C[neutral.landmarks["lower_lip"]]
    cheek_ref = C[neutral.face_mask].mean(axis=0)
    assert lips[0] / lips[1] > cheek_ref[0] / cheek_ref[1]          # lips are redder than the face


def test_skin_tone_controls_colour():
    light = HeadModel(1500, seed=0, identity=HeadIdentity(skin_tone=0.0), texture_size=16).mesh()
    dark = HeadModel(1500, seed=0, identity=HeadIdentity(skin_tone=1.0), texture_size=16).mesh()
    k = light.landmarks["forehead"]
    assert light.colors[k].mean() > dark.colors[k].mean() + 0.3


# ---------------------------------------------------------------------------- determinism and identity
def test_deterministic_bytes():
    a = HeadModel(2500, seed=11, texture_size=64).mesh({"smile": 0.5, "jaw_open": 0.3})
    b = HeadModel(2500, seed=11, texture_size=64).mesh({"smile": 0.5, "jaw_open": 0.3})
    for f in ("V", "F", "colors", "UV", "texture", "face_mask", "upper_face_mask"):
        assert getattr(a, f).tobytes() == getattr(b, f).tobytes(), f
    assert a.landmarks == b.landmarks and a.identity == b.identity


def test_different_seeds_differ():
    a = HeadModel(2000, seed=1, texture_size=16)
    b = HeadModel(2000, seed=2, texture_size=16)
    assert a.identity != b.identity
    assert not np.allclose(a.mesh().V[:50], b.mesh().V[:50])
    # a given identity does not depend on the seed's identity sampling
    ident = HeadIdentity(masculinity=0.5)
    c = HeadModel(2000, seed=1, identity=ident, texture_size=16).mesh()
    d = HeadModel(2000, seed=2, identity=ident.to_dict(), texture_size=16).mesh()
    assert np.array_equal(c.V, d.V) and c.identity == d.identity


def test_identity_roundtrip_and_random():
    ident = HeadIdentity.random(np.random.default_rng(7))
    assert HeadIdentity.from_dict(ident.to_dict()) == ident
    assert HeadIdentity.random(np.random.default_rng(7)) == ident
    for name, (lo, hi) in HeadIdentity.RANGES.items():
        assert lo <= getattr(ident, name) <= hi
    e = HeadExpression(smile=0.25, frown=1.0)
    assert HeadExpression.NAMES == EXPRESSION_NAMES and EXPRESSION_NAMES[0] == "smile" and EXPRESSION_NAMES[-1] == "frown"
    assert e.as_array().tolist() == [0.25, 0, 0, 0, 0, 0, 0, 0, 0, 1.0]
    assert HeadExpression.from_dict(e.to_dict()) == e
    assert HeadExpression.from_array(e.as_array()) == e


@pytest.mark.parametrize("masculinity", [-1.0, 1.0])
def test_extreme_identities_stay_valid(masculinity):
    extreme = {k: (hi if masculinity > 0 else lo) for k, (lo, hi) in HeadIdentity.RANGES.items()}
    extreme["masculinity"] = masculinity
    model = HeadModel(2500, seed=0, identity=extreme, texture_size=16)
    for expr in (None, {"jaw_open": 1.0, "smile": 1.0, "cheek_puff": 1.0}, {n: 1.0 for n in EXPRESSION_NAMES}):
        head = model.mesh(expr)
        rep = topology_report(head.V, head.F)
        assert rep.is_disk and rep.degenerate_faces == 0
        assert _closed_volume(head.V, head.F) > 0.002
    assert isinstance(head, SynthHead)


def test_masculinity_shapes_the_head():
    fem = HeadModel(3000, seed=0, identity=HeadIdentity(masculinity=-1.0), texture_size=16)
    mas = HeadModel(3000, seed=0, identity=HeadIdentity(masculinity=1.0), texture_size=16)
    f, m = fem.mesh(), mas.mesh()
    # wider neck, more prominent brow ridge relative to the eyes, bigger head
    def neck_width(h):
        y = h.V[:, 1]
        sel = np.abs(y - (_lm(h, "chin")[1] - 0.05)) < 0.005
        return np.ptp(h.V[sel, 0])

    assert neck_width(m) > neck_width(f) * 1.1
    assert np.ptp(m.V[:, 1]) > np.ptp(f.V[:, 1])


# ---------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(n_vertices=999), "n_vertices"),
        (dict(n_vertices=200_001), "n_vertices"),
        (dict(n_vertices=5000.5), "n_vertices"),
        (dict(n_vertices=True), "n_vertices"),
        (dict(seed=-1), "seed"),
        (dict(seed="a"), "seed"),
        (dict(texture_size=8), "texture_size"),
        (dict(identity={"masculinity": 2.0}), "masculinity"),
        (dict(identity={"wings": 1.0}), "wings"),
        (dict(identity=[1, 2]), "identity"),
        (dict(expression={"smile": 1.5}), "smile"),
        (dict(expression={"jaw_open": -0.1}), "jaw_open"),
        (dict(expression={"frown": float("nan")}), "frown"),
        (dict(expression={"wink": 1.0}), "wink"),
        (dict(expression=0.5), "expression"),
    ],
)
def test_bad_arguments(kwargs, word):
    args = dict(n_vertices=1000, seed=0, texture_size=16)
    args.update(kwargs)
    with pytest.raises(GeofaceError, match=word):
        procedural_head(**args)


def test_bad_dataclass_values():
    with pytest.raises(InvalidMeshError, match="pucker"):
        HeadExpression(pucker=2.0)
    with pytest.raises(InvalidMeshError, match="skin_tone"):
        HeadIdentity(skin_tone=-0.5)
    with pytest.raises(InvalidMeshError, match="shape"):
        HeadExpression.from_array([0.0, 1.0])


def test_head_model_is_built_once_for_the_same_arguments_and_is_not_changed_by_its_use():
    from geoface.synth.head import MODEL_CACHE_SIZE, MODEL_CACHE_TEXTURE, HeadModel, head_model, _MODELS

    a = head_model(1500, seed=7, texture_size=32)
    smile = a.mesh({"smile": 1.0})
    smile.V[:] = 0.0  # what a caller does with its head does not reach the model
    smile.texture[:] = 0
    assert head_model(1500, seed=7, texture_size=32) is a
    fresh = HeadModel(1500, seed=7, texture_size=32)
    for e in (None, {"smile": 1.0}, {"jaw_open": 0.7}):
        m, f = a.mesh(e), fresh.mesh(e)
        assert np.array_equal(m.V, f.V) and np.array_equal(m.texture, f.texture) and np.array_equal(m.colors, f.colors)
    assert head_model(1500, seed=8, texture_size=32) is not a
    for s in range(MODEL_CACHE_SIZE):
        head_model(1000, seed=100 + s, texture_size=16)
    assert head_model(1500, seed=7, texture_size=32) is not a  # the oldest are let go
    with pytest.raises(InvalidMeshError, match="n_vertices"):
        head_model(1500.0, seed=7, texture_size=32)
    kept = list(_MODELS)
    big = head_model(1000, seed=1, texture_size=MODEL_CACHE_TEXTURE + 1)
    assert list(_MODELS) == kept and head_model(1000, seed=1, texture_size=MODEL_CACHE_TEXTURE + 1) is not big
