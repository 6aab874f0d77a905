import math

import numpy as np
import pytest

from geoface import GeofaceError
from geoface.ddpm.evaluate import (cosine_similarity, masked_rms_distances, mesh_validity, nearest_neighbour,
                                    stratified_split, vendi_score)

from .conftest import make_gimage_dataset


# ---------------------------------------------------------------- Vendi
def test_vendi_identical_items_is_one():
    assert vendi_score(np.ones((6, 6))) == pytest.approx(1.0, abs=1e-9)
    X = np.tile([[1.0, 2.0, 3.0]], (5, 1))
    assert vendi_score(cosine_similarity(X)) == pytest.approx(1.0, abs=1e-9)


def test_vendi_orthogonal_items_is_n():
    assert vendi_score(np.eye(5)) == pytest.approx(5.0, abs=1e-9)
    assert vendi_score(cosine_similarity(3.0 * np.eye(7)[:4])) == pytest.approx(4.0, abs=1e-9)


def test_vendi_two_clusters():
    # two identical-within, orthogonal-between clusters of sizes a, b: eigenvalues a/n, b/n
    for a, b in ((3, 3), (3, 1)):
        X = np.array([[1.0, 0.0]] * a + [[0.0, 2.0]] * b)
        p = np.array([a, b]) / (a + b)
        assert vendi_score(cosine_similarity(X)) == pytest.approx(math.exp(-(p * np.log(p)).sum()), abs=1e-9)
    assert vendi_score(cosine_similarity(np.array([[1.0, 0]] * 2 + [[0, 1.0]] * 2))) == pytest.approx(2.0)


def test_vendi_rejects_bad_matrices():
    with pytest.raises(GeofaceError, match="square"):
        vendi_score(np.ones((2, 3)))
    with pytest.raises(GeofaceError, match="unit diagonal"):
        vendi_score(2 * np.eye(3))


# ---------------------------------------------------------------- nearest neighbour
def _brute(A, mA, B, mB):
    D = np.full((len(A), len(B)), np.inf)
    for i in range(len(A)):
        for j in range(len(B)):
            m = mA[i] & mB[j]
            if m.any():
                D[i, j] = np.sqrt(np.mean((A[i][:, m] - B[j][:, m]) ** 2))
    return D


def test_masked_rms_constructed():
    N = 4
    A = np.zeros((1, 3, N, N))
    B = np.stack([np.full((3, N, N), 0.5), np.full((3, N, N), 0.1)])
    full = np.ones((2, N, N), bool)
    D = masked_rms_distances(A, full[:1], B, full)
    np.testing.assert_allclose(D, [[0.5, 0.1]], atol=1e-12)
    d, j = nearest_neighbour(A, full[:1], B, full)
    assert j.tolist() == [1] and d[0] == pytest.approx(0.1)
    # differences outside the common coverage do not count; no overlap gives inf
    B2 = B.copy()
    B2[0, :, :, 2:] = 9.0
    half = np.zeros((2, N, N), bool)
    half[:, :, :2] = True
    D2 = masked_rms_distances(A, half[:1], B2, full)
    np.testing.assert_allclose(D2, [[0.5, 0.1]], atol=1e-12)
    other = ~half
    assert np.isinf(masked_rms_distances(A, half[:1], B, other)).all()
    with pytest.raises(GeofaceError, match="mB"):
        masked_rms_distances(A, half[:1], B, other[:1])


def test_masked_rms_matches_brute_force():
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(5, 3, 6, 6)), rng.normal(size=(4, 3, 6, 6))
    mA, mB = rng.random((5, 6, 6)) > 0.3, rng.random((4, 6, 6)) > 0.3
    np.testing.assert_allclose(masked_rms_distances(A, mA, B, mB), _brute(A, mA, B, mB), rtol=1e-9)


# ---------------------------------------------------------------- validity
@pytest.fixture(scope="module")
def real_gi(tmp_path_factory):
    from geoface.gimage import load_gimage
    root = make_gimage_dataset(tmp_path_factory.mktemp("ev"), n_items=1, N=16)
    return load_gimage(root / "head_000" / "aug0")


def test_validity_of_a_real_item_and_corruptions(real_gi):
    from geoface.gimage import GeometryImage
    v = mesh_validity(real_gi)
    assert v.valid, v.reason
    assert (v.components, v.euler, v.boundary_loops, v.zero_area_faces) == (1, 1, 1, 0)

    nan = GeometryImage(real_gi.image.copy(), real_gi.mask.copy(), dict(real_gi.meta))
    nan.image[0, 3, 3] = np.nan
    assert not mesh_validity(nan).valid and not mesh_validity(nan).finite

    rng = np.random.default_rng(0)  # scrambled coverage: holes and islands
    holes = GeometryImage(real_gi.image.copy(), rng.random(real_gi.mask.shape) > 0.4, dict(real_gi.meta))
    h = mesh_validity(holes)
    assert not h.valid and (h.components > 1 or h.euler != 1)

    flat = GeometryImage(real_gi.image.copy(), real_gi.mask.copy(), dict(real_gi.meta))
    flat.image[0:3, :, :8] = 0.0  # half the positions collapsed onto one point (clamped samples do this)
    f = mesh_validity(flat)
    assert not f.valid and f.zero_area_faces > 0

    scrambled = GeometryImage(real_gi.image.copy(), real_gi.mask.copy(), dict(real_gi.meta))
    perm = rng.permutation(16 * 16)
    scrambled.image[0:3] = scrambled.image[0:3].reshape(3, -1)[:, perm].reshape(3, 16, 16)
    sc = mesh_validity(scrambled)
    assert sc.reconstructs and (sc.components, sc.euler, sc.boundary_loops) == (1, 1, 1)  # topology survives
    assert not sc.valid and min(sc.folded_faces, sc.self_intersecting_faces) > 0.2 * sc.faces  # ... geometry does not

    empty = GeometryImage(real_gi.image.copy(), np.zeros_like(real_gi.mask), dict(real_gi.meta))
    e = mesh_validity(empty)
    assert not e.valid and not e.reconstructs


