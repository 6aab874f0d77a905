"""Facial regions on the ICT-FaceKit UV layout: moved to :mod:`geoface.skin.regions` (kept
importable from here)."""
from geoface.skin.regions import *  # noqa: F401,F403
from geoface.skin.regions import REGION_NAMES, ict_uv_regions, landmark_uv  # noqa: F401
