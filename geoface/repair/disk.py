"""``make_disk``: any triangle mesh to a topological disk, reporting every change.

A topological disk here means: one component, manifold, consistently oriented, genus 0,
exactly one boundary loop, and no degenerate faces.  That is what every later stage of
geoface (Ricci flow, optimal transport, geometry images) consumes.

>>> from geoface.synth import torus
>>> V, F = torus(1.0, 0.3, 32, 12)
>>> res = make_disk(V, F, up="z")
>>> res.report.is_disk
True
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ..errors import InvalidMeshError, MeshTopologyError
from ..mesh.core import boundary_loops, check_mesh, checked_meshes, face_areas
from ..mesh.frame import axis_text
from ..mesh.topology import TopologyReport, topology_report
from ..progress import log
from ..tol import tol
from .clean import clean
from .components import keep_components
from .handles import remove_handles
from .holes import fill_holes
from .opening import as_axis, open_at_plane, open_with_cap
from .remesh import remesh
from .step import StepResult

OpenMode = Literal["auto", "plane", "cap", "none"]
OPEN_MODES = ("auto", "plane", "cap", "none")
#: pieces of a scan smaller than this fraction of its area are debris to the frame of a standing figure
WHOLE_AREA_FRACTION = 0.01


@dataclass(frozen=True)
class RepairOptions:
    """Options of :func:`make_disk` (all have sensible defaults).

    Attributes
    ----------
    open : "auto" | "plane" | "cap" | "none"
        How to give a closed surface its boundary.  ``auto`` (default) cuts a closed
        surface at a plane near its bottom along ``up`` (the neck of an upright head) and
        keeps the longest existing boundary of an open one; ``plane``/``cap`` always cut
        (existing holes are all filled first, the cut becomes the boundary); ``none``
        never cuts (a closed input is then an error).  With ``auto``, an open surface
        whose longest boundary is shorter than ``min_opening`` × √area or has fewer than 8
        vertices (a closed scan with only small holes), or whose frame (``up="auto"``) is that of
        a closed head whose longest boundary is not the neck, is treated as closed: an opening
        that small would squeeze the whole surface into a point of the map.  A plane cut
        that leaves such an opening is raised (height doubled, up to 0.32) while the kept
        part still holds 90% of the area.
    min_opening : float
        See ``open`` (default 0.1; the real heads and scans we test have 0.9 to 3.7, the
        hoof cut of the closed cow 0.23).
    up : "auto" | "x" | "y" | "z" | "-x" | ... | 3-vector
        Up axis of the model: ``"auto"`` (default) finds it from the shape
        (:func:`geoface.repair.upright.upright_frame`: a human head by the head template in any
        axis convention, else the opening, a flat cut, the plane it stands on), or an axis.
    open_height : float
        Plane position as a fraction of the extent along ``up`` from the bottom (0.02).
    plane_origin : 3-vector or None
        A point on the cutting plane; overrides ``open_height``.
    cap_area : float
        Area fraction removed by ``open="cap"`` (0.02).
    merge_tolerance : float or None
        Vertex merge distance relative to the bbox diagonal (default ``tol.merge``).
    min_component_area : float or None
        Drop components below this fraction of the total area before keeping the largest.
    target_vertices : int or None
        Remesh to about this many vertices (after cleaning, before topology surgery).
    remesh_method : "isotropic" | "decimate"
    keep_boundary : "longest" | int
        Which existing boundary loop stays open: the longest, or the one through a vertex.
    refine_holes, fair_holes : bool
        Refine hole patches to the surrounding edge length; fair them (bi-Laplacian).
    max_handles : int
        Refuse meshes with more handles than this (default 100).
    find_face : bool
        With ``up="auto"``, look for the face first (renders of the surface and the face tracker:
        :func:`geoface.track.scan.scan_landmarks`; about a second); its frame decides where one is
        found.  False: the shape's cues alone.
    seed : int
        Seed for the roots tried when searching short handle loops.
    """

    open: OpenMode = "auto"
    up: object = "auto"
    open_height: float = 0.02
    plane_origin: object = None
    cap_area: float = 0.02
    merge_tolerance: float | None = None
    min_component_area: float | None = None
    target_vertices: int | None = None
    remesh_method: str = "isotropic"
    keep_boundary: object = "longest"
    min_opening: float = 0.1
    refine_holes: bool = True
    fair_holes: bool = True
    max_handles: int = 100
    seed: int = 0
    find_face: bool = True

    def validate(self) -> "RepairOptions":
        if self.open not in OPEN_MODES:
            raise InvalidMeshError(f"open must be one of {', '.join(OPEN_MODES)}; got {self.open!r}")
        if not (isinstance(self.up, str) and self.up == "auto"):
            as_axis(self.up)
        if self.target_vertices is not None and (int(self.target_vertices) != self.target_vertices or self.target_vertices < 16):
            raise InvalidMeshError(f"target_vertices must be an integer >= 16; got {self.target_vertices!r}")
        if not (0 < self.open_height < 1):
            raise InvalidMeshError(f"open_height must be in (0, 1); got {self.open_height!r}")
        if not (np.isfinite(self.min_opening) and self.min_opening >= 0):
            raise InvalidMeshError(f"min_opening must be a non-negative number; got {self.min_opening!r}")
        return self


@dataclass(frozen=True)
class DiskResult:
    """Result of :func:`make_disk`.

    Attributes
    ----------
    V : (n, 3) float64, F : (m, 3) int64 — the disk
    vertex_map : (n,) int64 — input vertex of each output vertex, -1 if created by repair
    face_map : (m,) int64 — input face of each output face, -1 if created
    report : TopologyReport of the output
    changes : list of dict — every change made, in order
    area_before, area_after : float — surface areas of input and output
    seconds : float — wall time
    frame : the up / front found with ``up="auto"`` (:class:`geoface.repair.upright.UprightFrame`),
        None when ``up`` was given
    """

    V: np.ndarray
    F: np.ndarray
    vertex_map: np.ndarray
    face_map: np.ndarray
    report: TopologyReport
    changes: list = field(default_factory=list)
    area_before: float = 0.0
    area_after: float = 0.0
    seconds: float = 0.0
    frame: object = None

    @property
    def area_added(self) -> float:
        return float(sum(c.get("area_added", 0.0) for c in self.changes))

    @property
    def area_removed(self) -> float:
        return float(sum(c.get("area_removed", 0.0) for c in self.changes))

    def to_dict(self) -> dict:
        return {
            "report": self.report.to_dict(),
            "changes": self.changes,
            "area_before": self.area_before,
            "area_after": self.area_after,
            "area_added": self.area_added,
            "area_removed": self.area_removed,
            "seconds": self.seconds,
            "frame": None if self.frame is None else self.frame.to_dict(),
        }

    def summary(self) -> str:
        """Human-readable list of changes."""
        lines = []
        for c in self.changes:
            rest = ", ".join(f"{k}={_fmt(v)}" for k, v in c.items() if k != "step")
            lines.append(f"  {c['step']:<28} {rest}")
        if not lines:
            lines.append("  (no changes: the input already was a clean disk)")
        lines.append(
            f"area {self.area_before:.6g} -> {self.area_after:.6g} (added {self.area_added:.4g}, removed {self.area_removed:.4g}); "
            f"{len(self.V)} vertices, {len(self.F)} faces; {self.seconds:.2f} s"
        )
        return "\n".join(lines)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def _disk_problems(rep: TopologyReport) -> list[str]:
    probs = []
    if rep.components != 1:
        probs.append(f"{rep.components} components")
    if not rep.manifold:
        probs.append(f"non-manifold ({rep.nonmanifold_edges} edges, {rep.nonmanifold_vertices} vertices)")
    if not rep.consistently_oriented:
        probs.append("inconsistent orientation")
    if rep.genus not in (0, None) or (rep.genus is None and rep.manifold):
        probs.append(f"genus {rep.genus}")
    if rep.boundary_loops != 1:
        probs.append(f"{rep.boundary_loops} boundary loops")
    if rep.degenerate_faces:
        probs.append(f"{rep.degenerate_faces} degenerate faces")
    return probs


def make_disk(V, F, options: RepairOptions | None = None, *, quiet: bool | None = None, **overrides) -> DiskResult:
    """Turn a triangle mesh into a topological disk.

    Steps: clean (merge, degenerate/duplicate faces, non-manifold splits, orientation)
    → keep the largest component → optional remesh → fill every hole but the kept
    boundary → remove handles → open a closed surface (plane or cap) → clean up the cut
    (largest part, fill extra loops) → verify.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    options : RepairOptions, optional; keyword overrides of its fields are accepted too
    quiet : bool, optional
        silence the progress lines (default: the global switch, ``geoface --quiet``)

    Returns
    -------
    DiskResult

    Raises
    ------
    InvalidMeshError
        Malformed arrays (NaN, bad indices, empty).
    MeshTopologyError
        A disk cannot be made (e.g. a closed surface with ``open="none"``), with the reason.
    """
    t0 = time.perf_counter()
    opts = replace(options or RepairOptions(), **overrides).validate()
    V, F = check_mesh(V, F)
    with checked_meshes():  # every later step works on meshes derived from this one
        return _make_disk(V, F, opts, t0, quiet)


def _make_disk(V, F, opts, t0, quiet):
    area_before = float(face_areas(V, F).sum())

    log(f"make_disk: {len(V)} vertices, {len(F)} faces; cleaning", quiet=quiet, detail=True)
    res = clean(V, F, merge_tolerance=opts.merge_tolerance)
    cleaned = res
    res = res.then(keep_components(res.V, res.F, min_area_fraction=opts.min_component_area))
    _strict(res, "clean")
    if opts.target_vertices is not None:
        log(f"remeshing to ~{opts.target_vertices} vertices", quiet=quiet, detail=True)
        res = res.then(remesh(res.V, res.F, int(opts.target_vertices), method=opts.remesh_method))
        res = res.then(clean(res.V, res.F))
        res = res.then(keep_components(res.V, res.F))
    frame = None
    if isinstance(opts.up, str) and opts.up == "auto":
        from .upright import upright_frame

        pieces = keep_components(cleaned.V, cleaned.F, min_area_fraction=WHOLE_AREA_FRACTION, largest_only=False)
        frame = upright_frame(res.V, res.F, whole=(pieces.V, pieces.F), look=bool(opts.find_face))
        opts = replace(opts, up=frame.up)
        # an uncertain frame is said whatever the verbosity (the user should check it)
        log(f"make_disk: up {axis_text(frame.up)}, front {axis_text(frame.front)} ({frame.kind}; {frame.how})"
            + ("" if frame.certain else f"; UNCERTAIN: {frame.why}"), quiet=quiet, detail=frame.certain)
    loops = boundary_loops(res.F)
    closed = len(loops) == 0
    if loops and opts.open == "auto" and opts.keep_boundary == "longest" and frame is not None and frame.kind == "closed":
        log("make_disk: a closed head with holes (its longest boundary is not the neck): filling every hole and "
            "cutting it open at the neck", quiet=quiet, detail=True)
        closed = True
    elif loops and opts.open == "auto" and opts.keep_boundary == "longest" and _small_opening(res.V, res.F, opts.min_opening):
        log("make_disk: the longest boundary is a small hole (shorter than "
            f"{opts.min_opening:g} sqrt(area), or under {MIN_OPENING_VERTICES} vertices): filling every hole and "
            "cutting the surface open like a closed one", quiet=quiet, detail=True)
        closed = True
    if closed and opts.open == "none":
        raise MeshTopologyError("the mesh is closed (no boundary) and open='none'; use open='auto', 'plane' or 'cap'")
    cut = opts.open in ("plane", "cap") or (opts.open == "auto" and closed)
    if loops:
        # an explicit cut makes the new boundary: then every existing hole is closed
        keep = "none" if cut else opts.keep_boundary
        log(f"make_disk: {len(loops)} boundary loops; filling {'all' if cut else 'all but the kept one'}", quiet=quiet, detail=True)
        res = res.then(fill_holes(res.V, res.F, keep=keep, refine=opts.refine_holes, fairing=opts.fair_holes))
    log("make_disk: removing handles", quiet=quiet, detail=True)
    res = res.then(remove_handles(res.V, res.F, max_handles=opts.max_handles, seed=opts.seed))
    _strict(res, "handles")
    if cut:
        log(f"make_disk: opening the surface ({'cap' if opts.open == 'cap' else 'plane'})", quiet=quiet, detail=True)
        closed_res = res
        area_closed = float(face_areas(res.V, res.F).sum())
        # with open="auto" a plane cut that leaves too small an opening is raised (doubled)
        # while the part kept still holds 90% of the area
        heights = [opts.open_height]
        if opts.open == "auto" and opts.plane_origin is None:
            heights += [h for h in (0.04, 0.08, 0.16, 0.32) if h > opts.open_height]
        for i, height in enumerate(heights):
            trial = closed_res
            if opts.open == "cap":
                trial = trial.then(open_with_cap(trial.V, trial.F, up=opts.up, area_fraction=opts.cap_area))
            else:
                trial = trial.then(open_at_plane(trial.V, trial.F, up=opts.up, height=height, origin=opts.plane_origin))
            trial = trial.then(clean(trial.V, trial.F))
            trial = trial.then(keep_components(trial.V, trial.F))
            trial = trial.then(fill_holes(trial.V, trial.F, keep="longest", refine=opts.refine_holes, fairing=opts.fair_holes))
            # a cut can in rare cases leave pinches that cleaning turns into handles
            trial = trial.then(remove_handles(trial.V, trial.F, max_handles=opts.max_handles, seed=opts.seed))
            if i and float(face_areas(trial.V, trial.F).sum()) < 0.9 * area_closed:
                break  # raising the cut would cut parts off: keep the last opening
            res = trial
            if not _small_opening(res.V, res.F, opts.min_opening):
                break
            if i + 1 < len(heights):
                log(f"make_disk: the opening at height {height:g} is small; cutting higher", quiet=quiet, detail=True)
    res = res.then(clean(res.V, res.F))
    rep = topology_report(res.V, res.F)
    problems = _disk_problems(rep)
    if problems:
        raise MeshTopologyError("could not make a disk: " + "; ".join(problems))
    return DiskResult(
        V=res.V,
        F=res.F,
        vertex_map=res.vertex_map,
        face_map=res.face_map,
        report=rep,
        changes=res.changes,
        area_before=area_before,
        area_after=float(rep.surface_area),
        seconds=time.perf_counter() - t0,
        frame=frame,
    )




#: an opening needs at least this many boundary vertices (four corners, eight corner sets)
MIN_OPENING_VERTICES = 8


def _small_opening(V: np.ndarray, F: np.ndarray, min_opening: float) -> bool:
    """Whether the longest boundary loop is too small to be the disk's opening."""
    loops = boundary_loops(F)
    if not loops:
        return False
    lengths = [float(np.linalg.norm(V[np.roll(lp, -1)] - V[lp], axis=1).sum()) for lp in loops]
    k = int(np.argmax(lengths))
    return len(loops[k]) < MIN_OPENING_VERTICES or lengths[k] < min_opening * float(np.sqrt(face_areas(V, F).sum()))


def _strict(res: StepResult, stage: str) -> None:
    """In strict mode, check the intermediate mesh is an oriented manifold."""
    if not tol.strict:
        return
    rep = topology_report(res.V, res.F)
    if not (rep.manifold and rep.consistently_oriented):
        raise MeshTopologyError(f"strict: after {stage} the mesh is not an oriented manifold: {rep.to_dict()}")


__all__ = ["DiskResult", "OPEN_MODES", "RepairOptions", "make_disk"]
