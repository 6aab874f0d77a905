"""One progress helper for every long loop (rich when available, silent when quiet).

>>> from geoface.progress import progress
>>> for i in progress(range(3), "demo", quiet=True):
...     pass
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

#: global switch, set by ``geoface --quiet`` and by the tests (GEOFACE_QUIET=1)
QUIET = os.environ.get("GEOFACE_QUIET", "") not in ("", "0")


def set_quiet(on: bool) -> None:
    global QUIET
    QUIET = bool(on)


def progress(it: Iterable[T], description: str = "", total: int | None = None, quiet: bool | None = None) -> Iterator[T]:
    """Iterate over ``it`` showing a progress bar on stderr unless quiet."""
    q = QUIET if quiet is None else quiet
    if q or not sys.stderr.isatty():
        yield from it
        return
    try:
        from rich.progress import track
    except ImportError:  # pragma: no cover
        yield from it
        return
    yield from track(it, description=description, total=total, console=None, transient=True)


def log(message: str, quiet: bool | None = None) -> None:
    """Print one status line on stderr unless quiet."""
    q = QUIET if quiet is None else quiet
    if not q:
        print(message, file=sys.stderr, flush=True)
