"""Visibility buffers: which face of a mesh each pixel of near-orthographic views from all around shows.

The normalized mesh is rasterized (render.rasterize.zbuffer, no back-face culling: orientation-free) from VIEWS
cameras on a Fibonacci sphere, far away with a narrow field of view, into face-id buffers (`render` ->
`Renders`). `Renders.points_seen` tells which views see given points on the surface: a point is seen where it
projects onto background, or lies at most half a pixel (DEPTH_TOLERANCE) behind the plane of the face the
buffer holds at its pixel; `Renders.faces_seen` which views see each face (it covers a pixel centre, or its
centroid is seen). numpy at the boundary, torch inside.

Two users: the fit's visible surface (fit/visible.py: which input faces a viewer sees) and the encoder's
self-check (metrics/unseen.py: which decoded faces no outside view sees).

    renders = render(vertices, faces)                  # Renders: face_id (B,H,W), cameras, tolerance
    seen, _ = renders.faces_seen()                     # (B,F) bool
    pixel = pixel_size(RESOLUTION, bounding_radius(vertices, faces))  # a pixel's world length at the origin
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from tetweave_codec.geometry.triangles import face_normals
from tetweave_codec.render.cameras import fibonacci_cameras
from tetweave_codec.render.rasterize import zbuffer

# Cameras on a Fibonacci sphere, far away with a narrow field of view (near-orthographic), looking at the origin;
# the view cone holds the ball around the origin that holds the input, MARGIN larger.
VIEWS = 32
RESOLUTION = 384
CAMERA_DISTANCE = 20.0
MARGIN = 1.02
VIEW_BATCH = 8  # views rasterized at once (memory: VIEW_BATCH x RESOLUTION^2 x ~40 bytes)
# A face whose centroid lies at most this many pixels (world length at the origin) behind the plane of the face
# the depth buffer holds at its pixel counts as seen there.
DEPTH_TOLERANCE = 0.5
# A point of a face counts as seen (depth test) only in views at least this far from edge-on: |cos| >= MIN_COS.
MIN_COS = 0.3
# Inputs with more faces than this are not rendered (InputError where a caller checks): the per-view arrays would
# exceed memory.
MAX_FACES = 4_000_000
# Renders would exceed this many bytes of buffers per batch: fewer views per batch, then a lower resolution.
MAX_BUFFER_BYTES = 1 << 30


def _fov_deg(radius: float) -> float:
    """Field of view whose cone holds the ball of `radius` (times MARGIN) around the origin."""
    return 2.0 * math.degrees(math.asin(min(MARGIN * radius, 0.5 * CAMERA_DISTANCE) / CAMERA_DISTANCE))


def _cameras(views: int, radius: float):
    """Near-orthographic cameras on a Fibonacci sphere of radius CAMERA_DISTANCE (float32)."""
    return fibonacci_cameras(views, radius=CAMERA_DISTANCE, fov_deg=_fov_deg(radius))


def pixel_size(resolution: int, radius: float) -> float:
    """World length of one pixel at the origin's depth, for an input within `radius` of the origin."""
    return 2.0 * CAMERA_DISTANCE * math.tan(math.radians(_fov_deg(radius)) / 2.0) / resolution


