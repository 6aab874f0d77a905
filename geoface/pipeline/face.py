"""The face in ``convert``: its landmarks recorded (``metrics.json``, each set's ``meta.json``)
and the corner sets turned along the boundary until its eye line is level in the default image."""

from __future__ import annotations

import numpy as np

from ..errors import GeofaceError
from ..progress import log
from .corner_set import LEVEL_TARGET, MAX_LEVEL_TURN, level_turn

__all__ = ["level_corners", "face_record", "corners_key", "COARSE_LEVEL_DEGREES", "LEVEL_BOUNDARY", "LEVEL_SEARCH_VERTICES",
           "FINE_LEVEL_DEGREES"]

#: the last few meshes' level turns are kept (per process): a dataset converts each mesh once per
#: corner set, and each item's corners are turned by the same set 0 map's eye line
LEVEL_CACHE_SIZE = 8
_LEVELS: dict = {}
#: options that do not change the map of corner set 0 (the cache's key leaves them out)
_NOT_THE_MAP = ("augment", "corner_set", "reconstruct", "preview", "metrics", "level", "find_face")


def _level_key(solver, roi, face, opts) -> str:
    import hashlib
    from dataclasses import asdict

    h = hashlib.sha1()
    for a in (solver.V, solver.F, np.asarray(face["points"], np.float64)) + (() if roi is None else (np.asarray(roi),)):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr(sorted((k, repr(v)) for k, v in asdict(opts).items() if k not in _NOT_THE_MAP)).encode())
    return h.hexdigest()


def corners_key(corners) -> tuple:
    """A corner set as a dictionary key."""
    return tuple(int(c) for c in corners)


def _tilter(solver, V, roi, colors, face, front, up, opts, quiet):
    """``(tilt, made)``: ``tilt(turn)``, the eye line (degrees) in the final map of corner set 0
    turned so on ``solver``'s mesh (None where the map fails; memoised by the corners the turn
    picks), and the maps made on the way (``{corners: (st entries, map_set's result)}``)."""
    from ..param.corners import corner_sets
    from .corner_set import SetInputs, face_pixels, map_set

    made: dict = {}
    tilts: dict = {}

    def tilt(turn):
        c = corner_sets(solver.V, solver.F, n=8, front=front, up=up, count=1, turn=turn)[0]
        key = corners_key(c)
        if key in tilts:  # a turn too small to move a corner: the map made already
            return tilts[key]
        st = {"corner_set": 0, "corners": [int(x) for x in c]}
        try:  # the first map is set 0's own: its iterations show with -v like any set's
            res = map_set(st, c, SetInputs(solver, V, roi, colors, opts, quiet if not made else True))
        except GeofaceError:
            tilts[key] = None
            return None
        made[key] = ({k: v for k, v in st.items() if k not in ("corner_set", "corners")}, res)
        r, Vx, _, _, uv = res
        tilts[key] = face_pixels(face["points"], Vx, r.F, uv, opts.res)["eye_line_degrees"]
        return tilts[key]

    tilt.clear = lambda: (made.clear(), tilts.clear())  # after the boundary is refined
    return tilt, made


def _coarse_disk(solver, roi, vertices: int):
    """``solver``'s disk decimated to about ``vertices`` vertices as a new solver (pymeshlab's
    quadric edge collapse with the boundary and the topology kept: every boundary vertex stays,
    so the corners can stand where they stand on the disk), and the mask carried over (each
    coarse vertex takes its nearest fine vertex's); None where the result is not a disk (one
    boundary loop, manifold, Euler characteristic 1) or the flow refuses it."""
    from scipy.spatial import cKDTree

    from .._lazy import lazy_import
    from ..mesh.core import edge_topology
    from ..param.ricci import RicciFlowSolver

    pymeshlab = lazy_import("pymeshlab", "levelling the face on a decimated copy")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(solver.V, np.float64), np.asarray(solver.F, np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=2 * int(vertices), preserveboundary=True, preservetopology=True,
                                                boundaryweight=1.0, planarquadric=True, qualitythr=0.3, autoclean=True)
    cm = ms.current_mesh()
    V, F = np.asarray(cm.vertex_matrix(), np.float64), np.asarray(cm.face_matrix(), np.int64)
    try:  # the flow refuses more than one boundary loop, unused vertices and non-manifold edges itself
        coarse = RicciFlowSolver(V, F)
    except GeofaceError:
        return None
    if len(V) - len(edge_topology(F).E) + len(F) != 1:  # one loop and manifold, but not a disk
        return None
    croi = None if roi is None else np.asarray(roi)[cKDTree(solver.V[: len(roi)]).query(V)[1]]
    return coarse, croi


