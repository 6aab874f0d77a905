"""An optional cache on disk for what one mesh's conversion finds and another process would find
again: the face on the mesh (:func:`geoface.track.scan.scan_landmarks`) and the turn of the
corner sets that levels its eye line (:func:`geoface.pipeline.face.level_corners`).

Off unless the environment names a folder: ``GEOFACE_CACHE=DIR``. Each entry is a small JSON file
named by a hash of what it was computed from (the mesh's bytes, the options that change it) and
of geoface's version; a file that cannot be read is a miss, a write that fails is skipped (with a
debug line), and files are written atomically, so processes may share the folder. The dataset
builder points its worker processes at one such folder for the length of a build (each mesh is
looked at once, not once per worker); nothing else writes there.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path

log = logging.getLogger("geoface")

#: the environment variable that names the cache folder
ENV = "GEOFACE_CACHE"


def folder() -> Path | None:
    """The cache folder the environment names, or None (no cache)."""
    d = os.environ.get(ENV, "").strip()
    return Path(d) if d else None


def _path(kind: str, key: str) -> Path | None:
    d = folder()
    if d is None:
        return None
    from . import __version__

    name = hashlib.sha1(f"{kind}|{__version__}|{key}".encode()).hexdigest()
    return d / kind / f"{name}.json"


def get(kind: str, key: str):
    """The JSON value stored for ``key`` under ``kind``, or None."""
    p = _path(kind, key)
    if p is None or not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return None


def put(kind: str, key: str, value) -> None:
    """Store the JSON-able ``value`` for ``key`` under ``kind`` (atomically; failures skipped)."""
    p = _path(kind, key)
    if p is None:
        return
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps(value))
        os.replace(tmp, p)
    except OSError as e:
        log.debug("cache: %s not written (%s)", p, e)
        try:
            tmp.unlink()
        except OSError:
            pass
