"""Build a geometry-image dataset from a folder of meshes, on a process pool or a Dask cluster.

One **item** per mesh × corner set (the paper's augmentation: ``augment = K`` takes the first
K of the 8 corner sets).  Item ``k`` of ``head_007.obj`` is written to
``OUT_DIR/head_007/aug{k}/`` (``position.png``, ``normal.png``, ``texture.png``, ``mask.png``,
``meta.json``, ``preview.png``; ``reconstruction.obj`` with ``reconstruct=True``) by
:func:`geoface.pipeline.convert`, atomically: a folder is complete or absent.

``OUT_DIR/manifest.jsonl`` gets one line per item processed, written by the driver only:
``item``, ``mesh``, ``corner_set``, ``status`` (``ok`` / ``failed``), ``error``, ``seconds``,
``metrics`` (distortion, OT iterations, coverage, face pixel share, reconstruction error) and,
when labels are given, ``labels`` and ``prompt``.  The last line of an item wins; a rebuild with
other options or another source (``rebuild``, ``--force``) starts the manifest afresh.

* A failing mesh (corrupt file, impossible topology, a solver failure) is logged and recorded
  as ``failed``; the run goes on.
* Resumable: an item whose last status is ``ok`` and whose folder is complete is skipped; so
  is one that failed before (``retry_failed=True`` tries those again).  A second run over the
  same input does no work.
* Deterministic: each item runs with single-threaded BLAS, so its files are byte-identical
  whichever scheduler or worker count produced them (``meta.json`` holds no timings).

Schedulers: ``workers=1`` runs in this process; ``workers=N`` a local process pool;
``scheduler="tcp://host:8786"`` a Dask distributed cluster (:mod:`geoface.dataset.workers`).
The input meshes, their labels and the manifest are read by :mod:`geoface.dataset.files`.

>>> build_dataset("meshes/", "dataset/", DatasetOptions(res=128, augment=8), workers=2)  # doctest: +SKIP
"""

from __future__ import annotations

import json
import os
import time
import traceback
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from ..errors import GeofaceError
from ..progress import log
from .files import MANIFEST, MESH_SUFFIXES, find_meshes, load_labels, read_manifest
from .workers import die_with_parent, executor

__all__ = ["DatasetOptions", "build_dataset", "build_ict_dataset", "find_meshes", "load_labels", "read_manifest", "MESH_SUFFIXES",
           "die_with_parent"]

#: files that make an item folder complete (``texture.png`` only where the mesh has colours or a texture)
ITEM_FILES = ("position.png", "normal.png", "mask.png", "meta.json")


@dataclass(frozen=True)
class DatasetOptions:
    """Options of :func:`build_dataset` (the flags of ``geoface dataset build``).

    res : image resolution N (default 512); augment : corner sets per mesh, 1..8 (default 8);
    roi : ``"auto"`` (the face mask in ``<stem>.json`` beside the mesh, as written by
    ``geoface synth head --meta`` or ``data_tools/make_synthetic_heads.py``, else the frontal
    face cone), ``"face"`` (always the cone) or ``"none"``; lam : mass factor on the ROI (2.5);
    blend : share of the conformal map's area in OT's target measure (0.1, as ``convert``);
    feature : extra mass on sharp spots (4, as ``convert``);
    method : ``"ot"`` or ``"conformal"``; ot_tol : OT tolerance; reconstruct : also write
    ``reconstruction.obj`` and its error; preview : write ``preview.png``; up / open : how
    closed meshes are cut open (see :func:`geoface.repair.make_disk`); find_face : with
    ``up="auto"``, look for each mesh's face (as ``convert``: its frame, the eye line levelled);
    False: the shape's cues alone (meshes that are not human heads, at about 2 s less each).
    """

    res: int = 512
    augment: int = 8
    roi: str = "auto"
    lam: float = 2.5
    blend: float = 0.1
    feature: float = 4.0
    method: str = "ot"
    ot_tol: float = 1e-3
    reconstruct: bool = False
    preview: bool = True
    up: str = "auto"
    open: str = "auto"
    find_face: bool = True

    def validate(self) -> "DatasetOptions":
        if self.roi not in ("auto", "face", "none"):
            raise GeofaceError(f"roi must be one of auto, face, none; got {self.roi!r}")
        self.convert_options(0, None)  # the rest is checked by ConvertOptions
        return self

    def convert_options(self, corner_set: int, roi):
        from ..pipeline import ConvertOptions

        return ConvertOptions(
            res=self.res, roi="none" if roi is None else roi, lam=self.lam, blend=self.blend, feature=self.feature, augment=self.augment,
            method=self.method, ot_tol=self.ot_tol, reconstruct=self.reconstruct, preview=self.preview,
            up=self.up, open=self.open, corner_set=corner_set, metrics=False, find_face=self.find_face,
        ).validate()


