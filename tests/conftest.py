"""Shared fixtures: small exact meshes, the shared real meshes, strict mode, quiet progress."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("GEOFACE_QUIET", "1")
# pytest-xdist runs a worker per core: each gets its share of the cores for its math libraries.
# Left at their default (every core each), the workers' thread pools fight over the cores and a
# torch-heavy test can run ten times slower while another worker is busy too.
if os.environ.get("PYTEST_XDIST_WORKER_COUNT"):
    _share = str(max(1, (os.cpu_count() or 1) // int(os.environ["PYTEST_XDIST_WORKER_COUNT"])))
    for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(_var, _share)


@pytest.fixture(scope="session", autouse=True)
def _shared_cache(tmp_path_factory):
    """One on-disk cache of faces and level turns (geoface._cache) for the whole run, shared by
    the xdist workers and the processes the tests start: a mesh converted by several tests (and
    by a dataset's worker processes) is looked at once. Set before any test starts."""
    from geoface import _cache

    if _cache.folder() is not None:  # the caller chose one
        yield
        return
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    os.environ[_cache.ENV] = str(root / "geoface-cache")
    yield
    os.environ.pop(_cache.ENV, None)


@pytest.fixture(autouse=True)
def _threads():
    """Each test starts with the worker's share of threads (a test that trains with a config's
    ``threads`` changes torch's process-wide setting)."""
    if os.environ.get("PYTEST_XDIST_WORKER_COUNT"):
        import torch

        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))
    yield


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


@pytest.fixture(scope="session")
def clip_capture(tmp_path_factory):
    """One second of a real clip (``woman_blue_backdrop.mp4``, ../shared) made into a capture at
    160² once per test run: ``(ClipCapture, the clip's path)``; tests only read it."""
    pytest.importorskip("mediapipe")
    from geoface.avatar.clip import capture_clip
    from tests.helpers import short_clip

    work = tmp_path_factory.mktemp("clip")
    clip = short_clip("woman_blue_backdrop.mp4", work, seconds=1.0)
    return capture_clip(clip, work / "cap", res=160, head_vertices=1500, quiet=True), clip

