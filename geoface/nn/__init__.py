"""Pieces shared by the neural consumers (:mod:`geoface.learn`, :mod:`geoface.splat`).

:mod:`geoface.nn.config` reads saved configurations through one validated path (torch-free).
"""
