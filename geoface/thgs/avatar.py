"""THGS (talking avatars, ``geoface talk``) under the avatar contract (:class:`geoface.avatar.model_dir.AvatarModel`):
what ``geoface.drive`` loads, saves and drives by the ``format`` of a model folder's config.json."""
from __future__ import annotations

from geoface.avatar.model_dir import AvatarAdapter
from geoface.thgs.inference import drive_thgs, load_thgs, save_thgs
from geoface.thgs.model import THGSModel

__all__ = ["THGSAvatar"]


class THGSAvatar(AvatarAdapter):
    """A trained :class:`geoface.thgs.model.THGSModel` as an :class:`~geoface.avatar.model_dir.AvatarModel`."""

    FORMAT, KIND = THGSModel.FORMAT, THGSModel.KIND
    _load, _save, _drive = staticmethod(load_thgs), staticmethod(save_thgs), staticmethod(drive_thgs)
