"""SIGTERM and Ctrl-C for the ``geoface`` program: unwind, but never under running worker threads.

A command stopped by SIGTERM unwinds like Ctrl-C, so the temporary outputs it was writing
are removed (``geoface._io``).  Raising ``KeyboardInterrupt`` at once is unsafe while the
main thread waits on worker threads that run native code on its buffers, as SciPy's
``cKDTree.query(workers=-1)`` does: the wait is abandoned, the
buffers are freed by the unwinding, and the workers write into freed memory (a segfault
after "geoface: terminated").  Such a wait shows as the main thread's innermost Python frame
being in ``threading`` (``Thread.start``, ``Thread.join``, ``Condition.wait``): native code
runs no Python of its own.  So while that is so and some thread is inside a native target,
the interrupt is deferred: an interval timer re-checks every 20 ms and raises at the first check the main
thread is back in other code, or after ``MAX_DEFER_S`` regardless.  Nor is it raised inside a
finaliser or a weak reference's callback, where Python would print and ignore it: the timer
tries again 20 ms later.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from contextlib import contextmanager

MAX_DEFER_S = 5.0
_RECHECK_S = 0.02


def _native_workers() -> int:
    """How many threads other than the main one are inside a native target: their innermost
    Python frame is ``Thread.run`` itself (a Python target would show its own frame).  That is
    how SciPy's query threads look; a pool's manager thread or a watcher written in Python
    does not count, as unwinding the main thread cannot free what they work on."""
    main = threading.main_thread().ident
    n = 0
    for ident, f in sys._current_frames().items():
        if ident != main and f.f_code.co_filename == threading.__file__ and f.f_code.co_name == "run":
            n += 1
    return n


def _swallowed(frame) -> bool:
    """Whether an exception raised in ``frame`` would be swallowed ("Exception ignored in"):
    a finaliser or a weak reference's callback (``WeakSet``'s ``_remove``), which Python runs
    between any two instructions of the main thread.  Seen once in ~500 runs of a loaded CI."""
    if frame is None:
        return False
    code = frame.f_code
    return code.co_name == "__del__" or code.co_filename == _WEAKREFSET


_WEAKREFSET = sys.modules["_weakrefset"].__file__ if "_weakrefset" in sys.modules else ""


@contextmanager
def deferred_interrupts():
    """Install the handlers for SIGINT and SIGTERM for the duration; yields the list that
    records which signal arrived first (empty if none).  Restores the previous handlers."""
    got: list[int] = []
    since: list[float] = []

    def handler(signum, frame):
        if signum != signal.SIGALRM and not got:
            got.append(signum)
            since.append(time.monotonic())
        if not got:  # a stray alarm
            return
        if _swallowed(frame):  # raised there it would be printed and ignored: the run goes on
            signal.setitimer(signal.ITIMER_REAL, _RECHECK_S)
            return
        waiting = frame is not None and frame.f_code.co_filename == threading.__file__
        if waiting and _native_workers() and time.monotonic() - since[0] < MAX_DEFER_S:
            signal.setitimer(signal.ITIMER_REAL, _RECHECK_S)
            return
        signal.setitimer(signal.ITIMER_REAL, 0)
        raise KeyboardInterrupt

    previous = {}
    try:
        for s in (signal.SIGINT, signal.SIGTERM, signal.SIGALRM):
            previous[s] = signal.signal(s, handler)
    except ValueError:  # not in the main thread (an embedding application): leave them be
        for s, h in previous.items():
            signal.signal(s, h)
        previous = {}
    try:
        yield got
    finally:
        if previous:
            signal.setitimer(signal.ITIMER_REAL, 0)
            for s, h in previous.items():
                signal.signal(s, h if h is not None else signal.SIG_DFL)
