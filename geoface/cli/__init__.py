"""The ``geoface`` command: thin subcommands that parse, call one library function, report.

Bad input never produces a traceback: every :class:`~geoface.GeofaceError` (and file
system error) becomes one line on stderr and exit code 2.  Outputs are written
atomically, and an input file is never overwritten.
"""

from __future__ import annotations

import argparse
import functools
import sys
import warnings

from .. import __version__
from ..errors import GeofaceError, GeofaceWarning
from .._args import resolve_output

from ._common import Parser, guard_by_table, one_line

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="geoface", description="Geometry processing of head and face meshes.")
    p.add_argument("--version", action="version", version=f"geoface {__version__}")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.add_argument("-v", "--verbose", action="store_true", help="also the solvers' iterations")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help="no progress output")
    common.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="also the solvers' iterations (Ricci flow, optimal transport, training)")
    common.add_argument("--force", action="store_true", default=argparse.SUPPRESS,
                        help="replace outputs that exist (never an input)")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    _add = sub.add_parser
    sub.add_parser = lambda *a, **k: _add(*a, parents=[common], **k)  # every verb accepts -q

    # each group registers its own verbs; argparse only: torch loads inside the neural commands
    from .ddpm import register as register_ddpm
    from .hmd import register as register_hmd
    from .splat import register as register_splat
    from .talk import register as register_talk
    from .texture import register as register_texture
    from .dataset import register as register_dataset
    from .geometry_parser import register as register_geometry
    from .synth import register as register_synth
    from .track import register as register_track
    from .capture import register as register_capture

    for register in (register_geometry, register_dataset, register_ddpm, register_splat, register_hmd, register_talk,
                     register_texture, register_track, register_capture, register_synth):
        register(sub, common)
    return p


@functools.lru_cache(maxsize=1)
def _parser() -> argparse.ArgumentParser:
    """The parser :func:`main` uses, built once per process (argparse parses without changing
    it; a notebook or a test calls :func:`main` many times, and building it takes 20 ms)."""
    return build_parser()


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    try:
        args = parser.parse_args(argv)
        with warnings.catch_warnings():
            warnings.simplefilter("always", GeofaceWarning)
            warnings.showwarning = _show_warning
            resolve_output(parser, args)
    except SystemExit as e:  # a usage error (one line already printed), --help or --version
        return int(e.code or 0) if not isinstance(e.code, str) else 2
    if not hasattr(args, "force"):
        args.force = False
    import os

    from .. import progress as _progress

    # the library is quiet unless asked; the command line shows progress unless -q (or
    # GEOFACE_QUIET=1, as the tests set)
    was_quiet, was_verbose = _progress.QUIET, _progress.VERBOSE
    _progress.set_quiet(bool(args.quiet) or os.environ.get("GEOFACE_QUIET", "") not in ("", "0"))
    _progress.set_verbose(bool(getattr(args, "verbose", False)) or was_verbose)
    try:
        return _run(args)
    finally:
        _progress.set_quiet(was_quiet)
        _progress.set_verbose(was_verbose)


def _run(args) -> int:
    done: list = []  # the command's exit code, once it has returned (its outputs complete)
    try:
        return _run_guarded(args, done)
    except KeyboardInterrupt:
        # a signal in the window after the command returned, before the handlers are restored:
        # the outputs are complete, so the run ends as the command did (no traceback)
        if done:
            return done[0]
        print("geoface: interrupted", file=sys.stderr)
        return 130


def _run_guarded(args, done: list) -> int:
    from .interrupt import deferred_interrupts

    with deferred_interrupts() as got:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("always", GeofaceWarning)
                warnings.showwarning = _show_warning
                guard_by_table(args)
                done.append(int(args.func(args) or 0))
            return done[0]
        except GeofaceError as exc:
            print(f"geoface: error: {one_line(exc)}", file=sys.stderr)
            return 2
        except OSError as exc:
            print(one_line(f"geoface: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": ")), file=sys.stderr)
            return 2
        except MemoryError as exc:  # numpy's _ArrayMemoryError included: an input far larger than the machine
            print(one_line(f"geoface: error: out of memory ({exc or 'an input too large for this machine'})"), file=sys.stderr)
            return 2
        except KeyboardInterrupt:  # SIGTERM unwinds like Ctrl-C, so temporary outputs are removed
            import signal

            if done:  # it landed as the command returned: the outputs are complete
                return done[0]
            terminated = bool(got) and got[0] == signal.SIGTERM
            print("geoface: terminated" if terminated else "geoface: interrupted", file=sys.stderr)
            return 143 if terminated else 130


def entry() -> None:
    """The ``geoface`` program: :func:`main`, then exit with its code.

    After SIGTERM or Ctrl-C the stack has unwound (temporary outputs removed); if the
    interrupt had to be raised under a library's worker threads after all (they ran past
    ``interrupt.MAX_DEFER_S``), interpreter shutdown under them could crash, so an
    interrupted run leaves with ``os._exit`` once its output is flushed."""
    import os

    code = main()
    if code in (130, 143):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print(f"geoface: warning: {one_line(message)}", file=sys.stderr)


if __name__ == "__main__":  # pragma: no cover
    entry()