def test_validity_sees_folds_and_self_intersections(real_gi):
    """A clean disk can still be crumpled: faces turned against the normal channel, or crossing."""
    from geoface.gimage import GeometryImage
    v = mesh_validity(real_gi)
    assert v.folded_faces == 0.0 and v.self_intersecting_faces == 0.0

    flipped = GeometryImage(real_gi.image.copy(), real_gi.mask.copy(), dict(real_gi.meta))
    flipped.image[3:6] *= -1.0  # normals point inwards: every face is "folded" against them
    f = mesh_validity(flipped)
    assert not f.valid and f.folded_faces > 0.95 * f.faces and "fold" in f.reason

    # one vertex dragged past its neighbour two pixels away: a local fold and crossing faces
    poked = GeometryImage(real_gi.image.copy(), real_gi.mask.copy(), dict(real_gi.meta))
    P = poked.image[0:3]
    P[:, 8, 8] += 1.5 * (P[:, 8, 10] - P[:, 8, 8])
    p = mesh_validity(poked)
    assert p.reconstructs and (p.components, p.euler, p.boundary_loops) == (1, 1, 1)
    assert 0 < p.folded_faces < 0.05 * p.faces and 0 < p.self_intersecting_faces < 0.05 * p.faces
    assert not p.valid and "self-intersecting" in p.reason  # 10 of 450 faces > 2 %
    assert not mesh_validity(poked, max_folded=0.0, max_self_intersecting=0.0).valid
    assert mesh_validity(poked, max_self_intersecting=None, max_folded=1.0).valid  # the checks are what caught it


# ---------------------------------------------------------------- classifier, split
def test_classifier_learns_a_separable_toy_set():
    pytest.importorskip("torch")
    from geoface.ddpm.evaluate import predict, train_classifier
    rng = np.random.default_rng(0)
    y = np.arange(24) % 2
    X = rng.normal(0, 0.3, size=(24, 3, 16, 16)).astype(np.float32)
    X[:, 0, 4:12, 4:12] += np.where(y == 1, 1.0, -1.0)[:, None, None]
    m1 = train_classifier(X[:16], y[:16], epochs=3, width=8, seed=0)
    assert np.mean(predict(m1, X[16:]) == y[16:]) == 1.0
    m2 = train_classifier(X[:16], y[:16], epochs=3, width=8, seed=0)
    for p, q in zip(m1.parameters(), m2.parameters()):
        assert (p == q).all()  # deterministic for a seed
    with pytest.raises(GeofaceError, match="one label per item"):
        train_classifier(X[:3], y[:2])


def test_stratified_split():
    labels = np.array(["a"] * 10 + ["b"] * 5 + ["c"])
    tr, ho = stratified_split(labels, 0.2, seed=1)
    assert sorted(np.concatenate([tr, ho]).tolist()) == list(range(16))
    assert Counter_(labels[ho]) == {"a": 2, "b": 1}
    np.testing.assert_array_equal(stratified_split(labels, 0.2, seed=1)[1], ho)


def Counter_(x):
    from collections import Counter
    return dict(Counter(x.tolist()))


def test_aligned_distance_sees_through_rigid_augmentation():
    """A rotated, scaled, shifted copy of an item is at distance 0 after alignment (and far
    before); against an unrelated item the aligned distance matches an independent fit
    (SciPy's Kabsch rotation, least-squares scale) and never exceeds the plain distance."""
    from scipy.spatial.transform import Rotation

    from geoface.ddpm.evaluate import aligned_rms_distances

    rng = np.random.default_rng(0)
    N = 8
    A = rng.normal(0, 0.3, (1, 3, N, N))
    m = np.ones((1, N, N), bool)
    m[0, :2] = False
    R = Rotation.from_euler("y", 25, degrees=True).as_matrix()
    copy = (0.93 * np.einsum("ij,jhw->ihw", R, A[0]) + np.array([0.04, -0.02, 0.03])[:, None, None])[None]
    other = rng.normal(0, 0.3, (1, 3, N, N))
    B = np.concatenate([copy, other])
    mB = np.concatenate([m, np.ones((1, N, N), bool)])
    D = aligned_rms_distances(A, m, B, mB)
    plain = masked_rms_distances(A, m, B, mB)
    assert D[0, 0] < 1e-7 and plain[0, 0] > 0.05  # (sqrt of a cancelled variance: ~1e-9)
    assert (D <= plain + 1e-12).all()
    # independent fit for the unrelated pair over the common pixels
    common = (m[0] & mB[1]).ravel()
    a = A[0].reshape(3, -1)[:, common].T
    b = other[0].reshape(3, -1)[:, common].T
    a0, b0 = a - a.mean(0), b - b.mean(0)
    rot, _ = Rotation.align_vectors(b0, a0)
    ra = rot.apply(a0)
    s = (b0 * ra).sum() / (ra * ra).sum()
    ref = np.sqrt(np.mean((b0 - s * ra) ** 2))
    assert D[0, 1] == pytest.approx(ref, rel=1e-6)
    d, j = nearest_neighbour(A, m, B, mB, aligned=True)
    assert j.tolist() == [0]
