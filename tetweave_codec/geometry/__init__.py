"""The geometry core: spherical harmonics, Delaunay tetrahedralization, directional marching tetrahedra, tet helpers.

numpy/torch functions over arrays with shapes in their docstrings; no training, I/O or container logic here.
The decoder uses only `sh`, `delaunay` and `marching_tets.marching_tets_numpy` (no torch import on that path).
"""
