"""Targets of the fit: mask, depth and normal maps of the input mesh from views on a sphere (paper §4.1, §5.1).

The input is rendered once, up front, from `n_views` Fibonacci-sphere cameras; every iteration of the fit then
compares its current mesh with a fresh subset of these views. Rendering the (possibly million-face) input once is
far cheaper than re-rendering it every iteration, and the renderer chunks it so memory stays bounded.

Normals are made to face the camera: scans and soups are often inconsistently oriented, while the fitted mesh is
always closed and outward-oriented, so its visible side always faces the viewer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from tetweave_codec.render import Cameras, RenderMaps, fibonacci_cameras, render_maps

# Views rendered per call when making targets: bounds peak memory for big inputs.
_TARGET_VIEWS_PER_CALL = 4


@dataclass(frozen=True)
class Targets:
    """Rendered maps of the input mesh.

    cameras: K views. mask (K,H,W) in {0,1} (no antialiasing: a target has no gradient), depth (K,H,W) camera depth,
    0 on background, normals (K,H,W,3) world-space unit normals facing the camera, 0 on background.
    """

    cameras: Cameras
    mask: Tensor
    depth: Tensor
    normals: Tensor

    def __len__(self) -> int:
        return len(self.cameras)

    def select(self, index: Tensor) -> tuple[Cameras, RenderMaps]:
        """The cameras and maps of views `index` (B,) long."""
        return self.cameras[index], RenderMaps(self.mask[index], self.depth[index], self.normals[index])


def render_targets(
    vertices: np.ndarray,
    faces: np.ndarray,
    n_views: int,
    size: int,
    device: torch.device | str = "cpu",
    radius: float = 3.0,
    fov_deg: float = 45.0,
) -> Targets:
    """Render the input mesh (normalized frame) from `n_views` Fibonacci-sphere cameras at `size`² pixels.

    vertices (V,3), faces (F,3): the normalized input. Returns float32 maps on `device`.
    """
    device = torch.device(device)
    verts = torch.as_tensor(np.asarray(vertices), dtype=torch.float32, device=device)
    tris = torch.as_tensor(np.asarray(faces, dtype=np.int64), device=device)
    cameras = fibonacci_cameras(n_views, radius=radius, fov_deg=fov_deg, device=device)
    masks, depths, normals = [], [], []
    with torch.no_grad():
        for start in range(0, n_views, _TARGET_VIEWS_PER_CALL):
            cams = cameras[start : start + _TARGET_VIEWS_PER_CALL]
            maps = render_maps(verts, tris, cams, size, antialias=False)
            rays = cams.pixel_rays(size).to(maps.normals.dtype)
            facing_away = (maps.normals * rays).sum(-1, keepdim=True) > 0
            masks.append(maps.mask)
            depths.append(maps.depth)
            normals.append(torch.where(facing_away, -maps.normals, maps.normals))
    return Targets(cameras, torch.cat(masks), torch.cat(depths), torch.cat(normals))
