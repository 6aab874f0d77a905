"""Connected components: keep the largest, or all above an area fraction."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidMeshError
from ..mesh.core import check_mesh, face_areas, face_components
from .step import StepResult, select_faces


def keep_components(V, F, *, min_area_fraction: float | None = None, largest_only: bool = True) -> StepResult:
    """Drop small connected components.

    Parameters
    ----------
    min_area_fraction : float in [0, 1], optional
        Components with less than this fraction of the total area are dropped.
    largest_only : bool
        After the area filter, keep only the largest remaining component (a disk needs one).

    Examples
    --------
    >>> import numpy as np
    >>> from geoface.synth import square_grid
    >>> V, F = square_grid(4)
    >>> V2 = np.concatenate([V, V[:3] + 5.0]); F2 = np.concatenate([F, [[16, 17, 18]]])
    >>> len(keep_components(V2, F2).F) == len(F)
    True
    """
    V, F = check_mesh(V, F)
    if min_area_fraction is not None and not (0.0 <= min_area_fraction <= 1.0):
        raise InvalidMeshError(f"min_area_fraction must be in [0, 1]; got {min_area_fraction!r}")
    ncomp, lab = face_components(F, len(V))
    if ncomp <= 1:
        return StepResult.identity(V, F)
    area = np.bincount(lab, weights=face_areas(V, F), minlength=ncomp)
    total = area.sum()
    keep_c = np.ones(ncomp, bool)
    if min_area_fraction is not None:
        keep_c &= area >= min_area_fraction * total
        if not keep_c.any():
            keep_c[np.argmax(area)] = True
    if largest_only:
        best = np.argmax(np.where(keep_c, area, -1.0))
        keep_c[:] = False
        keep_c[best] = True
    dropped = int((~keep_c).sum())
    change = {
        "step": "remove_components",
        "removed": dropped,
        "kept": int(keep_c.sum()),
        "area_removed": float(area[~keep_c].sum()),
        "area_fraction_removed": float(area[~keep_c].sum() / total) if total > 0 else 0.0,
    }
    return select_faces(V, F, keep_c[lab], [change])
