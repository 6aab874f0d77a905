import math

import pytest

torch = pytest.importorskip("torch")

from geoface.nn.errors import NNError  # noqa: E402
from geoface.nn.hashenc import (HashEncoding, TriPlaneHashEncoding, hash_encode,  # noqa: E402
                                   hash_encode_reference, level_resolutions)


def test_level_resolutions_geometric():
    r = level_resolutions(4, 16, 1024)
    assert r[0] == 16 and r[-1] == 1024
    assert r == [16, 64, 256, 1024]  # b = 4
    assert level_resolutions(1, 8, 8) == [8]


@pytest.mark.parametrize("dim,log2", [(2, 6), (2, 16), (3, 8), (1, 4)])
def test_matches_reference_dense_and_hashed(dim, log2):
    # log2=6 → 64 rows: level 0 (res 4, 25 corners) dense, finer levels hashed.
    enc = HashEncoding(dim, levels=3, features=2, log2_table=log2, base_res=4, max_res=40, seed=0)
    with torch.no_grad():
        enc.tables.normal_()  # make features O(1) so the comparison means something
    x = torch.rand(37, dim, generator=torch.Generator().manual_seed(1))
    x[0] = 0.0
    x[1] = 1.0  # the far boundary: clamped into the last cell
    ref = hash_encode_reference(x, enc.tables.detach(), enc.resolutions)
    torch.testing.assert_close(enc(x), ref, rtol=1e-5, atol=1e-6)


def test_interpolates_grid_values_exactly_at_vertices_and_linearly_between():
    enc = HashEncoding(2, levels=1, features=1, log2_table=8, base_res=4, max_res=4, seed=0)
    with torch.no_grad():
        enc.tables.normal_(generator=torch.Generator().manual_seed(0))  # not the global RNG: order-independent
    T = enc.tables.detach()[0, :, 0]
    # grid vertex (i, j) of the dense 5x5 grid has row j*5 + i
    v = torch.tensor([[1 / 4, 2 / 4]])
    assert float(enc(v).detach()) == pytest.approx(float(T[2 * 5 + 1]), abs=1e-6)
    mid = torch.tensor([[1.5 / 4, 2 / 4]])
    assert float(enc(mid).detach()) == pytest.approx(0.5 * float(T[11] + T[12]), abs=1e-6)


def test_continuity_across_cells():
    enc = HashEncoding(2, levels=4, features=2, log2_table=10, base_res=8, max_res=128, seed=0)
    with torch.no_grad():
        enc.tables.normal_(generator=torch.Generator().manual_seed(0))  # not the global RNG: order-independent
    x = torch.tensor([[0.5, 0.3]])
    eps = 1e-6
    d = (enc(x + eps) - enc(x - eps)).abs().max()
    # d-linear interpolation is continuous: |Δ| <= 2 eps · res · |Δ table| ~ 1e-3 here; a jump between
    # cells would be of the order of the table values (~1)
    assert float(d.detach()) < 2e-3


def test_gradcheck_float64():
    enc = HashEncoding(2, levels=2, features=2, log2_table=5, base_res=3, max_res=9, seed=0).double()
    x = torch.rand(6, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    x.requires_grad_(True)
    tables = enc.tables.detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, t: hash_encode(a, t, enc.resolutions), (x, tables))


def test_fits_a_signal():
    torch.manual_seed(0)
    enc = HashEncoding(2, levels=4, features=2, log2_table=12, base_res=4, max_res=64, seed=0)
    head = torch.nn.Linear(enc.out_dim, 1)
    opt = torch.optim.Adam(list(enc.parameters()) + list(head.parameters()), lr=1e-2)
    x = torch.rand(2048, 2)
    y = torch.sin(6 * math.pi * x[:, :1]) * torch.cos(4 * math.pi * x[:, 1:])
    first = None
    for _ in range(150):
        loss = ((head(enc(x)) - y) ** 2).mean()
        first = first if first is not None else float(loss.detach())
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.05 * first


def test_triplane_shape_and_box():
    enc = TriPlaneHashEncoding(((-1, -1, -1), (1, 1, 1)), levels=3, features=2, log2_table=8, seed=0)
    x = torch.rand(5, 4, 3) * 2 - 1
    assert enc(x).shape == (5, 4, 18) and enc.out_dim == 18
    # the xy plane encoder sees only x and y: moving z leaves its 6 channels unchanged
    y = x.clone()
    y[..., 2] = 0.3
    torch.testing.assert_close(enc(x)[..., :6], enc(y)[..., :6])
    with pytest.raises(NNError):
        TriPlaneHashEncoding(((0, 0, 0), (1, 0, 1)))


def test_bad_arguments():
    with pytest.raises(NNError):
        HashEncoding(dim=4)
    with pytest.raises(NNError):
        HashEncoding(2, base_res=64, max_res=16)
    with pytest.raises(NNError, match="2 coordinates"):
        HashEncoding(2)(torch.rand(3, 3))
