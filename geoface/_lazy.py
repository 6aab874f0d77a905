"""Lazy imports of optional heavy stacks with an install hint, and the optional compiled helpers."""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import MissingDependencyError

_EXTRA_OF = {
    "pymeshlab": "repair",
    "manifold3d": "repair",
    "igl": "repair",
    "networkx": "repair",
    "fast_simplification": "repair",
    "rich": "extra",
    "PIL": "extra",
    "skimage": "extra",
    "pyvista": "viz",
    "dask": "dist",
    "threadpoolctl": "dist",
}
#: import name -> pip name where they differ (core dependencies)
_PIP_NAME = {"cv2": "opencv-python-headless"}


def lazy_import(name: str, feature: str = "") -> ModuleType:
    """Import ``name`` or raise :class:`MissingDependencyError` with a pip hint."""
    try:
        return importlib.import_module(name)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        top = name.split(".")[0]
        extra = _EXTRA_OF.get(top)
        hint = f"pip install 'geoface[{extra}]'" if extra else f"pip install {_PIP_NAME.get(top, top)}"
        what = f" (needed for {feature})" if feature else ""
        raise MissingDependencyError(f"optional dependency '{top}' is not installed{what}; try: {hint}") from exc


def lazy_exports(package: str, names: dict[str, str]):
    """A package's public names, imported on first use: ``names`` maps each name to the module
    that defines it (relative to ``package`` unless it holds a dot).  Returns ``__getattr__``,
    ``__dir__`` and ``__all__`` for the package's ``__init__``, so that ``from geoface.ddpm
    import sample`` works while ``import geoface.ddpm`` stays free of torch.

    A name may not be the name of its own module: once that submodule is imported, Python
    binds the package attribute to the module and ``from package import name`` would return
    the module instead of the function."""
    clash = sorted(n for n, m in names.items() if m.rsplit(".", 1)[-1] == n)
    if clash:
        raise ImportError(f"{package}: exported names shadowed by their own submodules: {', '.join(clash)}")

    def __getattr__(name):
        mod = names.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(mod if "." in mod else f"{package}.{mod}"), name)

    def __dir__():
        return sorted(names)

    # where each name is defined, for tools that read modules statically (the API reference)
    __getattr__.homes = {n: (m if "." in m else f"{package}.{m}") for n, m in names.items()}

    return __getattr__, __dir__, sorted(names)


def native_library(folder, stem: str, abi: str):
    """The compiled helper ``stem`` that ``setup.py`` builds into ``folder`` (a plain C ABI, loaded
    with ctypes), or None where it is not built, does not load, or its ``abi`` function does not
    return 1 (an extension built for another version of the code)."""
    import ctypes
    import importlib.machinery
    from pathlib import Path

    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        p = Path(folder) / f"{stem}{suffix}"
        if p.is_file():
            try:
                lib = ctypes.CDLL(str(p))
                return lib if getattr(lib, abi)() == 1 else None
            except (OSError, AttributeError):
                return None
    return None
