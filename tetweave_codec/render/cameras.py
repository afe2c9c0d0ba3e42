"""Perspective look-at cameras around the normalized object.

Conventions (shared by every stage of the renderer):

- camera space: x to the right, y down, z forward (along the viewing direction), so that the depth of a point
  is its positive z and image rows grow downwards like the pixel rows of a PNG;
- screen space: continuous pixel coordinates, x in [0, W) along a row, y in [0, H) down the image; the centre
  of pixel (row i, column j) is (j + 0.5, i + 0.5);
- `fov_deg` is the vertical field of view; pixels are square, so the horizontal field of view follows from
  W / H.

World +y appears upwards in every image (unless the camera looks straight along y, where world +z is used).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))  # radians between consecutive Fibonacci-sphere samples
WORLD_UP = (0.0, 1.0, 0.0)
FALLBACK_UP = (0.0, 0.0, 1.0)  # used when a camera looks (almost) straight along WORLD_UP
MAX_IMAGE_SIDE = 1 << 15  # pixels; the rasterizer sizes its boxes with float32 log2, exact below 2**16


def image_size(size: int | tuple[int, int]) -> tuple[int, int]:
    """Normalize an image size argument to (H, W); an int means a square image."""
    if isinstance(size, int):
        h = w = size
    else:
        h, w = (int(s) for s in size)
    if not (0 < h <= MAX_IMAGE_SIDE and 0 < w <= MAX_IMAGE_SIDE):
        raise ValueError(f"image sides must be in 1..{MAX_IMAGE_SIDE}, got {size!r}")
    return h, w


@dataclass(frozen=True)
class Cameras:
    """A batch of B pinhole cameras.

    eye (B,3): camera centres in world coordinates.
    rotation (B,3,3): rows are the camera's right, down and forward axes in world coordinates, so that
        x_cam = rotation @ (x_world - eye).
    fov_deg: vertical field of view in degrees, shared by the batch.
    """

    eye: Tensor
    rotation: Tensor
    fov_deg: float = 45.0

    def __len__(self) -> int:
        return self.eye.shape[0]

    def __getitem__(self, index) -> Cameras:
        """A sub-batch (int, slice, index tensor or bool mask); an int keeps the batch dimension."""
        if isinstance(index, int):
            index = slice(index, index + 1 if index != -1 else None)
        return Cameras(self.eye[index], self.rotation[index], self.fov_deg)

    @property
    def device(self) -> torch.device:
        return self.eye.device

    @property
    def dtype(self) -> torch.dtype:
        return self.eye.dtype

    def to(self, device=None, dtype: torch.dtype | None = None) -> Cameras:
        return Cameras(
            self.eye.to(device=device, dtype=dtype), self.rotation.to(device=device, dtype=dtype), self.fov_deg
        )

    def focal(self, height: int) -> float:
        """Focal length in pixels for an image `height` pixels high."""
        return 0.5 * height / math.tan(math.radians(self.fov_deg) / 2.0)

    def world_to_camera(self, points: Tensor) -> Tensor:
        """points (V,3) world -> (B,V,3) camera space (differentiable)."""
        rot = self.rotation.to(points.dtype)
        eye = self.eye.to(points.dtype)
        return torch.einsum("bij,bvj->bvi", rot, points.unsqueeze(0) - eye[:, None, :])

    def project(self, points: Tensor, size: int | tuple[int, int]) -> Tensor:
        """points (V,3) world -> (B,V,3): screen x, screen y in pixels and camera depth z (differentiable).

        Points at or behind the camera plane get meaningless screen coordinates; callers cull them by z.
        """
        return self.project_planes(points, size).permute(1, 2, 0)

    def project_planes(self, points: Tensor, size: int | tuple[int, int]) -> Tensor:
        """`project` with the coordinate first: (3,B,V) screen x, screen y, camera depth (differentiable)."""
        h, w = image_size(size)
        rot = self.rotation.to(points.dtype)
        cam = torch.matmul(rot, points.t()) - (rot @ self.eye.to(points.dtype)[:, :, None])  # (B,3,V)
        f = self.focal(h)
        z = cam[:, 2]
        inv_z = 1.0 / torch.where(z.abs() > 1e-12, z, torch.full_like(z, 1e-12))
        sx = torch.addcmul(torch.full_like(z, 0.5 * w), cam[:, 0], inv_z, value=f)
        sy = torch.addcmul(torch.full_like(z, 0.5 * h), cam[:, 1], inv_z, value=f)
        return torch.stack([sx, sy, z])

    def pixel_rays(self, size: int | tuple[int, int]) -> Tensor:
        """World-space directions (B,H,W,3) through the pixel centres, scaled so that their camera z is 1.

        A pixel at camera depth d sees the world point eye + d * ray.
        """
        h, w = image_size(size)
        f = self.focal(h)
        dev, dt = self.device, self.dtype
        xs = (torch.arange(w, device=dev, dtype=dt) + 0.5 - 0.5 * w) / f
        ys = (torch.arange(h, device=dev, dtype=dt) + 0.5 - 0.5 * h) / f
        one = torch.ones((), device=dev, dtype=dt)
        cam = torch.stack(torch.broadcast_tensors(xs[None, :], ys[:, None], one), dim=-1)  # (H,W,3)
        return torch.einsum("hwj,bjk->bhwk", cam, self.rotation)

    def backproject(self, depth: Tensor) -> Tensor:
        """depth (B,H,W) camera depths -> world points (B,H,W,3) seen at the pixel centres."""
        rays = self.pixel_rays(tuple(depth.shape[1:])).to(depth.dtype)
        return self.eye.to(depth.dtype)[:, None, None, :] + depth[..., None] * rays


def look_at_cameras(eyes: Tensor, target=(0.0, 0.0, 0.0), fov_deg: float = 45.0) -> Cameras:
    """Cameras at `eyes` (B,3) looking at `target` (3,), world +y up in the image."""
    eyes = torch.as_tensor(eyes)
    target = torch.as_tensor(target, dtype=eyes.dtype, device=eyes.device)
    forward = target - eyes
    forward = forward / forward.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    up = torch.tensor(WORLD_UP, dtype=eyes.dtype, device=eyes.device).expand_as(forward)
    right = torch.linalg.cross(forward, up, dim=-1)
    degenerate = right.norm(dim=-1) < 1e-6
    if bool(degenerate.any()):
        alt = torch.tensor(FALLBACK_UP, dtype=eyes.dtype, device=eyes.device).expand_as(forward)
        right = torch.where(degenerate[:, None], torch.linalg.cross(forward, alt, dim=-1), right)
    right = right / right.norm(dim=-1, keepdim=True)
    down = torch.linalg.cross(forward, right, dim=-1)
    return Cameras(eyes, torch.stack([right, down, forward], dim=1), float(fov_deg))


def fibonacci_cameras(
    n: int, radius: float = 3.0, fov_deg: float = 45.0, device=None, dtype: torch.dtype = torch.float32
) -> Cameras:
    """n cameras spread evenly on a sphere of `radius` around the origin (Fibonacci lattice), looking at it.

    Deterministic: the same n always gives the same views (computed in float64, then cast).
    """
    if n <= 0:
        raise ValueError(f"need at least one camera, got {n}")
    i = torch.arange(n, dtype=torch.float64)
    y = 1.0 - (2.0 * i + 1.0) / n
    r = torch.sqrt((1.0 - y * y).clamp_min(0.0))
    phi = i * GOLDEN_ANGLE
    eyes = torch.stack([r * torch.cos(phi), y, r * torch.sin(phi)], dim=-1) * radius
    return look_at_cameras(eyes, fov_deg=fov_deg).to(device=device, dtype=dtype)