def level_corners(solver, V, roi, colors, face, front, up, opts, quiet):
    """The turn of the corner sets that makes the face's eye line level in the default image
    (:func:`geoface.pipeline.corner_set.level_turn`, measured on set 0's final map), and the maps
    made on the way (``{corners: (st entries, map_set's result)}``: the sets at that turn are not
    made twice). Corners sit on vertices, so on a coarse boundary no turn may come within
    :data:`COARSE_LEVEL_DEGREES`; the boundary is then refined
    (:meth:`geoface.param.ricci.RicciFlowSolver.refine_boundary`, to :data:`LEVEL_BOUNDARY`
    vertices: a corner moves by a 180th of the boundary, the image by 2°) and the turn sought
    again. A disk of more than :data:`LEVEL_SEARCH_FACTOR` × :data:`LEVEL_SEARCH_VERTICES`
    vertices is mapped as it stands first; where its eye line is more than :data:`LEVEL_TARGET`
    off, the turn is sought on a copy decimated to the latter (each secant step costs a map, a
    fraction of the disk's there), then the disk mapped once at that turn, and once more (one
    secant step) when its eye line is more than :data:`FINE_LEVEL_DEGREES` off
    (:func:`_level_on_copy`); where that still leaves it more than :data:`COARSE_LEVEL_DEGREES`
    off, the turn is sought on the disk itself. The result goes into ``face["metrics"]["level"]``."""
    import copy

    from .. import _cache
    from ..param.corners import corner_sets

    key0 = _level_key(solver, roi, face, opts)
    if key0 not in _LEVELS:  # levelled in another process (GEOFACE_CACHE: a dataset's workers)
        stored = _cache.get("level", key0)
        if isinstance(stored, dict) and "turn" in stored and "boundary_vertices_added" in stored:
            _LEVELS[key0] = stored
    if key0 in _LEVELS:  # this mesh levelled already (a dataset's other corner sets): the same turn
        level = copy.deepcopy(_LEVELS[key0])
        if level["boundary_vertices_added"]:
            solver.refine_boundary(LEVEL_BOUNDARY)  # deterministic: the same boundary as then
        face["metrics"]["level"] = level
        return level["turn"], {}
    log("convert: levelling the face's eye line (corner set 0)", quiet=quiet, detail=True)
    tilt, made = _tilter(solver, V, roi, colors, face, front, up, opts, quiet)
    level = None
    if len(solver.V) > LEVEL_SEARCH_FACTOR * LEVEL_SEARCH_VERTICES:
        level = _level_on_copy(solver, roi, face, front, up, opts, tilt)
    if level is None:
        level = _level_search(solver, tilt)
    face["metrics"]["level"] = level
    _LEVELS[key0] = copy.deepcopy(level)
    _cache.put("level", key0, level)
    while len(_LEVELS) > LEVEL_CACHE_SIZE:
        _LEVELS.pop(next(iter(_LEVELS)))
    keep = corners_key(corner_sets(solver.V, solver.F, n=8, front=front, up=up, count=1, turn=level["turn"])[0])
    return level["turn"], {k: v for k, v in made.items() if k == keep}


def _level_search(solver, tilt, shift: float = 0.0) -> dict:
    """The secant search of :func:`level_corners` on ``solver``'s own mesh, the boundary refined
    where it is too coarse to come near. ``shift`` is added to every eye line: the search on a
    copy then aims at the turn that levels the disk (the copy's eye line differs from the disk's
    by about the same at every turn)."""
    def seen(turn):
        y = tilt(turn)
        return None if y is None else y + shift

    level = level_turn(seen, seen(0.0))
    added = 0
    if level["eye_line_after"] is not None and abs(level["eye_line_after"]) > COARSE_LEVEL_DEGREES:
        # corners move by whole vertices: on a coarse boundary no turn is near enough
        added = solver.refine_boundary(LEVEL_BOUNDARY)
        if added:
            tilt.clear()
            level = level_turn(seen, seen(0.0))
    level["boundary_vertices_added"] = added
    return level


