import json

import numpy as np
import pytest


def make_gimage_dataset(root, n_items=4, N=16, manifest=True):
    """Tiny synthetic dataset: bumpy grids rasterised to N×N geometry images."""
    from geoface.gimage import geometry_image, save_gimage
    from geoface.synth.surfaces import square_grid

    prompts = ["a smiling female", "an angry male", "a neutral face", "a surprised child"]
    rows = []
    for k in range(n_items):
        V, F = square_grid(8, 1.0)
        V = np.asarray(V, np.float64).copy()
        uv = (V[:, :2] - V[:, :2].min(0)) / np.ptp(V[:, :2], axis=0)
        V[:, 2] = 0.2 * np.sin(3 * uv[:, 0] + k) * np.cos(2 * uv[:, 1])
        col = np.stack([uv[:, 0], uv[:, 1], np.full(len(V), k / n_items)], 1)
        gi = geometry_image(V, F, uv, N, colors=col)
        name = f"head_{k:03d}/aug0"
        save_gimage(root / name, gi)
        rows.append({"item": name, "status": "ok", "prompt": prompts[k % 4]})
    if manifest:
        rows.append({"item": "broken/aug0", "status": "failed", "error": "x"})
        (root / "manifest.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return root


@pytest.fixture(scope="session")
def gimage_dataset(tmp_path_factory):
    return make_gimage_dataset(tmp_path_factory.mktemp("gi_data"))
