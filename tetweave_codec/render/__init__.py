"""Differentiable offscreen renderer in plain torch (rasterize -> interpolate -> antialias)."""

from tetweave_codec.geometry.triangles import face_normals

from .antialias import MeshEdges, antialias, mesh_edges
from .cameras import Cameras, fibonacci_cameras, look_at_cameras
from .interpolate import perspective_barycentrics, vertex_normals
from .maps import RenderMaps, render_maps
from .rasterize import Fragments, rasterize
from .shading import image_grid, save_png, shade

__all__ = [
    "Cameras",
    "Fragments",
    "MeshEdges",
    "RenderMaps",
    "antialias",
    "face_normals",
    "fibonacci_cameras",
    "image_grid",
    "look_at_cameras",
    "mesh_edges",
    "perspective_barycentrics",
    "rasterize",
    "render_maps",
    "save_png",
    "shade",
    "vertex_normals",
]
