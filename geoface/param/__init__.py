"""Parameterization: discrete Ricci flow to a rectangle and optimal-transport maps (later issues)."""