def _complete(folder: Path) -> bool:
    return all((folder / f).is_file() for f in ITEM_FILES)


def _item_roi(mesh_path: Path, n_vertices: int, roi: str):
    if roi == "none":
        return None
    if roi == "auto":
        side = mesh_path.with_suffix(".json")
        if side.is_file():
            from ..pipeline import load_roi

            return load_roi(side, n_vertices)
    return "face"


def _summary_metrics(m: dict) -> dict:
    st = m["sets"][0]
    out = {
        "disk_vertices": m["disk_vertices"], "roi_vertices": m["roi_vertices"], "coverage": st["coverage"],
        "distortion": st["distortion"], "ricci_iterations": st["ricci"]["iterations"], "aspect": st["ricci"]["aspect"],
    }
    if "roi_pixel_share" in st:
        out["roi_pixel_share"] = st["roi_pixel_share"]
    if "ot" in st:
        out["ot_iterations"] = st["ot"]["iterations"]
        out["ot_residual"] = st["ot"]["residual"]
        out["flipped_before_untangle"] = st["ot"]["flipped_before"]
    if "reconstruction" in st:
        out["reconstruction"] = {k: v for k, v in st["reconstruction"].items() if k != "seconds"}
    return out


def _item_mesh(source, roi: str):
    """The mesh and region of interest of one item's source: a mesh file (its face mask from
    ``<stem>.json`` beside it) or an ICT-FaceKit head spec (:func:`geoface.synth.ict_data.ict_specs`)."""
    if isinstance(source, dict):
        from ..synth.ict_data import head_from_spec

        head = head_from_spec(source)
        return head.mesh(), (None if roi == "none" else ("face" if roi == "face" else head.face_mask))
    from ..mesh.io import load_mesh

    mesh = load_mesh(source)
    return mesh, _item_roi(Path(source), len(mesh.V), roi)


def run_item(source, out_folder: str, corner_set: int, options: DatasetOptions) -> dict:
    """Convert one source (a mesh path, or an ICT head spec dict) × corner set into
    ``out_folder``; never raises: returns a status dict (with the item's ``bbox``, the
    mesh-unit box its position image is normalised to).

    Runs with single-threaded BLAS so the output does not depend on the worker it ran on.
    """
    t0 = time.perf_counter()
    row: dict = {"status": "ok", "error": None}
    try:
        from .._lazy import lazy_import

        threadpool_limits = lazy_import("threadpoolctl", "dataset building").threadpool_limits
        from ..pipeline import convert

        with threadpool_limits(limits=1):
            mesh, roi = _item_mesh(source, options.roi)
            m = convert(mesh, out_folder, options.convert_options(corner_set, roi), quiet=True)
        row["metrics"] = _summary_metrics(m)
        meta = json.loads((Path(out_folder) / "meta.json").read_text())
        row["bbox"] = {"min": meta["bbox_min"], "max": meta["bbox_max"]}
    except GeofaceError as e:
        row.update(status="failed", error=f"{type(e).__name__}: {e}")
    except OSError as e:
        import errno

        row.update(status="failed", error=f"{type(e).__name__}: {e.strerror or e}")
        if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO):
            row["machine"] = True  # the machine, not the item: the whole build stops
    except Exception as e:  # a bug or an unexpected library error: record it, keep going
        tb = traceback.format_exception_only(type(e), e)[-1].strip()
        row.update(status="failed", error=f"unexpected {tb}")
    row["seconds"] = time.perf_counter() - t0
    return row


