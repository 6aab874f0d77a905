"""The avatar contract: model classes found by their config.json's format (no if-chains), one
error class, every verb in geoface/cli."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from geoface.avatar.model_dir import AvatarModel
from geoface.errors import AvatarError, CaptureError, CheckpointError, ModelFolderError

PKG = Path(__file__).resolve().parents[2] / "geoface"


def test_every_avatar_format_has_a_class_that_follows_the_protocol():
    from geoface.drive.avatars import avatar_formats
    from geoface.hfm.model import HFMModel
    from geoface.thgs.model import THGSModel

    formats = avatar_formats()
    assert set(formats) == {HFMModel.FORMAT, THGSModel.FORMAT}
    for fmt, cls in formats.items():
        assert cls.FORMAT == fmt and cls.KIND in ("hfm", "thgs")
        assert isinstance(cls(None), AvatarModel)  # load, save, drive, FORMAT, KIND


def test_a_folder_of_another_format_is_refused_by_name(tmp_path):
    from geoface.drive.avatars import avatar_drive, avatar_kind

    (tmp_path / "config.json").write_text(json.dumps({"format": "geoface-ddpm"}))
    with pytest.raises(AvatarError, match="geoface-hfm-gs.*geoface-thgs"):
        avatar_kind(tmp_path)
    with pytest.raises(AvatarError, match="no readable config.json"):
        avatar_drive(tmp_path / "none", None)


def test_the_error_classes():
    assert issubclass(CaptureError, AvatarError) and issubclass(ModelFolderError, AvatarError)
    assert issubclass(ModelFolderError, CheckpointError)
    from geoface.splat.errors import SplatError

    assert not issubclass(SplatError, AvatarError)  # the splatting core knows nothing of avatars


def test_every_verb_lives_in_geoface_cli():
    stray = [str(p.relative_to(PKG)) for p in PKG.rglob("*.py")
             if (p.name == "cli.py" or p.stem.endswith("_cli")) and p.parent.name != "cli"]
    assert not stray, stray
