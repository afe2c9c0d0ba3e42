"""Differentiable offscreen renderer in plain torch (rasterize -> interpolate -> antialias)."""