def _plan(sources, out_dir: Path, options: DatasetOptions, done: dict, retry_failed: bool):
    """``sources``: ``(stem, source)`` pairs; returns the items to build and those to skip."""
    todo, skipped = [], []
    for stem, src in sources:
        for k in range(options.augment):
            item = f"{stem}/aug{k}"
            prev = done.get(item)
            folder = out_dir / stem / f"aug{k}"
            if prev is not None and prev.get("status") == "ok" and _complete(folder):
                skipped.append(item)
            elif prev is not None and prev.get("status") == "failed" and not retry_failed:
                skipped.append(item)
            else:
                todo.append((item, stem, src, k, folder))
    return todo, skipped


OPTIONS_FILE = "options.json"


def _record_options(out: Path, opts: DatasetOptions, rebuild: bool, source: dict | None = None) -> bool:
    """Check ``out``'s recorded options against ``opts`` (all but ``augment``, which only adds
    or drops items) and ``source`` (what the items are made from, for generated datasets);
    record them.  Returns True when everything must be built again."""
    from .._io import atomic_write_text

    cur = {k: v for k, v in asdict(opts).items() if k != "augment"}
    if source is not None:
        cur["source"] = source
    path = out / OPTIONS_FILE
    changed = False
    if path.is_file():
        try:
            old = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError, OSError) as e:
            raise GeofaceError(f"{path} is not readable JSON ({e}); pass --force to rebuild the dataset") from None
        if not isinstance(old, dict):
            raise GeofaceError(f"{path} is not a JSON object; pass --force to rebuild the dataset")
        # an option added since that folder was built counts as its default there
        default = asdict(DatasetOptions())
        diff = {k: (old.get(k), v) for k, v in cur.items() if old.get(k, default.get(k)) != v}
        diff.update({k: (v, None) for k, v in old.items() if k not in cur})
        if diff:
            what = ", ".join(f"{k} {a!r} -> {b!r}" for k, (a, b) in diff.items())
            if not rebuild:
                raise GeofaceError(f"{out} was built with other options ({what}); pass --force to rebuild every item "
                                   "with these, or build into another folder")
            changed = True
    text = json.dumps(cur, indent=1)
    if not path.is_file() or path.read_text() != text:  # a resumed run with no change writes nothing
        atomic_write_text(path, text)
    return changed


def build_dataset(
    in_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    options: DatasetOptions | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    labels: str | os.PathLike | dict | None = None,
    retry_failed: bool = False,
    rebuild: bool = False,
    quiet: bool | None = None,
) -> dict:
    """Convert every mesh in ``in_dir`` × corner set into ``out_dir`` (see module docs).

    Parameters
    ----------
    in_dir : folder of meshes (``.obj .ply .off .stl .glb``), optionally with ``<stem>.json``
        face masks and a ``labels.jsonl``
    out_dir : output folder (created; existing finished items are kept and skipped)
    options : :class:`DatasetOptions`
    workers : local processes (default: the number of cores; 1 = in this process)
    scheduler : a Dask scheduler address (``tcp://host:port``); overrides ``workers``
    labels : labels per mesh stem (a dict, or a ``.jsonl``/``.json`` file); default
        ``in_dir/labels.jsonl`` when present
    retry_failed : try items that failed in an earlier run again
    rebuild : ``out_dir`` was built with other options (``options.json``): build every item
        again with these (without it such a run is refused: a resumed build must not mix
        items made with different options)

    Returns
    -------
    dict with ``items`` (planned), ``done``, ``failed``, ``skipped``, ``seconds``,
    ``items_per_minute`` (done items per minute of this run) and ``failures`` (item → error).
    """
    opts = (options or DatasetOptions()).validate()
    files = find_meshes(in_dir)
    if labels is None and (Path(in_dir) / "labels.jsonl").is_file():
        labels = Path(in_dir) / "labels.jsonl"
    lab = labels if isinstance(labels, dict) or labels is None else load_labels(labels)
    sources = [(p.stem, str(p)) for p in files]
    return _build(sources, out_dir, opts, lab, None, workers=workers, scheduler=scheduler, retry_failed=retry_failed,
                  rebuild=rebuild, quiet=quiet, what=f"{len(files)} meshes")


