"""Build script: everything is in pyproject.toml except the optional compiled parts.

``geoface.param._native.regular_triangulation`` wraps CGAL's exact 2D regular triangulation
(power diagrams for optimal transport).  It needs CGAL's headers (Debian: ``libcgal-dev``,
which ``make install`` sets up); without them the build skips it and geoface uses SciPy's
Qhull, which cannot separate sites closer than about 1e-7 of the square.

``geoface.mesh._native.zbuffer`` is the rasterizer's z-buffer loop in C++ (any C++ compiler;
without one, or where it fails to build, the same loop runs in NumPy).
"""

import os
import sysconfig

from setuptools import Extension, setup


def _have_cgal() -> bool:
    roots = [os.environ.get("CGAL_DIR", ""), "/usr/include", "/usr/local/include", sysconfig.get_paths()["include"]]
    conda = os.environ.get("CONDA_PREFIX")
    if conda:
        roots.append(os.path.join(conda, "include"))
    return any(r and os.path.isfile(os.path.join(r, "CGAL", "Regular_triangulation_2.h")) for r in roots)


ext = [Extension(
    "geoface.mesh._native.zbuffer",
    sources=["geoface/mesh/_native/zbuffer.cpp"],
    language="c++",
    # no fused multiply-adds: the same arithmetic, to the last bit, as the NumPy loop it stands for
    extra_compile_args=["-O2", "-ffp-contract=off"],
    optional=True,
)]
if _have_cgal() and os.environ.get("GEOFACE_NO_CGAL") != "1":
    ext.append(Extension(
        "geoface.param._native.regular_triangulation",
        sources=["geoface/param/_native/regular_triangulation.cpp"],
        language="c++",
        extra_compile_args=["-O3", "-std=c++17", "-DNDEBUG", "-DCGAL_NDEBUG"],
        libraries=["gmp", "mpfr"],
        optional=True,
    ))

setup(ext_modules=ext)
