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


from .._lazy import lazy_exports

# the head modules are large; they are imported on first use
__getattr__, _lazy_dir, _LAZY_NAMES = lazy_exports("geoface.synth", {
    **dict.fromkeys(["procedural_head", "HeadModel", "HeadIdentity", "HeadExpression", "SynthHead"], "head"),
    **dict.fromkeys(["load_ict_model", "ict_head", "ICTFaceModel", "ICTHead"], "ict"),
})


def __dir__():
    return sorted(set(__all__))


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
