"""Synthetic skin: PBR maps with facial regions on a head's UV layout (:mod:`.regions`,
:mod:`.render`) and their rendering under lights — the data of the texture model
(:mod:`geoface.texture.model`) and of the avatar captures (:mod:`geoface.hfm.ict`).

Numpy only; the layer sits above :mod:`geoface.nn` (it rasterises with
:func:`geoface.nn.mesh_render.rasterize_mesh`) and below ``learn`` and ``splat``.
"""
from geoface.errors import GeofaceError

__all__ = ["SkinError"]


class SkinError(GeofaceError):
    """An invalid argument to the skin generator or renderer."""
