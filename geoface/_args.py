"""Typed, ranged command-line numbers: ``--fps nan``, ``--batch 0`` or ``--smooth 1e9`` are
one-line usage errors (exit code 2), never a traceback or a run that cannot end."""

from __future__ import annotations

import argparse
import math

__all__ = ["number", "SEED", "add_json", "json_to_stdout", "write_json", "output_option", "resolve_output", "renamed"]


def number(kind: type = float, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
           hi_open: bool = False):
    """An argparse ``type`` for a finite ``int`` or ``float`` in a range.

    >>> number(int, 1, 8)("3"), number(float, 0, lo_open=True)("0.5")
    (3, 0.5)
    """
    what = "an integer" if kind is int else "a finite number"
    bounds = []
    if lo is not None:
        bounds.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        bounds.append(f"{'<' if hi_open else '<='} {hi:g}")
    desc = what + (" " + " and ".join(bounds) if bounds else "")

    def parse(text: str):
        try:
            if kind is int:
                v = int(text, 10)
            else:
                v = float(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"must be {desc}; got {text!r}") from None
        if kind is float and not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"must be {desc}; got {text!r}")
        if lo is not None and (v < lo or (lo_open and v == lo)):
            raise argparse.ArgumentTypeError(f"must be {desc}; got {text!r}")
        if hi is not None and (v > hi or (hi_open and v == hi)):
            raise argparse.ArgumentTypeError(f"must be {desc}; got {text!r}")
        return v

    parse.__name__ = "number"
    return parse


#: random seeds: what NumPy and torch accept everywhere
SEED = number(int, 0, 2**32 - 1)


def add_json(parser: argparse.ArgumentParser, what: str = "the results") -> None:
    """The one ``--json [PATH]`` of every command: ``--json PATH`` writes ``what`` to PATH (as
    well as the text), a bare ``--json`` (or ``--json -``) prints it instead of the text."""
    parser.add_argument("--json", nargs="?", const="-", default=None, metavar="PATH",
                        help=f"{what} as JSON: written to PATH, or printed instead of the text when PATH is - or left out")


def json_to_stdout(args) -> bool:
    return getattr(args, "json", None) == "-"


def write_json(args, obj) -> None:
    """Print or write ``obj`` as ``--json`` asks (atomically, for a file); nothing without it."""
    import json

    path = getattr(args, "json", None)
    if path is None:
        return
    text = json.dumps(obj, indent=2, default=float)
    if path == "-":
        print(text)
    else:
        from ._io import atomic_write_text

        atomic_write_text(path, text + "\n")


#: hidden positional outputs kept for one release, from before every verb wrote to -o
_LEGACY = "legacy_output"


def output_option(parser, metavar: str, help: str) -> None:
    """``-o/--output`` as every verb names its output; the old positional OUT_DIR still works
    (hidden) with a one-line deprecation warning."""
    parser.add_argument("-o", "--output", default=None, metavar=metavar, help=help + " (required)")
    parser.add_argument(_LEGACY, nargs="?", default=None, help=argparse.SUPPRESS)


def resolve_output(parser, args) -> None:
    """After parsing: -o or the legacy positional, exactly one of them."""
    if not hasattr(args, _LEGACY):
        return
    legacy = getattr(args, _LEGACY)
    delattr(args, _LEGACY)
    if legacy is not None and args.output is not None:
        parser.error(f"unrecognized arguments: {legacy}")
    if legacy is not None:
        import warnings

        from .errors import GeofaceWarning

        warnings.warn(f"the output is now given with -o: write `-o {legacy}` (a bare output path stops working in "
                      "the next release)", GeofaceWarning, stacklevel=2)
        args.output = legacy
    if args.output is None:
        parser.error("the following arguments are required: -o/--output")


def renamed(parser, old: str, new: str) -> None:
    """An option that was renamed: the old spelling is refused with the new one named (hidden in --help)."""
    class _Renamed(argparse.Action):
        def __call__(self, p, namespace, values, option_string=None):
            p.error(f"{old} is now {new}")

    parser.add_argument(old, nargs="?", action=_Renamed, help=argparse.SUPPRESS)


def synth_landmarks_option(p) -> None:
    """``--landmarks tracked|oracle`` of the avatars' ``synth`` verbs (see :func:`track_synthetic`)."""
    p.add_argument("--landmarks", choices=("tracked", "oracle"), default=None,
                   help="tracked: the landmarks, person masks (and headset masks) found on the frames by geoface track, "
                        "as a user's would be, the renderer's kept as landmarks_true.json, masks_true/ (and "
                        "hmd_masks_true/); oracle: the renderer's own (default: tracked for --head ict, oracle for "
                        "the procedural head, which is no face to the tracker)")

