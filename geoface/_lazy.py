"""Lazy imports of optional heavy stacks with an install hint."""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import MissingDependencyError

_EXTRA_OF = {
    "pymeshlab": "repair",
    "manifold3d": "repair",
    "igl": "repair",
    "networkx": "repair",
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
