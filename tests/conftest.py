"""Shared fixtures: small exact meshes, the shared real meshes, strict mode, quiet progress."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("GEOFACE_QUIET", "1")

@pytest.fixture(autouse=True)
def _strict():
    """Every test runs with geoface's expensive self-checks on."""
    from geoface import tol

    with tol.strict_mode():
        yield


@pytest.fixture
def tri():
    return np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]])


@pytest.fixture
def bowtie():
    """Two triangles sharing only a vertex (non-manifold vertex 0)."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, -1, 0]])
    F = np.array([[0, 1, 2], [0, 3, 4]])
    return V, F


@pytest.fixture
def fin():
    """A flat grid with a third face on one interior edge (non-manifold edge)."""
    from geoface.synth import square_grid

    V, F = square_grid(4)
    a, b = F[5, 0], F[5, 1]
    top = (V[a] + V[b]) / 2 + np.array([0.0, 0.0, 0.5])
    return np.vstack([V, top]), np.vstack([F, [[a, b, len(V)]]])