def build_ict_dataset(
    out_dir: str | os.PathLike,
    count: int,
    options: DatasetOptions | None = None,
    *,
    seed: int = 0,
    model: str | os.PathLike | None = None,
    mix_share: float = 0.3,
    heldout_share: float = 0.2,
    workers: int | None = None,
    scheduler: str | None = None,
    retry_failed: bool = False,
    rebuild: bool = False,
    quiet: bool | None = None,
) -> dict:
    """A labelled dataset of ``count`` real heads of the ICT-FaceKit model (identities ``~ N(0,
    I)``, preset expressions and random ARKit mixes, prompts from measured traits: see
    :mod:`geoface.synth.ict_data`) converted like :func:`build_dataset` (same options, workers,
    Dask scheduler, resumption).  The heads are made in the workers from small specs; no mesh
    files are written.  The face mask of the model is the region of interest (``roi="auto"``).
    Manifest rows carry ``labels`` (``expression_name``, ``split`` by identity, traits) and
    ``prompt``; ``heads.jsonl`` in ``out_dir`` lists every head's weights and labels."""
    from .._io import atomic_write_text
    from ..synth.ict import find_model
    from ..synth.ict_data import ict_specs

    opts = (options or DatasetOptions()).validate()
    if opts.up == "auto":  # the model's heads are Y-up by construction: no need to look
        opts = replace(opts, up="y")
    path = find_model(model)
    specs = ict_specs(count, seed=seed, model_path=str(path), mix_share=mix_share, heldout_share=heldout_share)
    source = {"kind": "ict-facekit", "count": int(count), "seed": int(seed), "mix_share": float(mix_share),
              "heldout_share": float(heldout_share), "model": str(path)}
    out = Path(out_dir)
    sources = [(sp["name"], {"model": str(path), "identity": sp["identity"], "expression": sp["expression"]}) for sp in specs]
    labels = {sp["name"]: sp["labels"] for sp in specs}

    def write_heads():
        atomic_write_text(out / "heads.jsonl", "".join(json.dumps({"name": sp["name"], **sp}) + "\n" for sp in specs))

    return _build(sources, out, opts, labels, source, workers=workers, scheduler=scheduler, retry_failed=retry_failed,
                  rebuild=rebuild, quiet=quiet, what=f"{count} ICT-FaceKit heads", before=write_heads)


def _build(sources, out_dir, opts: DatasetOptions, lab: dict | None, source: dict | None, *, workers, scheduler,
           retry_failed: bool, rebuild: bool, quiet, what: str, before=None) -> dict:
    if workers is None:
        workers = max(1, os.cpu_count() or 1)
    if int(workers) != workers or workers < 1:
        raise GeofaceError(f"workers must be a positive integer; got {workers!r}")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise GeofaceError(f"output path exists and is not a folder: {out}")
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    lock = _lock_folder(out)
    try:
        return _build_into(out, sources, opts, lab, source, workers=workers, scheduler=scheduler,
                           retry_failed=retry_failed, rebuild=rebuild, quiet=quiet, what=what, before=before)
    except BaseException:
        # a build that failed before any item (an unreachable scheduler, a full disk) leaves no
        # folder of its own making behind: only its records would be in it
        if created and not any(p.is_dir() for p in out.iterdir()):
            import shutil

            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        if lock is not None:
            os.close(lock)  # the lock goes with the descriptor


