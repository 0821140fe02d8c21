"""Baking: per-vertex and per-texel normals and colours, padding, export, baseline, quality report."""
