"""Shaded previews for people: Lambert or normal-map colours, image grids, PNG output."""

from __future__ import annotations

import io
import math
import os

import numpy as np
import torch
from torch import Tensor

from .cameras import Cameras
from .maps import RenderMaps

SHADING_MODES = ("lambert", "normals")
LIGHT_CAMERA = (-0.4, -0.6, -1.0)  # headlight from the upper left; camera space (x right, y down, z forward)
LIGHT_WORLD = (0.3, 0.8, 0.5)  # used when no cameras are given
ALBEDO = (0.78, 0.80, 0.84)  # light grey, slightly cool
AMBIENT = 0.18
BACKGROUND = (255, 255, 255)


def shade(
    maps: RenderMaps,
    cameras: Cameras | None = None,
    mode: str = "lambert",
    background: tuple[int, int, int] = BACKGROUND,
) -> Tensor:
    """Colour rendered maps for viewing: uint8 images (B,H,W,3), antialiased against `background`.

    mode "lambert": diffuse grey lit by a headlight (relative to each camera when `cameras` is given,
    otherwise a fixed world direction); back faces of open meshes come out dark, showing their orientation.
    mode "normals": world-space normals mapped from [-1, 1] to [0, 255] per channel.
    """
    if mode not in SHADING_MODES:
        raise ValueError(f"shading mode must be one of {SHADING_MODES}, got {mode!r}")
    with torch.no_grad():
        mask = maps.mask.detach().float().clamp(0.0, 1.0)[..., None]  # (B,H,W,1)
        n = maps.normals.detach().float()
        n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)  # undo silhouette blending towards 0
        if mode == "normals":
            colour = (n + 1.0) * 0.5
        else:
            if cameras is not None:
                light = torch.tensor(LIGHT_CAMERA, dtype=torch.float32, device=n.device)
                light = torch.einsum("j,bjk->bk", light / light.norm(), cameras.rotation.to(n))  # (B,3) world
            else:
                light = torch.tensor(LIGHT_WORLD, dtype=torch.float32, device=n.device)
                light = (light / light.norm()).expand(n.shape[0], 3)
            lambert = (n * light[:, None, None, :]).sum(-1, keepdim=True).clamp_min(0.0)
            albedo = torch.tensor(ALBEDO, dtype=torch.float32, device=n.device)
            colour = albedo * (AMBIENT + (1.0 - AMBIENT) * lambert)
        bg = torch.tensor(background, dtype=torch.float32, device=n.device) / 255.0
        image = mask * colour + (1.0 - mask) * bg
        return (image * 255.0).round().clamp(0, 255).to(torch.uint8).cpu()


def image_grid(
    images: Tensor | np.ndarray, cols: int | None = None, pad: int = 4, background: tuple[int, int, int] = BACKGROUND
) -> np.ndarray:
    """Tile images (B,H,W,3) uint8 into one (rows*H + pad*(rows+1), cols*W + pad*(cols+1), 3) uint8 image.

    cols defaults to ceil(sqrt(B)); empty cells are filled with `background`.
    """
    images = images.cpu().numpy() if isinstance(images, Tensor) else np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images must be (B,H,W,3), got {images.shape}")
    b, h, w, _ = images.shape
    cols = max(1, min(cols or math.ceil(math.sqrt(b)), b))
    rows = math.ceil(b / cols)
    grid = np.empty((rows * h + pad * (rows + 1), cols * w + pad * (cols + 1), 3), dtype=np.uint8)
    grid[:] = np.asarray(background, dtype=np.uint8)
    for i in range(b):
        r, c = divmod(i, cols)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        grid[y : y + h, x : x + w] = images[i]
    return grid


def save_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an (H,W,3) uint8 image as PNG, atomically (temporary file in the same folder, then rename)."""
    from PIL import Image

    from tetweave_codec.meshio import write_bytes_atomic

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8), mode="RGB").save(buf, format="PNG")
    write_bytes_atomic(path, buf.getvalue())
