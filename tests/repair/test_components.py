import numpy as np
import pytest

from geoface.errors import InvalidMeshError
from geoface.repair import keep_components
from geoface.synth import sphere, square_grid


def three_parts():
    V1, F1 = square_grid(6, size=1.0)  # area 1
    V2, F2 = square_grid(4, size=0.5)  # area 0.25
    V3, F3 = square_grid(2, size=0.1)  # area 0.01
    V = np.vstack([V1, V2 + 3, V3 + 6])
    F = np.vstack([F1, F2 + len(V1), F3 + len(V1) + len(V2)])
    return V, F, len(F1)


def test_keep_largest():
    V, F, m1 = three_parts()
    res = keep_components(V, F)
    assert len(res.F) == m1 and np.array_equal(res.face_map, np.arange(m1))
    assert res.changes[0]["area_removed"] == pytest.approx(0.26)


def test_area_fraction_filter():
    V, F, m1 = three_parts()
    res = keep_components(V, F, min_area_fraction=0.05, largest_only=False)
    assert res.changes[0]["removed"] == 1 and res.changes[0]["kept"] == 2
    with pytest.raises(InvalidMeshError):
        keep_components(V, F, min_area_fraction=1.5)


def test_single_component_untouched():
    V, F = sphere(1.0, 2)
    res = keep_components(V, F)
    assert res.changes == [] and np.array_equal(res.F, F)