def _level_on_copy(solver, roi, face, front, up, opts, tilt) -> dict | None:
    """The level turn of a large disk (:func:`level_corners`): the disk is mapped as it stands
    first (most faces found by looking come out within :data:`LEVEL_TARGET` of level, and that
    map is the one the images use); only where its eye line is further off is the turn sought
    on a decimated copy, aiming at the disk's own offset (its eye line minus the copy's at the
    same turn), then the disk mapped at that turn, and once more (a secant step through the
    disk's two maps) where it is still more than :data:`FINE_LEVEL_DEGREES` off. None where the
    disk's first map fails, the copy cannot be made, or the result is still more than
    :data:`COARSE_LEVEL_DEGREES` off."""
    y0 = tilt(0.0)
    if y0 is None:
        return None
    if abs(y0) <= LEVEL_TARGET:
        return {"turn": 0.0, "eye_line_before": y0, "eye_line_after": y0, "tries": 0, "boundary_vertices_added": 0}
    made = _coarse_disk(solver, roi, LEVEL_SEARCH_VERTICES)
    if made is None:
        return None
    coarse, croi = made
    ctilt, _ = _tilter(coarse, coarse.V, croi, None, face, front, up, opts, True)
    c0 = ctilt(0.0)
    if c0 is None:
        return None
    searched = _level_search(coarse, ctilt, shift=y0 - c0)
    turn = searched["turn"]
    best = (abs(y0), 0.0, y0)
    tries = 0
    if turn:
        y = tilt(turn)
        tries = 1
        if y is not None and abs(y) < best[0]:
            best = (abs(y), turn, y)
        if y is not None and abs(y) > FINE_LEVEL_DEGREES and y != y0:
            x = turn - y * turn / (y - y0)  # the secant through the disk's maps at 0 and at the turn
            if abs(x) <= MAX_LEVEL_TURN:
                y2 = tilt(x)
                tries = 2
                if y2 is not None and abs(y2) < best[0]:
                    best = (abs(y2), x, y2)
    if best[0] > COARSE_LEVEL_DEGREES:
        return None
    return {"turn": best[1], "eye_line_before": y0, "eye_line_after": best[2], "tries": tries,
            "boundary_vertices_added": 0,
            "searched_on": {"vertices": int(coarse.n_input), "tries": searched["tries"],
                            "eye_line_before": c0,
                            "eye_line_after": None if searched["eye_line_after"] is None else searched["eye_line_after"] - (y0 - c0),
                            "boundary_vertices_added": searched["boundary_vertices_added"]}}


#: where no turn of the corner sets brings the eye line within this many degrees of level, the
#: boundary is refined to at least :data:`LEVEL_BOUNDARY` vertices (a whole turn of the boundary
#: turns the image once round: a vertex step is then 2°) and the turn sought again
COARSE_LEVEL_DEGREES = 2.0
LEVEL_BOUNDARY = 180
#: a disk of more than ``LEVEL_SEARCH_FACTOR × LEVEL_SEARCH_VERTICES`` vertices seeks its level
#: turn on a copy decimated to ``LEVEL_SEARCH_VERTICES`` (:func:`level_corners`)
LEVEL_SEARCH_VERTICES = 4000
LEVEL_SEARCH_FACTOR = 3.0
#: after the copy's search, one more map on the disk itself where its eye line is further off
FINE_LEVEL_DEGREES = 1.0


def face_record(frame, stored):
    """The face found by looking (``frame.face``), for ``metrics.json`` and each set's
    ``meta.json``: its landmarks (68, else the detector's 4 key points) in the stored frame (x
    right, y up, z front); None when no face was found."""
    lm = None if frame is None else frame.face
    if lm is None or not lm.found:
        return None
    mesh = lm.source == "face mesh"
    P = lm.points if mesh else lm.keypoints
    r = lambda v: None if not np.isfinite(v) else round(float(v), 6)  # noqa: E731
    meta = {"source": lm.source, "confidence": round(float(lm.confidence), 4),
            "points": [[r(x) for x in p] for p in P @ stored.T],
            "names": "iBUG 68" if mesh else ["eye_right", "eye_left", "nose_tip", "mouth"]}
    return {"points": P, "meta": meta, "metrics": dict(lm.to_dict(points=False), points=meta["points"], names=meta["names"])}
