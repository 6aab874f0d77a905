"""Package-level promises: a light import, one error hierarchy, lazy heavy stacks."""

import subprocess
import sys

import geoface


def test_import_is_light():
    code = (
        "import sys, geoface, geoface.mesh, geoface.repair, geoface.synth;"
        "heavy = [m for m in ('torch', 'pyvista', 'vtk', 'pymeshlab', 'open3d', 'dask', 'diffusers') if m in sys.modules];"
        "print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""


def test_error_hierarchy():
    for name in ["MeshFormatError", "InvalidMeshError", "MeshTopologyError", "ParameterizationError", "InvalidGeometryImageError", "MissingDependencyError"]:
        assert issubclass(getattr(geoface, name), geoface.GeofaceError)


def test_missing_dependency_hint():
    from geoface._lazy import lazy_import
    from geoface.errors import MissingDependencyError

    try:
        lazy_import("geoface_no_such_module_xyz", "a test")
    except MissingDependencyError as exc:
        assert "pip install" in str(exc) and "a test" in str(exc)
    else:  # pragma: no cover
        raise AssertionError("expected MissingDependencyError")


def test_the_old_learn_names_still_resolve_with_a_warning():
    """geoface.learn split into geoface.ddpm and geoface.texture; the old front door warns and
    hands over the same objects."""
    import warnings

    import geoface.learn as old
    from geoface.ddpm import load_run
    from geoface.texture import TextureModel

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        assert old.load_run is load_run and old.TextureModel is TextureModel
    assert [str(x.message) for x in w] == ["geoface.learn.load_run is deprecated: import it from geoface.ddpm",
                                           "geoface.learn.TextureModel is deprecated: import it from geoface.texture"]
    assert all(x.category is DeprecationWarning for x in w)
