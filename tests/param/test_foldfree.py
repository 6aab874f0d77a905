"""The fold-free step after optimal transport: convex-combination maps (Tutte/Floater) and the
local untangling tried before the whole system is solved."""
from __future__ import annotations

import numpy as np

from geoface.mesh.core import signed_uv_areas
from geoface.param.foldfree import UNTANGLE_GAIN, convex_combination_map
from geoface.param.untangle import area_loss as _area_loss, untangle
from tests.helpers import planar_grid


def test_a_map_without_folds_is_kept_as_it_is():
    F, uv, inner = planar_grid()
    out, ok = untangle(F, uv, inner)
    assert ok and np.array_equal(out, uv)
    r = convex_combination_map(F, uv, uv)
    assert r.flipped == 0 and r.solve == "local" and np.abs(r.uv - uv).max() < 1e-12


def test_a_mirrored_patch_untangles_locally_and_keeps_its_area():
    """A patch of the grid mirrored in place (every triangle of it flipped, its rim folded): the
    untangled map is fold-free, vertices far from the patch do not move, and no triangle is
    squeezed (each keeps a good share of the grid's own area)."""
    F, uv, inner = planar_grid()
    h = 1.0 / 20
    patch = (np.abs(uv[:, 0] - 0.5) < 3.5 * h) & (np.abs(uv[:, 1] - 0.5) < 3.5 * h)
    target = uv.copy()
    target[patch, 0] = 1.0 - target[patch, 0]  # mirrored about x = 1/2
    assert (signed_uv_areas(F, target) <= 0).sum() > 50
    out, ok = untangle(F, target, inner)
    A = signed_uv_areas(F, out)
    assert ok and (A > 0).all()
    far = (np.abs(uv[:, 0] - 0.5) > 9.5 * h) | (np.abs(uv[:, 1] - 0.5) > 9.5 * h)
    assert np.array_equal(out[far], target[far])
    grid_area = 0.5 * h * h
    assert A.min() > 0.05 * grid_area and np.abs(np.log(A / grid_area)).mean() < 0.5, (A.min() / grid_area)
    # the whole step: fold-free, and it loses at most UNTANGLE_GAIN times the untangled map's areas
    # (the whole system's solve is kept only when it is about as good)
    r = convex_combination_map(F, target, uv)
    assert r.flipped == 0 and (signed_uv_areas(F, r.uv) > 0).all()
    assert _area_loss(F, r.uv, target) <= UNTANGLE_GAIN * _area_loss(F, out, target) + 1e-12


def test_untangling_stops_when_its_energy_stalls(monkeypatch):
    """L-BFGS's own tolerances are never met by the untangling energy: without a stop of its
    own, every region ran to ``max_iterations``. It stops once the energy has dropped by less
    than ``STALL`` over ``STALL_WINDOW`` iterations: the mirrored patch untangles in a few hundred
    iterations (3,000 without the stop), fold-free with its smallest triangle as large as then."""
    import scipy.optimize

    import geoface.param.untangle as U

    F, uv, inner = planar_grid()
    h = 1.0 / 20
    patch = (np.abs(uv[:, 0] - 0.5) < 3.5 * h) & (np.abs(uv[:, 1] - 0.5) < 3.5 * h)
    target = uv.copy()
    target[patch, 0] = 1.0 - target[patch, 0]
    runs = []
    real = scipy.optimize.minimize

    def counted(*a, **k):
        r = real(*a, **k)
        runs.append(int(r.nit))
        return r

    monkeypatch.setattr(scipy.optimize, "minimize", counted)
    out, ok = U.untangle(F, target, inner)
    assert ok and runs == [runs[0]] and runs[0] < 1000, runs  # one region: 380 iterations here
    monkeypatch.setattr(U, "STALL", -1.0)  # never stalls: the iteration limit
    runs.clear()
    full, ok_full = U.untangle(F, target, inner, max_iterations=3000)
    assert ok_full and runs == [3000], runs
    A, A_full = signed_uv_areas(F, out), signed_uv_areas(F, full)
    eps = 0.1 * np.median(np.abs(signed_uv_areas(F, target)))
    # the smallest triangle at 0.98 ε against 0.99 ε with the limit
    assert A.min() > 0.9 * eps and A.min() > 0.95 * A_full.min(), (A.min() / eps, A_full.min() / eps)


def test_tutte_embedding_of_a_regular_grid_is_the_grid():
    """Every interior vertex of the diagonal-split grid is the mean of its six neighbours."""
    from geoface.param.tutte import tutte_map

    F, uv, inner = planar_grid(15)
    noisy = uv.copy()
    noisy[inner] += np.random.default_rng(0).normal(0, 0.05, (inner.sum(), 2))  # the interior is not read
    np.testing.assert_allclose(tutte_map(F, noisy), uv, atol=1e-10)


def test_a_folded_start_is_made_fold_free_where_it_folds_only():
    """A map with a vertex pulled across its neighbours (as chords of an intrinsic layout can
    cross) becomes fold-free and stays near the map away from the fold (within a fifth of the
    grid's spacing; the folded vertex itself moves back by most of its pull)."""
    from geoface.param.balance import area_balanced_map
    from geoface.param.tutte import fold_free_start

    F, uv, inner = planar_grid(21)
    folded = uv.copy()
    k = int(np.argmin(np.linalg.norm(uv - [0.5, 0.5], axis=1)))
    folded[k] += [0.12, 0.09]  # across two rings of neighbours
    assert (signed_uv_areas(F, folded) <= 0).any()
    with np.testing.assert_raises(Exception):
        area_balanced_map(F, folded, np.full(len(uv), 1.0 / len(uv)))
    start = fold_free_start(F, folded)
    assert (signed_uv_areas(F, start) > 0).all()
    far = np.linalg.norm(uv - uv[k], axis=1) > 0.3
    assert np.abs(start[far] - folded[far]).max() < 0.01
    assert np.linalg.norm(start[k] - uv[k]) < 0.5 * np.linalg.norm(folded[k] - uv[k])
    assert fold_free_start(F, uv) is not None and np.array_equal(fold_free_start(F, uv), uv)
    bal = area_balanced_map(F, start, np.full(len(uv), 1.0 / len(uv)))  # the solver that needs a fold-free start
    assert (signed_uv_areas(F, bal.uv) > 0).all()
