"""Analytic surfaces with known answers and a procedural, expressive, textured head."""

from .surfaces import (
    cylinder,
    disk_grid,
    genus2,
    hemisphere,
    irregular_flat_patch,
    mobius_strip,
    punch_holes,
    sphere,
    spherical_cap,
    square_grid,
    torus,
)


def __getattr__(name):  # the head module is large; import it on first use
    if name in {"procedural_head", "HeadModel", "HeadIdentity", "HeadExpression", "SynthHead"}:
        from . import head

        return getattr(head, name)
    raise AttributeError(f"module 'geoface.synth' has no attribute {name!r}")


__all__ = [
    "HeadExpression",
    "HeadIdentity",
    "HeadModel",
    "SynthHead",
    "cylinder",
    "disk_grid",
    "genus2",
    "hemisphere",
    "irregular_flat_patch",
    "mobius_strip",
    "procedural_head",
    "punch_holes",
    "sphere",
    "spherical_cap",
    "square_grid",
    "torus",
]
