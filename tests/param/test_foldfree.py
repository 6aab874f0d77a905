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
