import numpy as np
import pytest

from geoface.errors import ParameterizationError
from geoface.mesh.core import boundary_loops
from geoface.param.corners import boundary_arclength, corner_sets, default_corners
from geoface.synth import disk_grid, sphere


def arc_positions(V, F, corners):
    loop = boundary_loops(F)[0]
    s, L = boundary_arclength(V, loop)
    pos = {int(v): s[i] for i, v in enumerate(loop)}
    return np.array([pos[int(c)] for c in corners]), L


def test_default_corners_split_the_boundary_in_quarters():
    V, F = disk_grid(12)  # 72 boundary vertices on a circle
    c = default_corners(V, F, front=(1, 0, 0), up=(0, 0, 1))
    loop = boundary_loops(F)[0]
    ref = int(loop[np.argmax(V[loop] @ [1, 0, -1])])  # furthest along front - up
    s, L = arc_positions(V, F, c)
    gaps = np.diff(np.r_[s, s[0] + L]) % L
    assert np.allclose(gaps, L / 4, atol=L / 72)
    # the reference sits mid-way along the first side (corner 0 -> corner 1)
    sr = arc_positions(V, F, [ref])[0][0]
    assert abs(((sr - s[0]) % L) - L / 8) <= L / 72


def test_reference_vertex_and_errors():
    V, F = disk_grid(6)
    loop = boundary_loops(F)[0]
    c = default_corners(V, F, reference=int(loop[5]))
    s, L = arc_positions(V, F, c)
    sr = arc_positions(V, F, [int(loop[5])])[0][0]
    assert abs(((sr - s[0]) % L) - L / 8) <= L / len(loop)
    with pytest.raises(ParameterizationError, match="not on the boundary"):
        default_corners(V, F, reference=0)
    with pytest.raises(ParameterizationError, match="one boundary loop"):
        default_corners(*sphere(1.0, 1))


def test_eight_augmentation_sets_are_eight_different_corner_sets():
    V, F = disk_grid(12)
    sets = corner_sets(V, F, n=8)
    assert len(sets) == 8
    assert len({frozenset(c.tolist()) for c in sets}) == 8  # not rotations of one another
    _, L = arc_positions(V, F, sets[0])
    firsts = np.array([arc_positions(V, F, c)[0][0] for c in sets])
    # each set is turned 1/32 of the boundary further along
    steps = np.diff(firsts) % L
    assert np.allclose(steps, L / 32, atol=L / 72)
    for c in sets:
        s, _ = arc_positions(V, F, c)
        assert np.allclose(np.diff(np.r_[s, s[0] + L]) % L, L / 4, atol=L / 72)
    assert np.array_equal(sets[0], default_corners(V, F))


def test_coarse_boundary_still_gives_distinct_sets():
    V, F = disk_grid(3)  # 18 boundary vertices: fewer than 32 positions
    sets = corner_sets(V, F, n=8)
    assert len({frozenset(c.tolist()) for c in sets}) == 8
    assert all(len(set(c.tolist())) == 4 for c in sets)


def test_count_gives_the_first_sets_only():
    V, F = disk_grid(8)
    all8 = corner_sets(V, F, n=8)
    first3 = corner_sets(V, F, n=8, count=3)
    assert len(first3) == 3 and all(np.array_equal(a, b) for a, b in zip(first3, all8))
