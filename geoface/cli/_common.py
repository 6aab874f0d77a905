"""What every verb shares: the parser class, and the output-path policy applied before any work."""
from __future__ import annotations

import argparse
import re
from pathlib import Path



#: options whose value may be a negative axis ("--up -z"), which argparse would take for a flag
_AXIS_OPTIONS = ("--up", "--front")


def one_line(message) -> str:
    """A message as one line: line breaks and other control characters (a file name may hold
    them) written as escapes, so that an error is always exactly one line."""
    named = {"\n": "\\n", "\r": "\\r", "\t": " "}
    return "".join(named.get(c, f"\\x{ord(c):02x}" if ord(c) < 32 or c == "\x7f" else c) for c in str(message)).strip()


def axis(auto: bool = True):
    """An argparse ``type`` for ``--up`` / ``--front``: ``auto`` (where ``auto`` allows it),
    ``+x``, ``-y``, ``z``, ... or three numbers, checked when the command line is read (a
    dataset build never starts with an axis no item can use).

    >>> axis()("auto"), axis()("-z"), axis()("0,0,1")
    ('auto', '-z', '0,0,1')
    """
    def parse(text: str) -> str:
        from ..errors import GeofaceError
        from ..mesh.frame import parse_up

        if auto and text.strip().lower() == "auto":
            return "auto"
        try:
            parse_up(text)
        except GeofaceError as e:
            raise argparse.ArgumentTypeError(("auto, " if auto else "") + str(e).replace("up must be ", "")) from None
        return text

    parse.__name__ = "axis"
    return parse


class _Formatter(argparse.HelpFormatter):
    """Every option's default in ``--help``: a help text that does not say it gets
    ``(default: X)``; one that ends in the bare value, ``(0.02)``, says ``(default: 0.02)``."""

    def _get_help_string(self, action):
        h = action.help or ""
        d = action.default
        if (not action.option_strings or d is None or d is False or d is argparse.SUPPRESS
                or isinstance(action, argparse._StoreFalseAction)  # --no-X: its default is not to say it
                or "default" in h or "%(default)" in h):
            return h
        m = re.search(r"\(([^()]*)\)\s*$", h)
        if m and m.group(1).split(";")[0].split(",")[0].split(" ")[0].strip() in _spellings(d):
            return h[:m.start()] + f"(default: {m.group(1)})"
        return (h + " " if h else "") + "(default: %(default)s)"


def _spellings(value) -> set:
    """How a help text may write a default: 0.001 as 0.001 or 1e-3, 6.0 as 6."""
    out = {str(value)}
    if isinstance(value, float):
        out |= {f"{value:g}", f"{value:.0e}".replace("e-0", "e-"), repr(value)}
        if value == int(value):
            out.add(str(int(value)))
    return out


class Parser(argparse.ArgumentParser):
    def __init__(self, *a, **k):
        k.setdefault("formatter_class", _Formatter)
        super().__init__(*a, **k)

    def error(self, message):  # one line, exit code 2 (argparse's own code for usage errors)
        self.exit(2, f"{self.prog}: error: {one_line(message)}\n")

    def parse_known_args(self, args=None, namespace=None):
        import sys

        args = list(sys.argv[1:] if args is None else args)
        out, k = [], 0
        while k < len(args):  # "--up -z" -> "--up=-z"
            if args[k] in _AXIS_OPTIONS and k + 1 < len(args) and args[k + 1] in ("-x", "-y", "-z"):
                out.append(f"{args[k]}={args[k + 1]}")
                k += 2
            else:
                out.append(args[k])
                k += 1
        return super().parse_known_args(out, namespace)


def mesh_outputs(path) -> list:
    """A mesh output with the companion files written with it (OBJ: .mtl, texture, normal map)."""
    if path is None:
        return []
    from ..mesh.io import format_of, companion_names

    format_of(path)  # an unsupported format is refused now, not after the work

    return [path, *companion_names(path)]


def guard_outputs(args, inputs, outputs, resumable=()) -> None:
    """The output-path policy (geoface._io.check_outputs), before any work.  An input mesh
    counts with the files it references (its MTL, texture, normal map)."""
    from .._io import check_outputs
    from ..mesh.io import companion_names, referenced_files

    ins = []
    for p in inputs:
        if p is None:
            continue
        ins.append(p)
        if Path(p).is_file():
            ins += [c for c in companion_names(p) if c.exists()]
            ins += [c for c in referenced_files(p) if c not in ins]
    outputs = [o for o in outputs if o is not None and o != "-"]  # "--json -": stdout
    check_outputs(ins, outputs, force=getattr(args, "force", False), resumable=resumable)


#: the neural commands' inputs and outputs (argument names), for the output-path policy;
#: the geometry commands apply it in their own functions (they know their companion files)
_PATHS = {
    ("ddpm", "train"): (("data_dir",), ("output",)),
    ("track", None): (("input",), ("output", "masks")),
    ("ddpm", "sample"): (("run_dir",), ("output",)),
    ("texture", "synth"): ((), ("output",)),
    ("texture", "train"): (("data_dir", "init"), ("output",)),
    ("texture", "reconstruct"): (("photo", "model", "mesh", "camera", "landmarks"), ("output",)),
    ("splat", "fit"): (("mesh",), ("output", "renders")),
    ("hmd", "synth"): ((), ("output",)),
    ("hmd", "train"): (("reg_dir",), ("output",)),
    ("hmd", "remove"): (("model_dir", "usage_dir"), ("output", "video")),
    ("hmd", "eval"): (("model_dir", "usage_dir"), ("json",)),
    ("talk", "synth"): ((), ("output",)),
    ("talk", "train"): (("data_dir",), ("output",)),
    ("talk", "animate"): (("model_dir", "audio", "poses"), ("output", "video")),
    ("talk", "eval"): (("model_dir", "data_dir"), ("json",)),
    ("talk", "export"): (("model_dir", "drive"), ("output",)),
    ("hmd", "export"): (("model_dir", "drive"), ("output",)),
}


def guard_by_table(args) -> None:
    """The output-path policy for the commands in :data:`_PATHS`.  A DDPM run folder with a
    checkpoint is resumed with ``--resume``; model folders the command refuses to replace on
    its own terms (hmd, talk) are left to it."""
    key = (getattr(args, "command", None), getattr(args, "what", None))
    if key not in _PATHS:
        return
    ins, outs = _PATHS[key]
    inputs = [getattr(args, a, None) for a in ins]
    outputs = [getattr(args, a, None) for a in outs]
    resumable = []
    if key == ("ddpm", "train") and getattr(args, "resume", False):
        resumable = outputs
    if key[0] in ("hmd", "talk") and key[1] in ("train", "remove", "animate"):
        resumable = [getattr(args, "output", None)]  # they check their model/frames folders themselves (--force)
    guard_outputs(args, inputs, outputs, resumable=resumable)


def verbs(parser, common):
    """Second-level subcommands (``geoface synth head``); each accepts the common flags (-q)."""
    sp = parser.add_subparsers(dest="what", metavar="WHAT", parser_class=Parser)
    sp.required = True
    add = sp.add_parser
    sp.add_parser = lambda *a, **k: add(*a, parents=[common], **k)
    return sp