def bounding_radius(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Largest distance from the origin of a vertex that a face uses (at least 1e-3)."""
    return max(float(np.sqrt((vertices[np.unique(faces)] ** 2).sum(axis=1).max())), 1e-3)


@dataclass(frozen=True)
class Renders:
    """Visibility buffers of one mesh: face_id (B,H,W) int64 (-1 background), its vertices (V,3) and faces (F,3),
    the cameras (render.Cameras, float64) and their eyes (B,3), and the depth tolerance tol (world length)."""

    face_id: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    eyes: np.ndarray
    cams: object
    resolution: int
    tol: float

    def points_seen(self, points: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(B,P) bool: whether view b sees the point (P,3) on the surface: it projects onto background, or at most
        `tol` behind the plane of the face the buffer holds at its pixel, that plane extended to the point's exact
        screen position (points of faces smaller than a pixel beside it on the same surface are seen, a wall
        behind it is not). With `normals` (P,3) unit (the point's face), only views that see that face at least
        MIN_COS away from edge-on count: a piece of a face next to a seam, seen edge-on, projects within a pixel
        of the seam's far side although it lies inside the other part."""
        res = self.resolution
        out = np.zeros((len(self.eyes), len(points)), dtype=bool)
        pts = torch.from_numpy(np.ascontiguousarray(points, dtype=np.float64))
        for b in range(len(self.eyes)):
            cam = self.cams[b]
            cx, cy, cz = cam.project_planes(pts, res)[:, 0].numpy()
            px = np.clip(np.floor(cx).astype(np.int64), 0, res - 1)
            py = np.clip(np.floor(cy).astype(np.int64), 0, res - 1)
            buf = self.face_id[b, py, px]
            front = buf >= 0
            tri = self.faces[buf[front]]  # (M,3) the buffer's faces
            if 3 * len(tri) < len(self.vertices):  # project only their corners
                corners = torch.from_numpy(self.vertices[tri.reshape(-1)])
                x, y, z = cam.project_planes(corners, res)[:, 0].numpy().reshape(3, -1, 3)
            else:
                vproj = cam.project_planes(torch.from_numpy(self.vertices), res)[:, 0].numpy()  # (3,V)
                x, y, z = (vproj[k][tri] for k in range(3))  # (M,3) each
            d = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
            d = np.where(np.abs(d) > 1e-12, d, 1e-12)
            qx, qy = cx[front] - x[:, 0], cy[front] - y[:, 0]
            b1 = (qx * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * qy) / d
            b2 = ((x[:, 1] - x[:, 0]) * qy - qx * (y[:, 1] - y[:, 0])) / d
            inv = (1 - b1 - b2) / z[:, 0] + b1 / z[:, 1] + b2 / z[:, 2]  # 1/depth is affine in screen space
            plane = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), np.inf)
            out[b] = ~front
            out[b, front] = cz[front] <= plane + self.tol
            if normals is not None:
                axis = self.cams.rotation[b, 2].numpy()  # the view's forward axis
                out[b] &= np.abs(normals @ axis) >= MIN_COS
        return out

    def faces_seen(self, extra: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(B,F) bool: view b sees face f (covers a pixel centre, or its centroid is seen: `points_seen`), and
        `points_seen` of the points `extra` (P,3) (one pass over the views for both)."""
        centroids = self.vertices[self.faces].mean(axis=1)
        seen = self.points_seen(centroids, face_normals(self.vertices, self.faces))
        extra_seen = self.points_seen(extra) if extra is not None else None
        for b in range(len(seen)):
            ids = self.face_id[b].reshape(-1)
            seen[b, ids[ids >= 0]] = True
        return seen, extra_seen


def render(vertices: np.ndarray, faces: np.ndarray, views: int = VIEWS, resolution: int = RESOLUTION) -> Renders:
    """Visibility buffers of the mesh (normalized frame) from `views` near-orthographic cameras, no culling."""
    radius = bounding_radius(vertices, faces)
    cams = _cameras(views, radius)
    batch = max(1, min(VIEW_BATCH, MAX_BUFFER_BYTES // (16 * resolution * resolution)))
    vt = torch.from_numpy(np.ascontiguousarray(vertices, dtype=np.float32))
    ft = torch.from_numpy(np.ascontiguousarray(faces, dtype=np.int64))
    ids = []
    for start in range(0, views, batch):
        planes = cams[start : start + batch].project_planes(vt, resolution)
        ids.append(zbuffer(planes, ft, resolution, resolution).numpy())
    tol = DEPTH_TOLERANCE * pixel_size(resolution, radius)
    cams = cams.to(dtype=torch.float64)
    return Renders(np.concatenate(ids), vertices, faces, cams.eye.numpy(), cams, resolution, tol)
