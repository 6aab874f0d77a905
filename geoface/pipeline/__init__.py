"""The whole conversion, mesh → geometry images → mesh, as one call (``geoface convert``).

Stages: repair to a disk → corners → Ricci flow (conformal, rectangle) → optimal-transport
measure-preserving map (or stay conformal) → geometry images → reconstruction → preview and
metrics.  ``augment = K`` repeats the parameterization for the first K of the 8 corner sets
(the paper's augmentation), writing one image set per corner set; each corner set's stages, from
the flow on, are :mod:`geoface.pipeline.corner_set`.

>>> convert(load_mesh("head.obj"), "out/", ConvertOptions(res=256))  # doctest: +SKIP
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..errors import GeofaceError, InvalidMeshError
from ..mesh.io import Mesh
from ..progress import log
from ..repair.proxy import NEEDLE_RATIO
from .corner_set import SetInputs, convert_set, corner_uvs_for, extend_split, reconstruction_error  # noqa: F401  (extend_split: public here too)
from .face import corners_key, face_record, level_corners
from ..rotations import upright_rotation  # noqa: F401  (re-exported)

__all__ = ["ConvertOptions", "convert", "face_region", "load_roi", "reconstruction_error", "corner_uvs_for", "upright_rotation"]

METHODS = ("ot", "conformal")
#: a scan with more than this many times ``ConvertOptions.proxy`` vertices goes through a proxy
PROXY_FACTOR = 1.5
#: with the default proxy size, only scans of more than this many vertices go through it (smaller
#: ones convert in seconds whole, as they did with the earlier 30,000-vertex default)
PROXY_ABOVE = 45000
#: default proxy size, chosen on validation scans (bench/bench_scale.py --proxies; docs/large_scans.md,
#: "The proxy's size"): against 30,000 the same mean distance to the scan within 10%, the maps
#: solved in half the time
DEFAULT_PROXY = 15000
#: a scan whose needle triangles' short edges (``ConvertOptions.needles``) would merge at least this
#: share of its vertices is parameterized through a proxy with them merged
NEEDLE_MIN_SHARE = 1e-3
#: default share of the conformal map's own area in OT's target measure (chosen on validation
#: heads: docs/benchmarks.md, "The target measure")
DEFAULT_BLEND = 0.1
#: default extra mass on sharp spots (γ of :func:`geoface.param.measure.sharpness`; chosen on
#: validation heads: docs/benchmarks.md, "Sharp spots")
DEFAULT_FEATURE = 4.0


@dataclass(frozen=True)
class ConvertOptions:
    """Options of :func:`convert` (the CLI flags of ``geoface convert``).

    res : image resolution N; roi : "face" (on a human head, the face region of the head
    template registered to it; otherwise a frontal cone, see :func:`face_region`),
    "none", or a per-input-vertex boolean mask; lam : mass factor on the ROI (2.5 in the
    paper; 1 = area-preserving); blend : share of the conformal map's own area in OT's
    target measure (:data:`DEFAULT_BLEND`; 0 = the paper's measure, see
    :mod:`geoface.param.measure`); feature : γ, sharp spots' (cone tips, a closed mouth's
    corners) masses times ``1 + γ`` (:data:`DEFAULT_FEATURE`; 0 = the paper's measure); augment : number of corner sets (1..8); method : "ot" or
    "conformal"; ot_tol : OT tolerance; smooth : Laplacian smoothing iterations of the
    reconstruction; up / open : how :func:`geoface.repair.make_disk` cuts closed heads, and
    which way is up in the image; ``up="auto"`` (default): found from the shape in any axis
    convention (:func:`geoface.repair.upright.upright_frame`; ``metrics.json`` keeps it under
    ``frame``, with whether it is certain), or an axis name / 3-vector;
    front : the face direction for the default corners and the face cone: ``"auto"``
    (default: from the centroid of the surface towards the centroid of an explicit ROI mask,
    e.g. the face mask of ``synth head --meta`` or of an ICT-FaceKit head; without a mask,
    where the mesh faces: the frame of ``up="auto"``, or :func:`geoface.mesh.frame.mesh_frame`
    about a given up), an axis name
    (``"z"``, ``"-x"``, ...) or a 3-vector;
    corner_set : convert only corner set ``k`` (0..7) of the 8, written directly in the
    output folder (used by the dataset builder: one item per mesh × corner set); ``augment``
    is then ignored; metrics : write ``metrics.json`` (it holds timings, so a folder without
    it is byte-identical across runs); proxy : a scan with more than 1.5 × ``proxy`` vertices (with the default,
    :data:`DEFAULT_PROXY` = 15,000: more than :data:`PROXY_ABOVE` = 45,000) is decimated to ``proxy`` vertices for the repair and the maps, and the
    images take positions, normals and colours from the full surface
    (:mod:`geoface.pipeline.proxy`); 0: never; needles : when edges shorter than ``needles``
    times the longest edge of their face (needle triangles: marching-cubes output, edges split
    next to their ends) would merge at least 0.1% of the vertices, the maps are solved on a proxy
    with those edges collapsed (:func:`geoface.repair.proxy.merge_needles`) and the images sample
    the full surface, as for a decimated proxy; 0: never; find_face : with ``up="auto"``, look for
    the face first (:func:`geoface.track.scan.scan_landmarks`): where one is found, up, front and
    the eye line are the face's, and its landmarks go into ``metrics.json`` and ``meta.json``
    (default True; False: the shape's cues alone); level : where a face was found, turn the
    corner sets along the boundary until its eye line is level in the default image (corner set
    0's final map; :func:`geoface.pipeline.corner_set.level_turn`: no more maps where it is within
    0.5° already, up to three more where not, found once per mesh in a process; default True).
    """

    res: int = 512
    roi: object = "face"
    lam: float = 2.5
    blend: float = DEFAULT_BLEND
    feature: float = DEFAULT_FEATURE
    augment: int = 1
    method: str = "ot"
    ot_tol: float = 1e-3
    smooth: int = 0
    up: str = "auto"
    open: str = "auto"
    front: object = "auto"
    reconstruct: bool = True
    preview: bool = True
    corner_set: int | None = None
    metrics: bool = True
    proxy: int = DEFAULT_PROXY
    needles: float = NEEDLE_RATIO
    find_face: bool = True
    level: bool = True

    def validate(self) -> "ConvertOptions":
        from ..gimage.raster import MAX_RES

        if int(self.res) != self.res or not 4 <= self.res <= MAX_RES:
            raise GeofaceError(f"res must be an integer in [4, {MAX_RES}]; got {self.res!r}")
        if self.method not in METHODS:
            raise GeofaceError(f"method must be one of {', '.join(METHODS)}; got {self.method!r}")
        if not (np.isfinite(self.lam) and self.lam > 0):
            raise GeofaceError(f"lam must be positive; got {self.lam!r}")
        if not (np.isfinite(self.blend) and 0 <= self.blend < 1):
            raise GeofaceError(f"blend must be in [0, 1); got {self.blend!r}")
        if isinstance(self.feature, bool) or not (isinstance(self.feature, (int, float)) and np.isfinite(self.feature)
                                                   and 0 <= self.feature <= 100):
            raise GeofaceError(f"feature must be a number in [0, 100]; got {self.feature!r}")
        if isinstance(self.proxy, bool) or int(self.proxy) != self.proxy or not (self.proxy == 0 or self.proxy >= 1000):
            raise GeofaceError(f"proxy must be 0 (off) or a vertex count >= 1000; got {self.proxy!r}")
        if not (isinstance(self.needles, (int, float)) and not isinstance(self.needles, bool)
                and (self.needles == 0 or 0 < self.needles < 0.5)):
            raise GeofaceError(f"needles must be 0 (off) or a ratio in (0, 0.5); got {self.needles!r}")
        if int(self.augment) != self.augment or not 1 <= self.augment <= 8:
            raise GeofaceError(f"augment must be an integer in 1..8; got {self.augment!r}")
        from ..gimage.reconstruct import MAX_SMOOTH

        if int(self.smooth) != self.smooth or not 0 <= self.smooth <= MAX_SMOOTH:
            raise GeofaceError(f"smooth must be an integer in 0..{MAX_SMOOTH}; got {self.smooth!r}")
        if not (0 < self.ot_tol < 1):
            raise GeofaceError(f"ot_tol must be in (0, 1); got {self.ot_tol!r}")
        if self.corner_set is not None and (int(self.corner_set) != self.corner_set or not 0 <= self.corner_set <= 7):
            raise GeofaceError(f"corner_set must be an integer in 0..7; got {self.corner_set!r}")
        if not (isinstance(self.front, str) and self.front == "auto"):
            from ..repair.opening import as_axis

            try:
                f = as_axis(self.front)
            except GeofaceError as e:
                raise GeofaceError(f"front must be 'auto', an axis name or a 3-vector; got {self.front!r}") from e
            if not (isinstance(self.up, str) and self.up == "auto"):
                try:
                    u = as_axis(self.up)
                except GeofaceError as e:
                    raise GeofaceError(f"up must be 'auto', an axis name or a 3-vector; got {self.up!r}") from e
                if abs(float(np.dot(u, f))) > np.cos(np.radians(5.0)):
                    raise GeofaceError(f"up {self.up!r} and front {self.front!r} are parallel: the front must be "
                                       "across the up axis")
        if isinstance(self.roi, str) and self.roi not in ("face", "none"):
            raise GeofaceError(f"roi must be 'face', 'none' or a vertex mask; got {self.roi!r}")
        return self


def face_region(V: np.ndarray, front=(0.0, 0.0, 1.0), half_angle: float = 50.0) -> np.ndarray:
    """A heuristic face mask for an upright head with no mask of its own: vertices within a
    cone of ``half_angle`` degrees around ``front`` seen from the bounding-box centre."""
    V = np.asarray(V, np.float64)
    f = np.asarray(front, np.float64)
    f = f / np.linalg.norm(f)
    d = V - 0.5 * (V.min(0) + V.max(0))
    L = np.linalg.norm(d, axis=1)
    return (d @ f) >= np.cos(np.radians(half_angle)) * np.maximum(L, 1e-300)


def load_roi(path: str | os.PathLike, n_vertices: int) -> np.ndarray:
    """A vertex mask from a file: ``.npy`` (bool mask or indices), ``.txt`` (indices, one per
    line or whitespace separated) or ``.json`` (a list of indices, or an object with
    ``face_mask``, as written by ``geoface synth head --meta``)."""
    p = Path(path)
    if not p.is_file():
        raise GeofaceError(f"ROI mask file not found: {p}")
    try:
        if p.suffix == ".npy":
            a = np.load(p, allow_pickle=False)
        elif p.suffix == ".json":
            obj = json.loads(p.read_text())
            a = np.asarray(obj["face_mask"] if isinstance(obj, dict) else obj)
        else:
            a = np.loadtxt(p, dtype=np.int64, ndmin=1)
    except (ValueError, KeyError, OSError, json.JSONDecodeError) as e:
        raise GeofaceError(f"cannot read the ROI mask {p}: {e}") from None
    if a.dtype == bool:
        if a.shape != (n_vertices,):
            raise GeofaceError(f"ROI mask {p} has {a.size} entries; the mesh has {n_vertices} vertices")
        return a
    a = np.asarray(a)
    if a.ndim != 1 or (a.size and (not np.issubdtype(a.dtype, np.integer) or a.min() < 0 or a.max() >= n_vertices)):
        raise GeofaceError(f"ROI mask {p} must hold vertex indices in [0, {n_vertices})")
    m = np.zeros(n_vertices, bool)
    m[a.astype(np.int64)] = True
    return m


def _axis(value, default) -> np.ndarray:
    from ..repair.opening import as_axis

    return np.asarray(default, float) if isinstance(value, str) and value == "auto" else as_axis(value)


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in np.asarray(v, float)) + ")"


def _front(opts: ConvertOptions, V: np.ndarray, F: np.ndarray, roi, up: np.ndarray, seen=None) -> np.ndarray:
    """The face direction: given, or (``"auto"``) from the surface's area centroid towards
    the centroid of an explicit ROI mask, made orthogonal to ``up``; without a mask, where the
    surface faces (``seen``: the frame found with ``--up auto``, or
    :func:`geoface.mesh.frame.mesh_frame` about the given up), +Z failing that."""
    if not (isinstance(opts.front, str) and opts.front == "auto"):
        return _axis(opts.front, (0.0, 0.0, 1.0))
    if roi is None or isinstance(opts.roi, str) or not roi.any() or roi.all():
        if seen is None:
            from ..mesh.frame import mesh_frame

            try:
                seen = mesh_frame(V, F, up=up).front
            except GeofaceError:
                return np.array([0.0, 0.0, 1.0])
        d = np.asarray(seen, np.float64) - (np.asarray(seen, np.float64) @ up) * up
        L = np.linalg.norm(d)
        return d / L if L > 1e-6 else np.array([0.0, 0.0, 1.0])
    from ..mesh.core import vertex_areas

    a = vertex_areas(V, F)
    d = (a[roi, None] * V[roi]).sum(0) / a[roi].sum() - (a[:, None] * V).sum(0) / a.sum()
    d = d - (d @ up) * up
    L = np.linalg.norm(d)
    return d / L if L > 0 else np.array([0.0, 0.0, 1.0])


def _roi_onto(roi0, V_scan: np.ndarray, V_proxy: np.ndarray):
    """The user's mask on a proxy: each proxy vertex takes its nearest scan vertex's."""
    if roi0 is None:
        return None
    from scipy.spatial import cKDTree

    return roi0[cKDTree(V_scan).query(V_proxy)[1]]


def _scan_faces(px, disk, F_scan: np.ndarray) -> np.ndarray:
    """The scan faces a needle proxy's disk stands for: those whose proxy face is in the disk,
    and those that collapsed (the needles) onto proxy vertices that all are in the disk."""
    in_disk = np.zeros(len(px.F), bool)
    in_disk[disk.face_map[disk.face_map >= 0]] = True
    v_in = np.zeros(len(px.V) + 1, bool)  # the last entry: "no proxy vertex" (-1)
    v_in[disk.vertex_map[disk.vertex_map >= 0]] = True
    f = px.face_of
    keep = np.where(f >= 0, in_disk[f], v_in[px.vertex_of[F_scan]].all(1))
    return np.flatnonzero(keep)


def _explicit_roi(opts: ConvertOptions, V0: np.ndarray) -> np.ndarray | None:
    """A vertex mask given by the user (over the input's vertices), checked; None otherwise."""
    if isinstance(opts.roi, str):
        return None
    m = np.asarray(opts.roi)
    if m.shape != (len(V0),) or m.dtype != bool:
        raise GeofaceError(f"roi mask must be a ({len(V0)},) bool array over the input's vertices")
    return m


def convert(mesh: Mesh, out_dir: str | os.PathLike, options: ConvertOptions | None = None, *, quiet: bool | None = None,
            overwrite: bool = True) -> dict:
    """Convert ``mesh`` into geometry images in ``out_dir`` (see module docs).

    Writes (per corner set ``k``; directly in ``out_dir`` when ``augment == 1``, else in
    ``out_dir/aug{k}``): ``position.png``, ``normal.png``, ``texture.png``, ``mask.png``,
    ``roi.png`` (8-bit, 255 on the ROI's pixels; with an ROI), ``meta.json``, ``reconstruction.obj`` (+ ``.mtl``, texture, normal map) and
    ``preview.png``; and ``metrics.json`` in ``out_dir``.  The folder appears complete or
    not at all (files 0644 and folders 0755 under umask 022); an existing ``out_dir`` is
    replaced only with ``overwrite`` (the CLI's ``--force``).  Returns the metrics dict.
    """
    from ..mesh.core import check_mesh, checked_meshes

    opts = (options or ConvertOptions()).validate()
    if not isinstance(mesh, Mesh):
        raise InvalidMeshError("convert needs a geoface.mesh.Mesh")
    check_mesh(mesh.V, mesh.F)  # once, here: every step below works on meshes derived from it
    with checked_meshes():
        return _convert(mesh, out_dir, opts, quiet=quiet, overwrite=overwrite)


def proxy_threshold(proxy: int) -> float:
    """How many vertices a scan must exceed to be solved on a ``proxy``-vertex proxy:
    :data:`PROXY_FACTOR` × ``proxy``, and :data:`PROXY_ABOVE` with the default size."""
    return PROXY_ABOVE if proxy == DEFAULT_PROXY else PROXY_FACTOR * proxy


def _convert(mesh: Mesh, out_dir, opts: ConvertOptions, *, quiet, overwrite) -> dict:
    from ..param.corners import corner_sets
    from ..param.ricci import RicciFlowSolver
    from ..repair import make_disk

    out_dir = Path(out_dir)
    times: dict = {}
    t_all = time.perf_counter()
    roi0 = _explicit_roi(opts, mesh.V)

    scan, proxy_kind, needle_px = None, None, None
    if opts.proxy and len(mesh.V) > proxy_threshold(opts.proxy):
        from ..repair.proxy import decimate

        t = time.perf_counter()
        log(f"convert: {len(mesh.V):,} vertices: the maps are solved on a {opts.proxy:,}-vertex proxy, the images sample "
            "the full surface", quiet=quiet)
        px = decimate(mesh.V, mesh.F, opts.proxy)
        scan, proxy_kind = mesh, "decimated"
        roi0 = _roi_onto(roi0, mesh.V, px.V)
        mesh = Mesh(px.V, px.F)
        times["proxy"] = time.perf_counter() - t
    elif opts.needles and len(mesh.F):
        from ..repair.proxy import merge_needles

        px = merge_needles(mesh.V, mesh.F, opts.needles)
        if px is not None and px.merged >= NEEDLE_MIN_SHARE * len(mesh.V):
            log(f"convert: needle triangles: the maps are solved with their short edges collapsed ({px.merged:,} of "
                f"{len(mesh.V):,} vertices merged), the images sample the full surface", quiet=quiet)
            scan, proxy_kind = mesh, "needles merged"
            roi0 = _roi_onto(roi0, mesh.V, px.V)
            mesh = Mesh(px.V, px.F)
            times["proxy"] = px.seconds
            needle_px = px

    t = time.perf_counter()
    log(f"convert: repairing {len(mesh.V)} vertices to a disk", quiet=quiet)
    disk = make_disk(mesh.V, mesh.F, up=opts.up, open=opts.open, find_face=bool(opts.find_face), quiet=quiet)
    dm = mesh.with_geometry(disk.V, disk.F, disk.vertex_map, disk.face_map)
    V = dm.V
    colors = dm.colors
    frame = disk.frame
    roi = None
    if roi0 is not None:
        roi = np.zeros(len(V), bool)
        ok = disk.vertex_map >= 0
        roi[ok] = roi0[disk.vertex_map[ok]]
    times["repair"] = time.perf_counter() - t

    t = time.perf_counter()
    up_vec = frame.up if frame is not None else _axis(opts.up, (0.0, 1.0, 0.0))
    if frame is not None and not frame.certain:
        log(f"convert: which way is up is uncertain ({frame.why}); taking up {_vec(frame.up)}, front {_vec(frame.front)}; "
            "pass --up (and --front) to set them", quiet=quiet)
    front = _front(opts, V, dm.F, roi, up_vec, frame.front if frame is not None else None)
    if roi is None and isinstance(opts.roi, str) and opts.roi == "face":
        roi = None
        if frame is not None and frame.template is not None:  # a human head: the template's face
            from ..repair.upright import template_face_region

            roi = template_face_region(V, frame)
        if roi is None or not roi.any():
            roi = face_region(V, front)
    indices = [opts.corner_set] if opts.corner_set is not None else list(range(opts.augment))
    face = face_record(frame, upright_rotation(up_vec, front))
    solver = RicciFlowSolver(V, dm.F)
    turn, mapped = 0.0, {}
    if face is not None and opts.level:
        # the corner sets turned along the boundary until the face's eye line is level in set 0
        turn, mapped = level_corners(solver, V, roi, colors, face, front, up_vec, opts, quiet)
    all_sets = corner_sets(solver.V, solver.F, n=8, front=front, up=up_vec, count=max(indices) + 1, turn=turn)
    sets = [all_sets[i] for i in indices]
    times["corners"] = time.perf_counter() - t
    full = None
    if scan is not None:
        from .proxy import full_surface

        t = time.perf_counter()
        full = full_surface(scan, V, dm.F, roi, fill=disk.face_map < 0,
                            faces=None if needle_px is None else _scan_faces(needle_px, disk, scan.F))
        times["full_surface"] = time.perf_counter() - t
        if full is None:
            log("convert: no part of the scan lies on the repaired proxy; the images keep the proxy's positions", quiet=quiet)

    metrics: dict = {
        "input_vertices": int(len(mesh.V)), "input_faces": int(len(mesh.F)), "up": [float(x) for x in up_vec],
        "disk_vertices": int(len(V)), "disk_faces": int(len(dm.F)),
        "repair": {"area_before": disk.area_before, "area_after": disk.area_after, "changes": len(disk.changes)},
        "options": {k: (v if not isinstance(v, np.ndarray) else "mask") for k, v in asdict(opts).items()},
        "roi_vertices": int(roi.sum()) if roi is not None else 0,
        "front": [float(x) for x in front],
        "frame": None if frame is None else frame.to_dict(),
        "sets": [],
    }
    if scan is not None:
        metrics["proxy"] = {"kind": proxy_kind, "scan_vertices": int(len(scan.V)), "scan_faces": int(len(scan.F)), "proxy_vertices": int(len(mesh.V)),
                            "seconds": times["proxy"], "full_surface_seconds": times["full_surface"],
                            "full_faces": 0 if full is None else int(len(full.F)),
                            "snap_tolerance": None if full is None else full.tol / full.diag}
    from .._io import atomic_dir

    stored = upright_rotation(up_vec, front)
    if face is not None:
        metrics["face"] = face["metrics"]
    with atomic_dir(out_dir, overwrite=overwrite) as tmp_root:
        failures: list = []
        inputs = SetInputs(solver, V, roi, colors, opts, quiet, disk=dm, stored=stored, full=full, face=face)
        for pos, (k, corners) in enumerate(zip(indices, sets)):
            st: dict = {"corner_set": k, "corners": [int(c) for c in corners]}
            folder = tmp_root if len(sets) == 1 else tmp_root / f"aug{k}"
            folder.mkdir(exist_ok=True)
            try:
                convert_set(st, folder, corners, inputs, pos, len(sets), mapped=mapped.pop(corners_key(corners), None))
            except GeofaceError as e:
                if len(sets) == 1:
                    raise
                # one failing corner set is recorded and skipped; the others stand
                shutil.rmtree(folder, ignore_errors=True)
                failures.append({"corner_set": k, "error": str(e)})
                log(f"convert [{pos + 1}/{len(sets)}]: corner set {k} failed and is skipped: {e}", quiet=quiet)
                continue
            metrics["sets"].append(st)
        if not metrics["sets"]:
            raise GeofaceError(f"every corner set failed; the first: {failures[0]['error']}")
        metrics["failed_sets"] = failures
        metrics["seconds"] = {"repair": times["repair"], "corners": times["corners"], "total": time.perf_counter() - t_all}
        for k in ("proxy", "full_surface"):
            if k in times:
                metrics["seconds"][k] = times[k]
        if opts.metrics:
            (tmp_root / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics


