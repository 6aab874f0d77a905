"""Saved configurations read through one validated path.

Every model folder geoface writes (DDPM runs, texture models, HFM-GS and THGS avatars) holds a
JSON config that becomes a dataclass.  :func:`config_from_dict` checks each field against
the dataclass's annotation before the constructor runs — the type (``int``, a finite
``float``, ``bool``, ``str``, tuples/lists of those, ``X | None``, ``Literal[...]``) and then
the dataclass's own range checks — and raises :class:`~geoface.errors.CheckpointError` that
names the file and the field at fault.  :func:`check_version` refuses a folder written by a
newer format.

>>> from dataclasses import dataclass
>>> @dataclass
... class C:
...     n: int = 3
...     lr: float = 1e-3
>>> config_from_dict(C, {"n": 4}, where="config.json")
C(n=4, lr=0.001)
>>> config_from_dict(C, {"n": "4"}, where="config.json")
Traceback (most recent call last):
...
geoface.errors.CheckpointError: config.json: field 'n' must be an integer; got '4'
"""

from __future__ import annotations

import dataclasses
import math
import typing

from ..errors import CheckpointError, GeofaceError

__all__ = ["config_from_dict", "check_version"]


def _describe(tp) -> str:
    origin = typing.get_origin(tp)
    if tp is int:
        return "an integer"
    if tp is float:
        return "a finite number"
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (tuple, list) or tp in (tuple, list):
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        return "a list" + (f" of {_describe(args[0])}s" if args else " of numbers")
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " or ".join("null" if a is type(None) else _describe(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", str(tp))


def _convert(tp, v):
    """``v`` as type ``tp``, or raise ValueError."""
    origin = typing.get_origin(tp)
    if tp is typing.Any or tp is object:
        return v
    if tp is bool:
        if isinstance(v, bool):
            return v
        raise ValueError
    if tp is int:
        if isinstance(v, int) and not isinstance(v, bool):
            return v
        raise ValueError
    if tp is float:
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            return float(v)
        raise ValueError
    if tp is str:
        if isinstance(v, str):
            return v
        raise ValueError
    if origin is typing.Literal:
        if v in typing.get_args(tp):
            return v
        raise ValueError
    if origin in (tuple, list):
        if not isinstance(v, (list, tuple)):
            raise ValueError
        args = typing.get_args(tp)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(v):
                raise ValueError
            out = [_convert(a, x) for a, x in zip(args, v)]
        else:
            elem = args[0] if args else typing.Any
            out = [_convert(elem, x) for x in v]
        return tuple(out) if origin is tuple else out
    if tp in (tuple, list):  # a bare tuple/list annotation: a list of numbers
        if not isinstance(v, (list, tuple)) or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v):
            raise ValueError
        return tuple(v) if tp is tuple else list(v)
    if origin is dict or tp is dict:
        if isinstance(v, dict):
            return v
        raise ValueError
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        for a in typing.get_args(tp):
            if a is type(None):
                if v is None:
                    return None
                continue
            try:
                return _convert(a, v)
            except ValueError:
                continue
        raise ValueError
    if dataclasses.is_dataclass(tp):
        return v  # nested configs are converted by their own from_dict
    return v


def config_from_dict(cls, d, *, where: str, error: type = CheckpointError, unknown: str = "error", convert_nested=None):
    """An instance of dataclass ``cls`` from the JSON object ``d`` (module docs).

    ``where``: the file, for messages.  ``unknown``: ``"error"`` or ``"ignore"`` keys the
    dataclass does not have.  ``convert_nested``: ``{field: function}`` for fields that are
    configs of their own.  Raises ``error`` (a CheckpointError by default) naming the field.
    """
    if not isinstance(d, dict):
        raise error(f"{where}: a config must be a JSON object; got {type(d).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    extra = sorted(set(d) - names)
    if extra and unknown == "error":
        raise error(f"{where}: unknown fields {extra}")
    kw = {}
    for name in names & set(d):
        v = d[name]
        if convert_nested and name in convert_nested:
            kw[name] = convert_nested[name](v)
            continue
        tp = hints.get(name, typing.Any)
        try:
            kw[name] = _convert(tp, v)
        except ValueError:
            raise error(f"{where}: field {name!r} must be {_describe(tp)}; got {v!r}"[:300]) from None
    try:
        return cls(**kw)
    except GeofaceError as e:
        raise error(f"{where}: {e}") from None
    except (TypeError, ValueError) as e:
        raise error(f"{where}: {e}") from None


def check_version(meta: dict, supported: int, *, where: str, error: type = CheckpointError, key: str = "version") -> int:
    """The folder's format version: a positive integer no newer than ``supported``."""
    v = meta.get(key, 1)
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise error(f"{where}: {key} must be a positive integer; got {v!r}")
    if v > supported:
        raise error(f"{where}: format version {v} is newer than this geoface reads ({supported}); upgrade geoface")
    return v


def resolve_device(name, error=None):
    """A device name checked: None and "cpu" pass; "cuda" or "cuda:K" only where torch sees that
    GPU. Anything else raises ``error`` (default GeofaceError) with a one-line reason."""
    from geoface.errors import GeofaceError

    error = error or GeofaceError
    if name is None or name == "cpu":
        return name
    if not (name == "cuda" or (name.startswith("cuda:") and name[5:].isdigit())):
        raise error(f"--device must be cpu, cuda or cuda:K; got {name!r}")
    import torch

    if not torch.cuda.is_available():
        raise error(f"--device {name}: torch sees no CUDA GPU on this machine; use --device cpu")
    if ":" in name and int(name[5:]) >= torch.cuda.device_count():
        raise error(f"--device {name}: there are {torch.cuda.device_count()} CUDA devices")
    return name


def check_ranges(obj, *, ints: dict = (), reals: dict = (), error: type = CheckpointError) -> None:
    """Every named field of ``obj`` within its range, else ``error`` naming it: ``ints``
    ``{name: (lo, hi)}`` (integers, not bools), ``reals`` ``{name: (lo, hi, lo_open, hi_open)}``
    (finite numbers)."""
    for name, (lo, hi) in dict(ints).items():
        v = getattr(obj, name)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise error(f"{name} must be an integer in {lo}..{hi}; got {v!r}"[:200])
    for name, (lo, hi, lo_open, hi_open) in dict(reals).items():
        v = getattr(obj, name)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        ok = ok and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
        if not ok:
            raise error(f"{name} must be a number in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}; "
                        f"got {v!r}"[:200])
