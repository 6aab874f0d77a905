"""THGS (talking avatars, ``geoface talk``) under the avatar contract (:class:`geoface.avatar.model_dir.AvatarModel`):
what ``geoface.drive`` loads, saves and drives by the ``format`` of a model folder's config.json."""
from __future__ import annotations

from geoface.avatar.model_dir import AvatarDrive
from geoface.thgs.inference import drive_thgs, load_thgs, save_thgs
from geoface.thgs.model import THGSModel

__all__ = ["THGSAvatar"]


class THGSAvatar:
    """A trained :class:`geoface.thgs.model.THGSModel` as an :class:`~geoface.avatar.model_dir.AvatarModel`."""

    FORMAT = THGSModel.FORMAT
    KIND = THGSModel.KIND

    def __init__(self, model: THGSModel):
        self.model = model

    @classmethod
    def load(cls, model_dir) -> "THGSAvatar":
        return cls(load_thgs(model_dir))

    def save(self, out_dir) -> None:
        save_thgs(self.model, out_dir)

    def drive(self, source, *, fps: float = 25.0) -> AvatarDrive:
        return drive_thgs(self.model, source, fps=fps)
