"""One progress helper for every long loop (rich when available, silent when quiet).

>>> from geoface.progress import progress
>>> for i in progress(range(3), "demo", quiet=True):
...     pass
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

#: global switch.  The library is quiet by default (``GEOFACE_QUIET=0`` or ``set_quiet(False)``
#: shows its status lines and progress on stderr); the ``geoface`` command turns it off for the
#: command's run unless ``-q`` (or ``GEOFACE_QUIET=1``) is given.
QUIET = os.environ.get("GEOFACE_QUIET", "1") not in ("", "0")


#: show the solvers' iteration lines too (``-v``, ``GEOFACE_VERBOSE=1``, ``set_verbose(True)``)
VERBOSE = os.environ.get("GEOFACE_VERBOSE", "0") not in ("", "0")

#: every status line also goes to this logger (INFO; iteration detail at DEBUG), for
#: applications that configure :mod:`logging`; it has only a NullHandler of its own
LOGGER = logging.getLogger("geoface")
LOGGER.addHandler(logging.NullHandler())


def set_quiet(on: bool) -> None:
    """Silence (True) or show (False) the library's status lines and progress bars."""
    global QUIET
    QUIET = bool(on)


def set_verbose(on: bool) -> None:
    """Show (True) or hide (False) the solvers' per-iteration lines when not quiet."""
    global VERBOSE
    VERBOSE = bool(on)


def progress(it: Iterable[T], description: str = "", total: int | None = None, quiet: bool | None = None,
             unit: str = "steps") -> Iterator[T]:
    """Iterate over ``it`` showing progress on stderr unless quiet: a live bar on a terminal,
    elsewhere (a notebook, a log file) a :class:`StepProgress` line with the rate and the time
    left every 10 seconds."""
    q = QUIET if quiet is None else quiet
    if q:
        yield from it
        return
    if total is None and hasattr(it, "__len__"):
        total = len(it)
    if sys.stderr.isatty():
        try:
            from rich.progress import track
        except ImportError:  # pragma: no cover
            pass
        else:
            yield from track(it, description=description, total=total, console=None, transient=True)
            return
    bar = StepProgress(total or 0, description, unit=unit, quiet=False)
    try:
        for x in it:
            yield x
            bar.update()
    finally:
        bar.close()


def log(message: str, quiet: bool | None = None, *, detail: bool = False) -> None:
    """One status line: to the ``geoface`` logger, and on stderr unless quiet.  ``detail``
    marks a solver's per-iteration line or a routine fallback: logged at DEBUG and shown
    only when verbose (``-v``)."""
    if quiet is True:
        return
    LOGGER.log(logging.DEBUG if detail else logging.INFO, message)
    q = QUIET if quiet is None else quiet
    if not q and (VERBOSE or not detail):
        print(message, file=sys.stderr, flush=True)


def _clock(seconds: float) -> str:
    s = int(round(max(0.0, seconds)))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class StepProgress:
    """Progress of a long loop of steps, with rate and time left, wherever it runs.

    On a terminal: a live bar (rich).  Elsewhere — a notebook, a log file, a job scheduler —
    one line on stderr after the first step and then every ``every`` seconds, e.g.
    ``ddpm train: step 120/3600 (3%), 1.92 steps/s, 30:12 left, loss 0.1234``; a final line
    when closed.  Silent when quiet.

    >>> bar = StepProgress(3, "demo", quiet=True)
    >>> for _ in range(3):
    ...     bar.update(loss=0.5)
    >>> bar.close()
    """

    def __init__(self, total: int, description: str = "", *, start: int = 0, unit: str = "steps", every: float = 10.0,
                 quiet: bool | None = None, stream=None, budget: float | None = None):
        import time

        self.total, self.description, self.unit, self.every = int(total), description, unit, float(every)
        #: a wall-clock budget (seconds) that stops the loop before ``total``: the time left is then
        #: the budget's, and the line says so
        self.budget = None if budget is None else float(budget)
        self.start = self.n = int(start)
        self.quiet = QUIET if quiet is None else quiet
        self.stream = stream if stream is not None else sys.stderr
        self.t0 = self._last = time.perf_counter()
        self._printed_first = False
        self.postfix: dict = {}
        self._rich = None
        if not self.quiet and stream is None and sys.stderr.isatty():
            try:
                from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
            except ImportError:  # pragma: no cover
                pass
            else:
                self._rich = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                      TextColumn("{task.fields[rate]}"), TimeRemainingColumn(), TextColumn("{task.fields[post]}"),
                                      transient=True)
                self._rich.start()
                self._task = self._rich.add_task(description, total=self.total, completed=self.start, rate="", post="")

    @property
    def rate(self) -> float:
        import time

        el = time.perf_counter() - self.t0
        return (self.n - self.start) / el if el > 0 else 0.0

    def line(self) -> str:
        r = self.rate
        post = "".join(f", {k} {v:.4g}" if isinstance(v, float) else f", {k} {v}" for k, v in self.postfix.items())
        if not self.total:  # an iterable of unknown length: count and rate only
            return f"{self.description}: {self.n} {self.unit}, {r:.3g} {self.unit}/s{post}"
        eta = (self.total - self.n) / r if r > 0 else float("nan")
        pct = 100.0 * self.n / self.total
        left = self._budget_left()
        if left is not None and not eta <= left:  # the budget ends the loop first
            return (f"{self.description}: {self.unit[:-1] if self.unit.endswith('s') else self.unit} {self.n} "
                    f"(time budget), {r:.3g} {self.unit}/s, {_clock(left)} left, about {self.n + int(r * left)} "
                    f"of {self.total} by then{post}")
        eta_s = _clock(eta) if eta == eta else "?"
        return f"{self.description}: {self.unit[:-1] if self.unit.endswith('s') else self.unit} {self.n}/{self.total} ({pct:.0f}%), {r:.3g} {self.unit}/s, {eta_s} left{post}"

    def _budget_left(self) -> float | None:
        import time

        if self.budget is None:
            return None
        return max(0.0, self.budget - (time.perf_counter() - self.t0))

    def update(self, n: int = 1, **postfix) -> None:
        import time

        self.n += int(n)
        self.postfix.update(postfix)
        if self.quiet:
            return
        if self._rich is not None:
            post = " ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in self.postfix.items())
            left = self._budget_left()
            if left is not None and self.rate > 0 and (self.total - self.n) / self.rate > left:
                post = f"time budget: {_clock(left)} left " + post
            self._rich.update(self._task, completed=self.n, rate=f"{self.rate:.3g} {self.unit}/s", post=post)
            return
        now = time.perf_counter()
        if not self._printed_first or now - self._last >= self.every:
            self._printed_first, self._last = True, now
            print(self.line(), file=self.stream, flush=True)

    def close(self) -> None:
        if self._rich is not None:
            self._rich.stop()
            self._rich = None
        elif not self.quiet and self.n > self.start:
            print(self.line(), file=self.stream, flush=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def args_quiet(args) -> bool:
    """Whether a command runs quietly: its ``--quiet`` flag or ``GEOFACE_QUIET``."""
    return bool(getattr(args, "quiet", False) or QUIET)
