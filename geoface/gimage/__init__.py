"""Geometry images: rasterize position/normal/texture into 16-bit images and back (later issues)."""
