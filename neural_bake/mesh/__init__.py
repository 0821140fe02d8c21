"""Coarse meshes: decimation, marching cubes, UV unwrap, texel rasterisation, tangent frames."""