def _lock_folder(out: Path):
    """An exclusive lock on the dataset folder itself (``flock`` on its descriptor: no lock file to
    leave behind) for the whole build; a second build into the same folder is refused with one
    line instead of writing every manifest row twice. None where the system has no ``flock``."""
    try:
        import fcntl
    except ImportError:  # not a POSIX system
        return None
    fd = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise GeofaceError(f"another dataset build is writing into {out}; wait for it to finish or build into "
                           "another folder") from None
    return fd


def _build_into(out: Path, sources, opts: DatasetOptions, lab: dict | None, source: dict | None, *, workers, scheduler,
                retry_failed: bool, rebuild: bool, quiet, what: str, before=None) -> dict:
    if not rebuild and (out / MANIFEST).is_file():
        read_manifest(out)  # an unreadable manifest is refused before anything is written
    changed = _record_options(out, opts, rebuild, source)
    if before is not None:
        before()
    if changed and (out / MANIFEST).is_file():  # rebuilt with other options or source: the old rows are stale
        from .._io import atomic_write_text

        atomic_write_text(out / MANIFEST, "")
    manifest = {} if changed else read_manifest(out)
    todo, skipped = _plan(sources, out, opts, manifest, retry_failed)
    total = len(todo) + len(skipped)
    where = f"Dask scheduler {scheduler}" if scheduler else ("this process" if workers == 1 else f"{workers} processes")
    log(f"dataset: {what} x {opts.augment} corner sets = {total} items; {len(skipped)} already done; "
        f"{len(todo)} to build on {where}", quiet=quiet)
    t0 = time.perf_counter()
    done = failed = 0
    failures: dict = {}
    if todo:
        submit, as_completed, close = executor(int(workers), scheduler)
        try:
            futures = {}
            for item, stem, src, k, folder in todo:
                futures[submit(run_item, src, str(folder), k, opts)] = (item, stem, src, k)
            with open(out / MANIFEST, "a", encoding="utf-8") as manifest:
                for n, fut in enumerate(as_completed(list(futures)), 1):
                    item, stem, src, k = futures[fut]
                    row = {"item": item, "mesh": Path(src).name if isinstance(src, str) else stem, "corner_set": k}
                    row.update(fut.result())
                    row["options"] = asdict(opts)
                    if lab is not None and stem in lab:
                        row["labels"] = lab[stem]
                        if "prompt" in lab[stem]:
                            row["prompt"] = lab[stem]["prompt"]
                    manifest.write(json.dumps(row) + "\n")
                    manifest.flush()
                    if row.pop("machine", False):
                        raise GeofaceError(f"{out}: {item}: {row['error'].split(': ', 1)[-1]}; the build stopped "
                                           f"({done} items built are kept; run it again when the disk can take more)")
                    if row["status"] == "ok":
                        done += 1
                    else:
                        failed += 1
                        failures[item] = row["error"]
                    el = time.perf_counter() - t0
                    eta = el / n * (len(todo) - n)
                    log(f"dataset [{n}/{len(todo)}] {item}: {row['status']} ({row['seconds']:.1f} s; "
                        f"{60 * n / max(el, 1e-9):.1f} items/min, {_clock(eta)} left)"
                        + (f" - {row['error']}" if row["error"] else ""), quiet=quiet)
        except BaseException:
            close(interrupted=True)  # SIGINT, SIGTERM, a driver error: the workers stop now
            from .._io import clean_tree_temporaries

            clean_tree_temporaries(out, depth=3)  # what the stopped workers were writing
            raise
        close()
    seconds = time.perf_counter() - t0
    summary = {
        "items": total, "done": done, "failed": failed, "skipped": len(skipped), "seconds": seconds,
        "items_per_minute": (60.0 * done / seconds) if done and seconds > 0 else 0.0, "failures": failures,
    }
    log(f"dataset: {done} built, {failed} failed, {len(skipped)} skipped in {seconds:.1f} s", quiet=quiet)
    return summary


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"
