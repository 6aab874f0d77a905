"""Closest-point baking: exact on planes (linear colours, linear texture ramps), normals on spheres."""

from __future__ import annotations

import numpy as np
import pytest

from geoface.errors import GeofaceError, InvalidGeometryImageError, InvalidMeshError
from geoface.gimage import geometry_image
from geoface.mesh.io import Mesh
from geoface.synth import irregular_flat_patch, sphere, spherical_cap, square_grid
from geoface.uvmap import bake_gimage, bake_texture, closest_points, texel_geometry

# a tilted plane: rotation about (1, 1, 0)-ish, then a shift
_a = 0.6
_R = np.array([[np.cos(_a), 0, np.sin(_a)], [0, 1, 0], [-np.sin(_a), 0, np.cos(_a)]]) @ np.array(
    [[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]])
_SHIFT = np.array([0.2, -0.1, 0.3])
_NORMAL = _R @ np.array([0.0, 0.0, 1.0])
_A = np.array([[0.5, -0.3, 0.2], [0.1, 0.4, -0.2], [-0.2, 0.1, 0.3]])


def _place(V2):
    return V2 @ _R.T + _SHIFT


def _color(P):
    """A linear function of position with values inside (0, 1) on the patch."""
    return 0.4 + (P - _SHIFT) @ _A.T * 0.5


def _on_plane(P):
    return P - ((P - _SHIFT) @ _NORMAL)[..., None] * _NORMAL


@pytest.fixture(scope="module")
def flat_source():
    V, F = square_grid(61)  # fine regular grid
    V = _place(V)
    return Mesh(V, F, colors=_color(V))


@pytest.fixture(scope="module")
def flat_target():
    V, F = irregular_flat_patch(120, seed=3)  # coarse, different tessellation
    uv = V[:, :2].copy()
    V = _place(V) + 0.01 * _NORMAL  # hovering 0.01 above the source
    return V, F, uv


def test_vertex_colours_baked_exactly_on_a_plane(flat_source, flat_target):
    V, F, uv = flat_target
    gi = geometry_image(V, F, uv, 48)
    out = bake_gimage(gi, flat_source)
    assert out.has("texture") and not gi.has("texture")
    P = gi.positions()[gi.mask]
    want = _color(_on_plane(P))
    got = out.modality("texture").transpose(1, 2, 0)[out.mask]
    assert out.mask.sum() == gi.mask.sum()
    assert np.abs(got - want).max() <= 1.0 / 255
    # position/normal channels untouched
    assert np.array_equal(out.modality("position"), gi.modality("position"))


def test_closest_points_barycentrics_reproduce_the_point(flat_source):
    rng = np.random.default_rng(0)
    P = _place(np.column_stack([rng.uniform(0.05, 0.95, (200, 2)), rng.uniform(-0.1, 0.1, 200)]))
    d, f, b = closest_points(P, flat_source.V, flat_source.F)
    C = (flat_source.V[flat_source.F[f]] * b[:, :, None]).sum(1)
    assert np.allclose(C, _on_plane(P), atol=1e-12)
    assert np.allclose(d, np.abs((P - _SHIFT) @ _NORMAL), atol=1e-12)
    assert np.allclose(b.sum(1), 1.0) and (b >= 0).all()


def test_textured_source_and_uv_texture_target(flat_source, flat_target):
    # texture ramps: R = column index, G = row index → linear in (u, v), so bilinear lookup is exact
    w = 256
    tex = np.zeros((w, w, 3), np.uint8)
    tex[:, :, 0] = np.arange(w)[None, :]
    tex[:, :, 1] = np.arange(w)[:, None]
    tex[:, :, 2] = 128
    V2 = (flat_source.V - _SHIFT) @ _R  # back to the plane's own coordinates
    UV = 0.1 + 0.8 * V2[:, :2]
    src = Mesh(flat_source.V, flat_source.F, UV=UV, FUV=flat_source.F, texture=tex)

    def analytic(P):
        q = ((_on_plane(P) - _SHIFT) @ _R)[:, :2]
        u, v = 0.1 + 0.8 * q[:, 0], 0.1 + 0.8 * q[:, 1]
        return np.column_stack([w * u - 0.5, w * (1 - v) - 0.5, np.full(len(u), 128.0)]) / 255

    V, F, uv = flat_target
    target = Mesh.from_vertex_uv(V, F, uv)
    res = bake_texture(target, src, 64)
    img, mask = res
    P, _, cover = texel_geometry(target, 64)
    assert np.array_equal(mask, cover) and mask.mean() > 0.9
    assert np.abs(img[mask] - analytic(P[mask])).max() <= 1.0 / 255
    assert (img[~mask] == 0).all()
    assert res.seconds["query"] <= res.seconds["total"]


def test_max_distance_cutoff(flat_source, flat_target):
    V, F, uv = flat_target
    gi = geometry_image(V, F, uv, 24)
    near = bake_gimage(gi, flat_source, max_distance=0.02)
    far = bake_gimage(gi, flat_source, max_distance=0.005)
    assert np.array_equal(near.mask, gi.mask)
    assert not far.mask.any() and far.meta["bake"]["baked_fraction"] == 0.0
    kept = bake_gimage(gi, flat_source, max_distance=0.005, keep_unbaked=True)
    assert np.array_equal(kept.mask, gi.mask) and (kept.modality("texture") == 0).all()


def test_normal_map_from_high_res_sphere():
    Vs, Fs = sphere(1.0, subdivisions=5)  # ~10k vertices
    src = Mesh(Vs, Fs)
    V, F = spherical_cap(1.0, np.pi / 3, n_rings=5)  # coarse cap of the same sphere
    uv = V[:, :2] / (2 * np.sin(np.pi / 3)) + 0.5
    gi = geometry_image(V, F, uv, 40)
    out = bake_gimage(gi, src, attribute="normal")
    n = out.normals()[out.mask]
    want = gi.positions()[out.mask]
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip((n * want).sum(1), -1, 1)))
    assert ang.max() < 0.5
    # the coarse mesh's own interpolated normals are visibly worse than the baked ones
    own = gi.normals()[gi.mask]
    own_ang = np.degrees(np.arccos(np.clip((own * want).sum(1), -1, 1)))
    assert own_ang.max() > 2 * ang.max()
    # the same through a UV texture of a target mesh
    nmap, m = bake_texture(Mesh.from_vertex_uv(V, F, uv), src, 32, attribute="normal")
    P, _, _ = texel_geometry(Mesh.from_vertex_uv(V, F, uv), 32)
    want = P[m] / np.linalg.norm(P[m], axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip((nmap[m] * want).sum(1), -1, 1))).max() < 0.5


def test_bad_inputs_raise(flat_source, flat_target):
    V, F, uv = flat_target
    gi = geometry_image(V, F, uv, 8)
    with pytest.raises(InvalidGeometryImageError, match="gi"):
        bake_gimage(np.zeros((6, 8, 8)), flat_source)
    with pytest.raises(InvalidMeshError, match="no colours"):
        bake_gimage(gi, Mesh(V, F))
    with pytest.raises(InvalidMeshError, match="source"):
        bake_gimage(gi, (V, F))
    with pytest.raises(GeofaceError, match="max_distance"):
        bake_gimage(gi, flat_source, max_distance=-1.0)
    with pytest.raises(GeofaceError, match="attribute"):
        bake_gimage(gi, flat_source, attribute="albedo")
    with pytest.raises(InvalidMeshError, match="UVs"):
        bake_texture(Mesh(V, F), flat_source, 16)
    with pytest.raises(GeofaceError, match="NaN"):
        closest_points(np.array([[np.nan, 0, 0]]), flat_source.V, flat_source.F)
    with pytest.raises(InvalidGeometryImageError, match="resolution"):
        bake_texture(Mesh.from_vertex_uv(V, F, uv), flat_source, 1)
