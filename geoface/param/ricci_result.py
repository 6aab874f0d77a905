"""The result of a Ricci-flow rectangle map (:class:`RicciFlowResult`, made by
:class:`geoface.param.ricci.RicciFlowSolver`): the layout, the conformal factors, and the
conformal map at points of the mesh."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterizationError
from .layout import to_unit_square
from .tracking import FlipTracker, scale_bary


@dataclass(frozen=True)
class RicciFlowResult:
    """Result of a Ricci-flow rectangle map.

    Attributes
    ----------
    uv : (n, 2) float64 — rectangle layout, corner 0 at the origin, corner 1 on +x
    F : (m, 3) int64 — the triangulation ``uv`` is valid for: the input's, except that
        "ears" (boundary vertices with a single triangle, which cannot have a straight
        boundary angle) had the edge opposite them flipped; ``ears_flipped`` counts them
    u : (n,) float64 — log conformal factors
    corners : (4,) int64 — the corner vertices, counter-clockwise from the origin
    width, height : float — rectangle sides; ``aspect = width / height``
    converged : bool; iterations : int; residual : float (max |target - angle sum|)
    seconds : float; history : list of residuals per iteration
    V : (n', 3) float64 — the mesh's vertices; the input's, followed by the midpoints of
        boundary edges split by the boundary refinement (``split_edges[i]`` holds the
        endpoints of vertex ``n + i``), if any
    mesh_F : (m', 3) int64 — the mesh triangulation the flow started from (the input after
        ear flips and boundary splits); :meth:`map_points` takes faces of it
    tracker : replays intrinsic flips (None without them)
    """

    uv: np.ndarray
    u: np.ndarray
    corners: np.ndarray
    width: float
    height: float
    converged: bool
    iterations: int
    residual: float
    seconds: float
    history: list = field(default_factory=list)
    degenerate_triangles: int = 0
    F: np.ndarray | None = None
    ears_flipped: int = 0
    intrinsic_flips: int = 0
    mesh_F: np.ndarray | None = None
    V: np.ndarray | None = None
    split_edges: np.ndarray | None = None
    tracker: FlipTracker | None = field(default=None, repr=False)

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def map_points(self, face, bary, interpolation: str = "projective") -> np.ndarray:
        """The conformal map at points of the mesh: ``face (k,)`` indexes ``mesh_F`` (the
        input triangulation after ear flips and boundary splits), ``bary (k, 3)`` in its
        corner order → ``(k, 2)`` in the layout's coordinates.

        ``projective`` (default): the discrete conformal map itself, which takes each
        triangle's circumcircle to the circumcircle of its image (barycentrics scale by
        ``exp(-u_i)``; Springborn 2019).  With intrinsic flips the points are first carried
        through them (:mod:`geoface.param.tracking`), and the map is projective on each piece
        of the common refinement.  ``linear``: ``uv`` interpolated linearly, as a renderer
        does with the vertex UVs (only without intrinsic flips).
        """
        face = np.asarray(face, np.int64)
        bary = np.asarray(bary, np.float64).reshape(-1, 3)
        if interpolation not in ("projective", "linear"):
            raise ParameterizationError(f"interpolation must be 'projective' or 'linear'; got {interpolation!r}")
        if self.tracker is None:
            b = bary if interpolation == "linear" else scale_bary(self.F, face, bary, self.u)
            return np.einsum("ki,kij->kj", b, self.uv[self.F[face]])
        if interpolation == "linear":
            raise ParameterizationError("a result with intrinsic flips has no linear interpolation on the mesh's triangles")
        tface, tbary = self.tracker.track(face, bary)
        if not np.array_equal(self.tracker.F_final, self.F):
            raise ParameterizationError("internal: replayed flips do not reproduce the final triangulation")
        b = scale_bary(self.F, tface, tbary, self.u)
        return np.einsum("ki,kij->kj", b, self.uv[self.F[tface]])

    def unit_square(self, fit: str = "stretch") -> np.ndarray:
        """UVs in the unit square: ``stretch`` each side to 1 (default) or ``uniform``
        (keep the aspect ratio, centred)."""
        return to_unit_square(self.uv, self.width, self.height, fit)
