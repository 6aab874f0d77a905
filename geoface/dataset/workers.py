"""Where a dataset build (:mod:`geoface.dataset`) runs its items.

Schedulers: ``workers=1`` runs in this process; ``workers=N`` a local process pool (spawned
processes); ``scheduler="tcp://host:8786"`` a Dask distributed cluster (every worker needs
geoface installed and the input/output folders mounted at the same paths).  Pool workers end
with the driver (:func:`die_with_parent`), even when it is killed.
"""

from __future__ import annotations

import os
import time

from ..errors import GeofaceError


class _Deferred:
    """A future for the serial backend: runs its call when its result is asked for."""

    def __init__(self, fn, *args):
        self.fn, self.args = fn, args

    def result(self):
        return self.fn(*self.args)


def executor(workers: int, scheduler: str | None):
    """``(submit(fn, *args) -> future, as_completed(futures), close())`` for the chosen backend."""
    if scheduler:
        from .._lazy import lazy_import

        distributed = lazy_import("dask.distributed", "dataset building on a Dask cluster")
        try:
            client = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as e:
            raise GeofaceError(f"cannot connect to the Dask scheduler {scheduler}: {e}") from None
        return (lambda fn, *a: client.submit(fn, *a, pure=False)), distributed.as_completed, lambda interrupted=False: client.close()
    if workers == 1:  # in this process, one item at a time as the driver asks for results
        return _Deferred, iter, lambda interrupted=False: None
    import multiprocessing as mp
    import shutil
    import tempfile
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from .. import _cache

    # the workers share one cache for the length of the build (geoface._cache): each mesh's face
    # and level turn are found once, not once per worker that converts one of its corner sets
    own_cache = None
    if _cache.folder() is None:
        own_cache = tempfile.mkdtemp(prefix="geoface-cache-")
    env = {_cache.ENV: own_cache} if own_cache else {}
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # spawned workers take the environment as it is when they start
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"), initializer=die_with_parent,
                               initargs=(os.getpid(),))

    def restore() -> None:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        if own_cache:
            shutil.rmtree(own_cache, ignore_errors=True)

    def close(interrupted: bool = False) -> None:
        try:
            _close(interrupted)
        finally:
            restore()

    def _close(interrupted: bool) -> None:
        if interrupted:  # do not wait for running items: end the workers now (the temporary
            # folders of their unfinished items are removed by the next run that builds them)
            procs = list((getattr(pool, "_processes", None) or {}).values())
            for proc in procs:
                proc.kill()
            for proc in procs:
                proc.join(timeout=2.0)
            pool.shutdown(wait=False, cancel_futures=True)
        else:
            pool.shutdown(wait=True, cancel_futures=True)

    return pool.submit, as_completed, close


def die_with_parent(parent: int, unwind: bool = True) -> None:
    """Worker initializer: end this worker when the driver dies (even by SIGKILL), instead
    of writing on for minutes (Linux: PR_SET_PDEATHSIG; elsewhere a watcher thread).  ``unwind``:
    SIGTERM raises KeyboardInterrupt, so that the item in hand cleans up (else SIGTERM ends the
    worker as it always does, quietly: what ``multiprocessing.Pool`` sends its workers on closing)."""
    import signal
    import sys
    import threading

    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the driver died before the call above
        os._exit(1)

    def on_term(signum, frame):  # unwind: the item's temporary folder is removed on the way out
        raise KeyboardInterrupt

    if unwind:
        signal.signal(signal.SIGTERM, on_term)

    def watch():
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, daemon=True).start()
