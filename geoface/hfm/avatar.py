"""HFM-GS (headset removal, ``geoface hmd``) under the avatar contract (:class:`geoface.avatar.model_dir.AvatarModel`):
what ``geoface.drive`` loads, saves and drives by the ``format`` of a model folder's config.json."""
from __future__ import annotations

from geoface.avatar.model_dir import AvatarAdapter
from geoface.hfm.io import load_hfm, save_hfm
from geoface.hfm.usage import drive_hfm
from geoface.hfm.model import HFMModel

__all__ = ["HFMAvatar"]


class HFMAvatar(AvatarAdapter):
    """A trained :class:`geoface.hfm.model.HFMModel` as an :class:`~geoface.avatar.model_dir.AvatarModel`."""

    FORMAT, KIND = HFMModel.FORMAT, HFMModel.KIND
    _load, _save, _drive = staticmethod(load_hfm), staticmethod(save_hfm), staticmethod(drive_hfm)
