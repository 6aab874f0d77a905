"""Tolerances in one place (as trimesh does), plus the ``strict`` self-check switch.

All tolerances are *relative*: lengths are multiplied by the bounding-box diagonal,
areas by its square, so a mesh in millimetres and the same mesh in metres behave alike.

>>> from geoface import tol
>>> tol.merge          # vertex-merge distance / bbox diagonal
1e-07
>>> with tol.strict_mode():
...     pass           # expensive self-checks run inside this block
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass


@dataclass
class Tolerances:
    #: generic "is zero" for dimensionless quantities
    zero: float = 1e-12
    #: vertices closer than ``merge * bbox_diagonal`` are duplicates
    merge: float = 1e-7
    #: faces with area below ``area_eps * bbox_diagonal**2`` are degenerate
    area_eps: float = 1e-14
    #: a triangle is a "cap" (zero-area, no short edge) when its area is below
    #: ``cap_eps * longest_edge**2``; such faces are removed by edge flips
    cap_eps: float = 1e-10
    #: when True, algorithms run expensive self-checks on their own output
    strict: bool = False

    @contextlib.contextmanager
    def strict_mode(self, on: bool = True):
        """Temporarily switch ``strict`` on (tests use this)."""
        old = self.strict
        self.strict = on
        try:
            yield self
        finally:
            self.strict = old


tol = Tolerances()
