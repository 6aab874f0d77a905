import numpy as np
import pytest

torch = pytest.importorskip("torch")

from geoface import GeofaceError
from geoface.ddpm.data import AugmentOptions, GImageDataset, area_resize, find_items, rigid_augment


def test_dataset_scaling_and_prompts(gimage_dataset):
    ds = GImageDataset(gimage_dataset)
    assert len(ds) == 4  # the failed manifest row is skipped
    it = ds[0]
    assert it["image"].shape == (9, 16, 16) and it["mask"].shape == (1, 16, 16)
    assert it["prompt"] == "a smiling female"
    x, m = it["image"], it["mask"][0].bool()
    assert x.min() >= -1 and x.max() <= 1 and m.any()
    assert torch.all(x[:, ~m] == 0)
    n = x[3:6, m]
    torch.testing.assert_close(n.norm(dim=0), torch.ones(n.shape[1]), atol=2e-3, rtol=0)


def test_plain_folder_tree(tmp_path):
    from .conftest import make_gimage_dataset
    make_gimage_dataset(tmp_path, n_items=2, manifest=False)
    items = find_items(tmp_path)
    assert len(items) == 2 and items[0].prompt == ""
    with pytest.raises(GeofaceError, match="not found"):
        find_items(tmp_path / "nope")


def test_area_resize_averages_valid_pixels():
    img = np.zeros((1, 4, 4), np.float32)
    mask = np.zeros((4, 4), bool)
    img[0, 0, 0], mask[0, 0] = 1.0, True
    img[0, 0, 1], mask[0, 1] = 0.5, True
    out, m = area_resize(img, mask, 2)
    assert out[0, 0, 0] == pytest.approx(0.75) and m.tolist() == [[True, False], [False, False]]
    with pytest.raises(GeofaceError, match="divide"):
        area_resize(img, mask, 3)


def test_rigid_augment_properties(gimage_dataset):
    ds = GImageDataset(gimage_dataset, res=8)
    x, mask = ds[1]["image"], ds[1]["mask"][0]
    g = torch.Generator().manual_seed(0)
    y = rigid_augment(x, mask, g, AugmentOptions(max_angle=90, max_shift=0.0, scale_range=(1.0, 1.0)))
    m = mask.bool()
    # rotation about y keeps the distance to the centre and the height; normals stay unit
    torch.testing.assert_close(y[0:3, m].norm(dim=0), x[0:3, m].norm(dim=0), atol=1e-5, rtol=0)
    torch.testing.assert_close(y[1, m], x[1, m])
    torch.testing.assert_close(y[3:6, m].norm(dim=0), x[3:6, m].norm(dim=0), atol=1e-5, rtol=0)
    torch.testing.assert_close(y[6:], x[6:])
    assert not torch.allclose(y[0], x[0])
    # seeded
    dsa = GImageDataset(gimage_dataset, res=8, augment=True, seed=5)
    dsb = GImageDataset(gimage_dataset, res=8, augment=True, seed=5)
    torch.testing.assert_close(dsa[2]["image"], dsb[2]["image"], rtol=0, atol=0)
