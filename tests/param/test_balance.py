"""Optimal transport that cannot fail on crowded sites: the area-balanced embedding, the fallback
path of the measure-preserving map, and the fast failure of the first solve.

The analytic case: a 40 x 40 grid of the unit square, uniform masses (so the exact
measure-preserving map is the identity), started from a fold-free map that squeezes a disk of
radius 0.3 radially by (r / 0.3)^k: vertices near the centre end up 1e-8 apart, with areas
e^-48 of their masses at k = 12 — what a long protrusion does to a conformal map."""

from __future__ import annotations

import numpy as np
import pytest

from geoface.errors import ParameterizationError
from geoface.mesh.core import boundary_loops, signed_uv_areas, vertex_areas
from geoface.param.balance import area_balanced_map, log_area_ratio
from geoface.param.foldfree import square_sides
from geoface.param.measure import measure_preserving_map
from geoface.param.ot import semi_discrete_ot
from geoface.synth import square_grid

CELL = 1.0 / 39


def _squeezed(k, R=0.3):
    V, F = square_grid(40)
    g = V[:, :2].copy()
    d = g - 0.5
    r = np.linalg.norm(d, axis=1)
    s = np.where(r < R, (r / R) ** k, 1.0)
    return V, F, g, 0.5 + d * s[:, None]


def test_balanced_embedding_undoes_a_billionfold_squeeze_without_folding():
    V, F, g, uv = _squeezed(12)
    nu = vertex_areas(V, F)
    assert np.abs(log_area_ratio(F, uv, nu)).max() > 40
    b = area_balanced_map(F, uv, nu)
    assert b.start_max_log_ratio > 40 and b.max_log_ratio <= 1.5
    assert (signed_uv_areas(F, b.uv) > 0).all()
    loop = boundary_loops(F)[0]
    assert square_sides(b.uv[loop]).any(1).all()  # the boundary stays on the square
    corners = np.flatnonzero(square_sides(uv[loop])[:, :2].any(1) & square_sides(uv[loop])[:, 2:].any(1))
    np.testing.assert_array_equal(b.uv[loop[corners]], uv[loop[corners]])
    assert np.abs(b.uv - g).max() < 0.03  # near the exact answer, the identity


def test_first_solve_fails_fast_and_partial_returns_where_it_stopped():
    V, F, _, uv = _squeezed(12)
    nu = vertex_areas(V, F)
    with pytest.raises(ParameterizationError, match="stalled"):
        semi_discrete_ot(uv, nu, stall=4)
    r = semi_discrete_ot(uv, nu, stall=4, partial=True)
    assert not r.converged and "stalled" in r.failure and r.residual > 1e-3


def test_measure_preserving_map_moves_crowded_sites_and_converges():
    V, F, g, uv = _squeezed(12)
    m = measure_preserving_map(V, F, uv, lam=1.0, quiet=True)
    assert m.path.startswith("balanced+ot") and m.sites == "balanced"
    assert m.converged and m.residual <= 1e-3 and m.flipped_after == 0
    assert m.attempts[0]["sites"] == "conformal" and not m.attempts[0]["converged"]
    assert np.abs(m.uv - g).max() < 0.3 * CELL  # the identity, to a third of a cell


def test_benign_sites_keep_the_direct_path():
    V, F, g, uv = _squeezed(4)
    m = measure_preserving_map(V, F, uv, lam=1.0, quiet=True)
    assert m.path == "ot" and m.sites == "conformal" and m.balanced is None and len(m.attempts) == 1
    assert m.converged and np.abs(m.uv - g).max() < 0.1 * CELL


def test_balanced_embedding_rejects_a_folded_start():
    V, F, _, uv = _squeezed(4)
    bad = uv.copy()
    inner = np.flatnonzero(~square_sides(uv).any(1))
    bad[inner[:2]] = bad[inner[:2]][::-1]  # swap two interior vertices: folds
    with pytest.raises(ParameterizationError, match="fold"):
        area_balanced_map(F, bad, vertex_areas(V, F))
