"""geoface.mesh.align: the least-squares similarity between corresponding points."""
import numpy as np

from geoface.mesh.align import similarity_transform


def _rot(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_recovers_a_similarity_and_fits_only_the_masked_pairs():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(30, 3))
    R0 = _rot([1, 2, 3], 0.7)
    Q = 1.7 * P @ R0.T + [0.3, -2.0, 5.0]
    s, R, t = similarity_transform(P, Q)
    assert np.isclose(s, 1.7) and np.allclose(R, R0) and np.allclose(t, [0.3, -2.0, 5.0])
    Q2 = Q.copy()
    Q2[:5] += 10.0  # outliers, left out by the mask
    mask = np.arange(30) >= 5
    s2, R2, t2 = similarity_transform(P, Q2, mask)
    assert np.isclose(s2, 1.7) and np.allclose(R2, R0) and np.allclose(t2, [0.3, -2.0, 5.0])
    assert not np.allclose(similarity_transform(P, Q2)[1], R0, atol=1e-3)


def test_a_mirror_image_gets_the_best_rotation_not_a_reflection():
    P = np.random.default_rng(1).normal(size=(20, 3))
    s, R, t = similarity_transform(P, P * [-1, 1, 1])
    assert np.isclose(np.linalg.det(R), 1.0) and s > 0
    assert similarity_transform(P[:2], P[:2] + 1)[0] == 1.0  # too few pairs: the identity
    s, R, t = similarity_transform(np.ones((4, 3)), np.zeros((4, 3)))  # all at one point
    assert s == 1.0 and np.allclose(R, np.eye(3)) and np.allclose(t, 0)
