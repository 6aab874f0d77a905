"""Compiled helpers of :mod:`geoface.mesh` (optional; built by ``setup.py``)."""
