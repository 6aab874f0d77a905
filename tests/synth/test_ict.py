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
