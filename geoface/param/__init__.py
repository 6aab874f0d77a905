"""Parameterization of a topological disk onto the unit square: discrete Ricci flow (a conformal
map to a rectangle with chosen corners), optimal transport on power diagrams (a
measure-preserving map with a magnified region), their fold-free completion, and the
distortion measures.

>>> from geoface.synth import square_grid
>>> from geoface.param import ricci_flow_rectangle
>>> V, F = square_grid(6)
>>> r = ricci_flow_rectangle(V, F)
>>> bool(r.converged), round(r.aspect, 2)   # a square: aspect 1 up to discretisation
(True, 1.0)
"""
from .._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports("geoface.param", {
    # conformal: Ricci flow to a rectangle, its corners
    "RicciFlowSolver": "ricci", "RicciFlowResult": "ricci", "ricci_flow_rectangle": "ricci",
    "corner_sets": "corners", "default_corners": "corners", "boundary_arclength": "corners",
    # measure-preserving: optimal transport, power diagrams, the fold-free map
    "measure_preserving_map": "measure", "MeasurePreservingSolver": "measure", "MeasureMapResult": "measure", "area_error": "measure",
    "semi_discrete_ot": "ot", "OTResult": "ot", "power_diagram": "power", "PowerDiagram": "power",
    "convex_combination_map": "foldfree", "FoldFreeResult": "foldfree",
    "area_balanced_map": "balance", "BalancedMap": "balance",
    # how good a map is; baselines to compare with
    "distortion": "metrics", "Distortion": "metrics", "map_distortion": "metrics",
    "harmonic_rectangle": "baselines", "lscm": "baselines", "to_unit_square": "layout",
})
