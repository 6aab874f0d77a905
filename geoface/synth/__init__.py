"""Analytic surfaces with known answers, a procedural, expressive, textured head, and real heads
of the ICT-FaceKit morphable model (``load_ict_model``, ``ict_head``)."""

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


def __getattr__(name):  # the head modules are large; import them on first use
    if name in {"procedural_head", "HeadModel", "HeadIdentity", "HeadExpression", "SynthHead"}:
        from . import head

        return getattr(head, name)
    if name in {"load_ict_model", "ict_head", "ICTFaceModel", "ICTHead"}:
        from . import ict

        return getattr(ict, name)
    raise AttributeError(f"module 'geoface.synth' has no attribute {name!r}")


__all__ = [
    "ICTFaceModel",
    "ICTHead",
    "load_ict_model",
    "ict_head",
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
