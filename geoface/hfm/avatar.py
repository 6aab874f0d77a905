"""HFM-GS (headset removal, ``geoface hmd``) under the avatar contract (:class:`geoface.avatar.model_dir.AvatarModel`):
what ``geoface.drive`` loads, saves and drives by the ``format`` of a model folder's config.json."""
from __future__ import annotations

from geoface.avatar.model_dir import AvatarDrive
from geoface.hfm.io import load_hfm, save_hfm
from geoface.hfm.usage import drive_hfm
from geoface.hfm.model import HFMModel

__all__ = ["HFMAvatar"]


class HFMAvatar:
    """A trained :class:`geoface.hfm.model.HFMModel` as an :class:`~geoface.avatar.model_dir.AvatarModel`."""

    FORMAT = HFMModel.FORMAT
    KIND = HFMModel.KIND

    def __init__(self, model: HFMModel):
        self.model = model

    @classmethod
    def load(cls, model_dir) -> "HFMAvatar":
        return cls(load_hfm(model_dir))

    def save(self, out_dir) -> None:
        save_hfm(self.model, out_dir)

    def drive(self, source, *, fps: float = 25.0) -> AvatarDrive:
        return drive_hfm(self.model, source, fps=fps)
