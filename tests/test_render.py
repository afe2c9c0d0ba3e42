"""Tests of the differentiable renderer (tetweave_codec.render): analytic shapes, occlusion, gradients.

Every test runs on the CPU and, when a GPU is present, again on CUDA (skipped otherwise).
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
import torch
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec.render import (
    Cameras,
    fibonacci_cameras,
    image_grid,
    look_at_cameras,
    mesh_edges,
    rasterize,
    render_maps,
    save_png,
    shade,
)

rasterize_module = sys.modules["tetweave_codec.render.rasterize"]

DEVICES = [
    "cpu",
    pytest.param(
        "cuda", marks=[pytest.mark.cuda, pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")]
    ),
]


@pytest.fixture(params=DEVICES)
def device(request) -> torch.device:
    return torch.device(request.param)


def _sphere(subdivisions: int, radius: float, device, dtype=torch.float64):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return (
        torch.tensor(m.vertices, dtype=dtype, device=device),
        torch.tensor(m.faces, dtype=torch.long, device=device),
    )


def _front_camera(device, dtype=torch.float64, distance: float = 3.0) -> Cameras:
    return look_at_cameras(torch.tensor([[0.0, 0.0, distance]], dtype=dtype), fov_deg=45.0).to(device)


# ------------------------------------------------------------ cameras


def test_fibonacci_cameras_look_at_the_origin_from_the_sphere(device):
    cams = fibonacci_cameras(6, radius=3.0, device=device, dtype=torch.float64)
    assert cams.eye.shape == (6, 3) and cams.rotation.shape == (6, 3, 3)
    assert torch.allclose(cams.eye.norm(dim=1), torch.full((6,), 3.0, dtype=torch.float64, device=device))
    eye_r = torch.eye(3, dtype=torch.float64, device=device).expand(6, 3, 3)
    assert torch.allclose(cams.rotation @ cams.rotation.transpose(1, 2), eye_r, atol=1e-12)
    assert torch.allclose(torch.linalg.det(cams.rotation), torch.ones(6, dtype=torch.float64, device=device))
    # forward axis points from the eye to the origin
    assert torch.allclose(cams.rotation[:, 2], -cams.eye / 3.0, atol=1e-12)
    # all distinct, deterministic
    assert torch.cdist(cams.eye, cams.eye).add(torch.eye(6, device=device, dtype=torch.float64)).min() > 0.5
    assert torch.equal(cams.eye, fibonacci_cameras(6, device=device, dtype=torch.float64).eye)


def test_world_up_appears_up_and_right_appears_right(device):
    cams = _front_camera(device)
    pts = torch.tensor([[0, 0, 0], [0, 0.5, 0], [0.5, 0, 0]], dtype=torch.float64, device=device)
    p = cams.project(pts, 64)[0]
    assert p[0, 0].item() == pytest.approx(32.0) and p[0, 1].item() == pytest.approx(32.0)
    assert p[1, 1] < p[0, 1]  # world +y: up in the image (smaller row)
    assert p[2, 0] > p[0, 0]  # world +x seen from +z: right
    assert p[0, 2].item() == pytest.approx(3.0)
    # a camera straight above still gets a valid frame
    top = look_at_cameras(torch.tensor([[0.0, 3.0, 0.0]], dtype=torch.float64))
    assert torch.allclose(torch.linalg.det(top.rotation), torch.ones(1, dtype=torch.float64))


def test_cameras_index_like_a_sequence():
    a = fibonacci_cameras(5, radius=2.5)
    assert torch.allclose(a.eye.norm(dim=1), torch.full((5,), 2.5), atol=1e-5)
    assert len(a[1:3]) == 2 and len(a[0]) == 1
    assert torch.equal(a[1:3].eye, a.eye[1:3]) and torch.equal(a[torch.tensor([4, 0])].eye, a.eye[[4, 0]])


# ------------------------------------------------------------ analytic


def test_depth_of_a_tilted_plane_matches_ray_intersection(device):
    """A big tilted quad: depth and barycentric reconstruction against the analytic ray-plane intersection."""
    cams = _front_camera(device)
    normal = torch.tensor([0.3, -0.2, 1.0], dtype=torch.float64)
    normal = normal / normal.norm()
    u = torch.linalg.cross(normal, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    u = u / u.norm()
    v = torch.linalg.cross(normal, u)
    centre = torch.tensor([0.05, -0.02, 0.1], dtype=torch.float64)
    quad = torch.stack([centre + 4 * (su * u + sv * v) for su, sv in [(-1, -1), (1, -1), (1, 1), (-1, 1)]])
    verts = quad.to(device)
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]], device=device)
    size = (40, 56)  # non-square on purpose
    frags = rasterize(verts, faces, cams, size)
    assert bool((frags.face_id >= 0).all())  # the quad covers the whole image
    rays = cams.pixel_rays(size)[0]  # (H,W,3), camera z = 1
    eye = cams.eye[0]
    n = normal.to(device)
    expected = ((centre.to(device) - eye) @ n) / (rays @ n)
    assert torch.allclose(frags.depth[0], expected, rtol=1e-9, atol=1e-9)
    maps = render_maps(verts, faces, cams, size)
    assert torch.allclose(maps.depth[0], expected, rtol=1e-9, atol=1e-9)
    assert torch.allclose(maps.mask, torch.ones_like(maps.mask))
    assert torch.allclose(maps.normals[0], n.expand(*size, 3), atol=1e-12)
    # barycentrics reproduce the surface point seen through each pixel centre
    pts = (frags.bary[0][..., None] * verts[faces[frags.face_id[0]]]).sum(-2)
    assert torch.allclose(pts, cams.backproject(frags.depth)[0], atol=1e-9)


@pytest.mark.parametrize("size", [48, 96])
def test_sphere_silhouette_area_matches_projected_disc(device, size):
    """A finely tessellated sphere seen from 4 directions covers the analytic disc (perspective: angular
    radius asin(r/d)); the antialiased mask sum is closer to the continuous area than the pixel count."""
    radius = 0.8
    verts, faces = _sphere(5, radius, device)
    cams = fibonacci_cameras(4, device=device, dtype=torch.float64)
    maps = render_maps(verts, faces, cams, size)
    disc = math.pi * (cams.focal(size) * math.tan(math.asin(radius / 3.0))) ** 2
    covered = (maps.fragments.face_id >= 0).sum(dim=(1, 2)).double()
    aa = maps.mask.sum(dim=(1, 2))
    # the icosphere is inscribed: its outline is at least r cos(half the edge angle) ~ 0.9997 r
    assert torch.all((covered - disc).abs() < 2.0 * math.sqrt(disc))
    assert torch.all((aa - disc).abs() < 0.004 * disc + 1.0)
    assert torch.all((aa - disc).abs() < (covered - disc).abs() + 0.5)
    # depth at the image centre: the sphere's nearest point
    c = size // 2
    centre_depth = maps.depth[:, c - 1 : c + 1, c - 1 : c + 1]
    assert torch.allclose(centre_depth, torch.full_like(centre_depth, 3.0 - radius), atol=2e-3)


def test_occlusion_of_overlapping_triangles(device):
    cams = _front_camera(device)
    near = [[-0.5, -0.5, 0.3], [0.5, -0.5, 0.3], [0.0, 0.5, 0.3]]  # closer to the camera at z = 3
    far = [[-0.3, -0.6, -0.2], [0.7, -0.6, -0.2], [0.2, 0.4, -0.2]]
    for order in ([near, far], [far, near]):
        verts = torch.tensor(order[0] + order[1], dtype=torch.float64, device=device)
        faces = torch.tensor([[0, 1, 2], [3, 4, 5]], device=device)
        near_id = 0 if order[0] is near else 1
        frags = rasterize(verts, faces, cams, 64)
        fid = frags.face_id[0]
        # rasterize each triangle alone to know where it lies
        alone = [rasterize(verts, faces[i : i + 1], cams, 64).face_id[0] >= 0 for i in range(2)]
        both = alone[0] & alone[1]
        assert both.sum() > 100 and (alone[0] ^ alone[1]).sum() > 100
        assert bool((fid[both] == near_id).all())
        assert bool((fid[alone[1 - near_id] & ~both] == 1 - near_id).all())
        assert bool((fid[~alone[0] & ~alone[1]] == -1).all())
        near_depth = frags.depth[0][fid == near_id]
        assert torch.allclose(near_depth, torch.full_like(near_depth, 2.7))


def test_triangles_behind_or_crossing_the_camera_are_culled(device):
    cams = _front_camera(device)
    verts = torch.tensor(
        [
            [-1, -1, 4.0],
            [1, -1, 4.0],
            [0, 1, 4.0],  # behind the eye (z = 3)
            [-1, -1, 3.5],
            [1, -1, 2.0],
            [0, 1, 2.0],  # crosses the camera plane
            [-0.2, -0.2, 0.0],
            [0.2, -0.2, 0.0],
            [0.0, 0.2, 0.0],
        ],
        dtype=torch.float64,
        device=device,
    )
    faces = torch.tensor([[0, 1, 2], [3, 4, 5], [6, 7, 8]], device=device)
    maps = render_maps(verts, faces, cams, 32)
    ids = maps.fragments.face_id.unique().tolist()
    assert set(ids) == {-1, 2}
    assert torch.isfinite(maps.depth).all() and torch.isfinite(maps.normals).all()


def test_background_stays_background(device):
    verts, faces = _sphere(3, 0.6, device)
    cams = fibonacci_cameras(3, device=device, dtype=torch.float64)
    maps = render_maps(verts, faces, cams, 40, normals="smooth")
    covered = (maps.fragments.face_id >= 0).double()
    # pixels with no covered pixel within 1 (4-neighbourhood) stay exactly zero in every map
    grown = torch.nn.functional.max_pool2d(covered[:, None], 3, stride=1, padding=1)[:, 0]
    far = grown == 0
    assert far.sum() > 1000
    assert maps.mask[far].abs().max() == 0 and maps.depth[far].abs().max() == 0
    assert maps.normals[far].abs().max() == 0
    # empty meshes and meshes outside the view render as background
    empty = render_maps(verts, faces[:0], cams, 16)
    assert empty.mask.abs().sum() == 0 and (empty.fragments.face_id == -1).all()
    away = render_maps(verts + 10.0, faces, cams, 16)
    assert away.mask.abs().sum() == 0


def test_flat_normals_point_outward_on_the_visible_side(device):
    verts, faces = _sphere(3, 0.8, device)
    cams = fibonacci_cameras(2, device=device, dtype=torch.float64)
    for mode in ("flat", "smooth"):
        maps = render_maps(verts, faces, cams, 32, antialias=False, normals=mode)
        inside = maps.fragments.face_id >= 0
        pts = cams.backproject(maps.depth)
        n = maps.normals[inside]
        assert torch.allclose(n.norm(dim=-1), torch.ones_like(n[:, 0]))
        radial = pts[inside] / pts[inside].norm(dim=-1, keepdim=True)
        assert (n * radial).sum(-1).min() > (0.95 if mode == "flat" else 0.999)


# ------------------------------------------------------------ z-buffer

# Pixels whose centre is this close to a triangle's edge may go either way between float32 and float64.
EDGE_TIE = 1e-3


def _reference_face_ids(
    verts: torch.Tensor, faces: torch.Tensor, cams: Cameras, size: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Brute force in float64 numpy: every pixel centre against every triangle.

    Returns the nearest face id (size,size) (-1: none), the two nearest depths (size,size,2) and whether the
    centre lies within EDGE_TIE pixels of some triangle's edge (size,size), where float32 may decide otherwise."""
    proj = cams.to(dtype=torch.float64).project(verts.double(), size).cpu().numpy()[0]  # (V,3)
    tri = proj[faces.cpu().numpy()]  # (F,3,3)
    ys, xs = np.mgrid[0:size, 0:size] + 0.5
    p = np.stack([xs.ravel(), ys.ravel()], 1)[:, None, :]  # (P,1,2)
    a, b, c = tri[None, :, 0, :2], tri[None, :, 1, :2], tri[None, :, 2, :2]

    def cross(u, v, q):
        d, r = v - u, q - u
        return d[..., 0] * r[..., 1] - d[..., 1] * r[..., 0]

    e0, e1, e2 = cross(b, c, p), cross(c, a, p), cross(a, b, p)
    area = e0 + e1 + e2
    inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
    inside &= (np.abs(area) > 0) & (tri[None, :, :, 2].min(-1) > 1e-2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = (e0 / tri[None, :, 0, 2] + e1 / tri[None, :, 1, 2] + e2 / tri[None, :, 2, 2]) / area
    z = np.where(inside, 1.0 / inv_z, np.inf)
    z = np.concatenate([z, np.full_like(z[:, :1], np.inf)], axis=1)  # so that there are always two layers
    best = z.argmin(1)
    ids = np.where(np.isfinite(z.min(1)), best, -1).reshape(size, size)
    # signed distance (pixels) of the centre to each edge line, positive inside; near an edge of the triangle
    lengths = [np.linalg.norm(c - b, axis=-1), np.linalg.norm(a - c, axis=-1), np.linalg.norm(b - a, axis=-1)]
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.stack([e * np.sign(area) / ln for e, ln in zip((e0, e1, e2), lengths, strict=True)], -1)
    near_edge = ((np.abs(dist) < EDGE_TIE).any(-1) & (dist > -EDGE_TIE).all(-1)).any(1).reshape(size, size)
    return ids, np.sort(z, 1)[:, :2].reshape(size, size, 2), near_edge


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_tri=st.integers(1, 12))
def test_zbuffer_matches_brute_force_on_random_triangle_soups(seed, n_tri):
    g = np.random.default_rng(seed)
    verts = torch.tensor(g.uniform(-1.0, 1.0, (3 * n_tri, 3)), dtype=torch.float64)
    faces = torch.arange(3 * n_tri).view(n_tri, 3)
    direction = g.normal(size=(1, 3))
    cams = look_at_cameras(torch.tensor(2.8 * direction / np.linalg.norm(direction)))
    size = 24
    got = rasterize(verts, faces, cams, size).face_id[0].numpy()
    want, depths, near_edge = _reference_face_ids(verts, faces, cams, size)
    # ignore pixels where the two nearest surfaces are within float32 resolution, or a centre sits on an edge
    # (seed 34731, 8 triangles: two centres 1e-4 px from an edge, covered in float32, not in float64)
    tie = np.isfinite(depths[..., 1]) & (depths[..., 1] - depths[..., 0] < 1e-5 * depths[..., 0]) | near_edge
    differ = (got != want) & ~tie
    assert differ.sum() <= 1, f"{differ.sum()} pixels differ"


def test_closed_mesh_has_no_pinholes_and_culling_agrees(device):
    """A closed mesh covers every pixel inside its outline; back-face culling changes nothing."""
    verts, faces = _sphere(4, 0.8, device, dtype=torch.float32)
    cams = fibonacci_cameras(4, device=device)
    a = rasterize(verts, faces, cams, 128)
    b = rasterize(verts, faces, cams, 128, cull_backfaces=True)
    assert torch.equal(a.face_id, b.face_id)
    r = cams.focal(128) * math.tan(math.asin(0.78 / 3.0))  # a little inside the outline
    ys, xs = torch.meshgrid(torch.arange(128) + 0.5, torch.arange(128) + 0.5, indexing="ij")
    disc = ((xs - 64) ** 2 + (ys - 64) ** 2 < r * r).to(device)
    assert bool((a.face_id[:, disc] >= 0).all())


def test_automatic_backface_culling_only_for_closed_outward_meshes(device):
    from tetweave_codec.render.maps import closed_outward

    verts, faces = _sphere(3, 0.8, device)
    assert closed_outward(verts, faces, mesh_edges(faces))
    flipped = faces[:, [0, 2, 1]]
    assert not closed_outward(verts, flipped, mesh_edges(flipped))  # inward normals: back faces are visible
    assert not closed_outward(verts, faces[1:], mesh_edges(faces[1:]))  # a hole
    cams = fibonacci_cameras(3, device=device, dtype=torch.float64)
    for f in (faces, flipped, faces[1:]):
        auto = render_maps(verts, f, cams, 48)
        plain = render_maps(verts, f, cams, 48, cull_backfaces=False)
        assert torch.equal(auto.fragments.face_id, plain.fragments.face_id)
        assert torch.equal(auto.mask, plain.mask) and torch.equal(auto.depth, plain.depth)


def test_views_render_independently_of_their_batch(device):
    """More views than fit in one facing bit mask (52): same maps as rendering the views in small batches."""
    verts, faces = _sphere(2, 0.8, device)
    verts = verts * torch.tensor([1.0, 0.7, 0.5], dtype=torch.float64, device=device)
    cams = fibonacci_cameras(56, device=device, dtype=torch.float64)
    all_views = render_maps(verts, faces, cams, 20)
    for part in (slice(0, 5), slice(50, 56)):
        some = render_maps(verts, faces, cams[part], 20)
        assert torch.equal(all_views.fragments.face_id[part], some.fragments.face_id)
        # Same pixels and blends; vectorized float64 sums over differently sized batches may differ in the last
        # bit (seen: 1.8e-15 on 4 of 2,000 pixels with torch 2.13 on this CPU), far below any cross-talk.
        torch.testing.assert_close(all_views.mask[part], some.mask, rtol=0, atol=1e-12)
        torch.testing.assert_close(all_views.normals[part], some.normals, rtol=0, atol=1e-12)


def test_chunking_does_not_change_the_image(device, monkeypatch):
    verts, faces = _sphere(3, 0.8, device, dtype=torch.float32)
    verts = torch.cat([verts, verts * 0.5 + 0.3])  # two overlapping spheres
    faces = torch.cat([faces, faces + verts.shape[0] // 2])
    cams = fibonacci_cameras(3, device=device)
    ref = rasterize(verts, faces, cams, 96)
    monkeypatch.setattr(rasterize_module, "FACE_CHUNK", 257)
    monkeypatch.setattr(rasterize_module, "CANDIDATE_CHUNK", 64)
    small = rasterize(verts, faces, cams, 96)
    assert torch.equal(ref.face_id, small.face_id)
    assert torch.equal(ref.depth, small.depth)


def test_ordered_row_sums_match_index_add():
    from tetweave_codec.render.antialias import add_rows

    g = torch.Generator().manual_seed(5)
    base = torch.rand(50, 3, generator=g, dtype=torch.float64, requires_grad=True)
    index = torch.randint(0, 50, (400,), generator=g)
    rows = torch.rand(400, 3, generator=g, dtype=torch.float64, requires_grad=True)
    plain = add_rows(base, index, rows, ordered=False)
    ordered = add_rows(base, index, rows, ordered=True)
    assert torch.allclose(plain, ordered, atol=1e-12)
    assert torch.equal(ordered, add_rows(base, index, rows, ordered=True))
    (g1, g2) = torch.autograd.grad(ordered.square().sum(), (base, rows))
    (h1, h2) = torch.autograd.grad(plain.square().sum(), (base, rows))
    assert torch.allclose(g1, h1) and torch.allclose(g2, h2)


def test_repeated_runs_are_identical(device):
    verts, faces = _sphere(3, 0.8, device, dtype=torch.float32)
    verts = verts.clone().requires_grad_(True)
    cams = fibonacci_cameras(4, device=device)
    first = render_maps(verts, faces, cams, 64, normals="smooth")
    grads = []
    for _ in range(2):
        maps = render_maps(verts, faces, cams, 64, normals="smooth")
        for a, b in ((first.mask, maps.mask), (first.depth, maps.depth), (first.normals, maps.normals)):
            assert torch.equal(a, b)
        assert torch.equal(first.fragments.face_id, maps.fragments.face_id)
        (g,) = torch.autograd.grad((maps.mask + maps.depth + maps.normals.sum(-1)).sum(), verts)
        grads.append(g)
    if device.type == "cpu":
        assert torch.equal(grads[0], grads[1])
    else:  # gradients are summed with atomics on GPUs: equal up to the order of float additions
        assert torch.allclose(grads[0], grads[1], rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------ gradients


def _fd_check(loss_fn, verts: torch.Tensor, rows: torch.Tensor, eps: float = 1e-6, rtol: float = 1e-5):
    """Central differences of loss_fn at `verts` for the coordinates of vertices `rows` vs autograd."""
    v = verts.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(loss_fn(v), v)
    scale = grad.abs().max().item()
    assert scale > 0
    for i in rows.tolist():
        for c in range(3):
            vp, vm = verts.clone(), verts.clone()
            vp[i, c] += eps
            vm[i, c] -= eps
            fd = (loss_fn(vp) - loss_fn(vm)).item() / (2 * eps)
            assert fd == pytest.approx(grad[i, c].item(), abs=rtol * scale), (i, c)
    return grad


def _bumpy_sphere(device):
    verts, faces = _sphere(2, 0.7, device)
    g = torch.Generator().manual_seed(1)
    bumps = torch.rand(verts.shape[0], 1, generator=g, dtype=torch.float64).to(device)
    return verts * (1.0 + 0.1 * bumps), faces


@pytest.mark.parametrize("normals", ["flat", "smooth"])
def test_depth_and_normal_losses_match_finite_differences(device, normals):
    verts, faces = _bumpy_sphere(device)
    cams = fibonacci_cameras(2, device=device, dtype=torch.float64)
    size = 40
    frags = rasterize(verts, faces, cams, size)  # visibility held fixed, as autograd sees it
    g = torch.Generator().manual_seed(0)
    wd = torch.rand(2, size, size, generator=g, dtype=torch.float64).to(device)
    wn = torch.rand(2, size, size, 3, generator=g, dtype=torch.float64).to(device)
    visible = faces[frags.face_id[frags.face_id >= 0].unique()].unique()
    rows = visible[torch.randperm(visible.numel(), generator=g)[:6].to(device)]

    def depth_loss(v):
        return (render_maps(v, faces, cams, size, normals=normals, fragments=frags).depth * wd).mean()

    def normal_loss(v):
        return (render_maps(v, faces, cams, size, normals=normals, fragments=frags).normals * wn).mean()

    _fd_check(depth_loss, verts, rows)
    _fd_check(normal_loss, verts, rows)


def test_mask_loss_gradient_at_silhouette_vertices(device):
    verts, faces = _bumpy_sphere(device)
    cams = fibonacci_cameras(2, device=device, dtype=torch.float64)
    size = 40
    frags = rasterize(verts, faces, cams, size)
    target = torch.zeros(2, size, size, dtype=torch.float64, device=device)
    target[:, 8:32, 10:30] = 1.0

    def mask_loss(v, antialias=True):
        maps = render_maps(v, faces, cams, size, antialias=antialias, fragments=frags)
        return (maps.mask - target).abs().mean()

    v = verts.clone().requires_grad_(True)
    assert not mask_loss(v, antialias=False).requires_grad  # without antialiasing the mask has no gradient
    (grad,) = torch.autograd.grad(mask_loss(v), v)
    moved = grad.norm(dim=1) > 1e-3 * grad.norm(dim=1).max()
    assert moved.sum() >= 8
    rows = moved.nonzero().squeeze(1)[:8]
    _fd_check(mask_loss, verts, rows)


def test_mask_loss_grows_and_shrinks_the_outline(device):
    """The silhouette gradient points the right way: a sphere too small grows, too big shrinks, and a few
    gradient steps on the mask loss alone bring its radius to the target's."""
    unit, faces = _sphere(3, 1.0, device)
    cams = fibonacci_cameras(3, device=device, dtype=torch.float64)
    target = render_maps(unit * 0.7, faces, cams, 32).mask

    def loss(radius):
        return (render_maps(unit * radius, faces, cams, 32).mask - target).abs().mean()

    for start, sign in ((0.55, -1.0), (0.85, 1.0)):
        r = torch.tensor(start, dtype=torch.float64, device=device, requires_grad=True)
        (g,) = torch.autograd.grad(loss(r), r)
        assert g.item() * sign > 0
    r = torch.tensor(0.55, dtype=torch.float64, device=device, requires_grad=True)
    opt = torch.optim.Adam([r], lr=0.02)
    for _ in range(40):
        opt.zero_grad()
        loss(r).backward()
        opt.step()
    assert abs(r.item() - 0.7) < 0.02


def test_antialiased_coverage_is_continuous_and_has_the_right_slope(device):
    """Moving the right edge of a screen-aligned square: away from the corners every pixel row's mask sum is
    the covered length (continuous while the edge crosses pixel centres), and the gradient is one pixel per
    pixel of motion in every row the edge spans."""
    cams = _front_camera(device)
    size = 48
    px_per_unit = cams.focal(size) / 3.0
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]], device=device)
    x_left = -0.3 * px_per_unit + size / 2  # screen x of the left edge
    xs = torch.linspace(0.2, 0.2 + 2.0 / px_per_unit, 9, dtype=torch.float64)  # sweeps over two pixel centres
    for x in xs.tolist():
        corners = [[-0.3, -0.3, 0], [x, -0.3, 0], [x, 0.3, 0], [-0.3, 0.3, 0]]
        verts = torch.tensor(corners, dtype=torch.float64, device=device, requires_grad=True)
        maps = render_maps(verts, faces, cams, size)
        rows = (maps.fragments.face_id[0] >= 0).any(dim=1).nonzero().squeeze(1)
        middle = rows[2:-2]  # rows away from the corners, where two edges blend the same pixels
        row_sums = maps.mask[0, middle].sum(dim=1)
        covered = x * px_per_unit + size / 2 - x_left
        assert torch.allclose(row_sums, torch.full_like(row_sums, covered), atol=1e-9)
        (g,) = torch.autograd.grad(maps.mask.sum(), verts)
        assert (g[1, 0] + g[2, 0]).item() == pytest.approx(rows.numel() * px_per_unit, rel=1e-9)


def test_mesh_edges_pairs_faces_and_marks_boundaries():
    # a square of two triangles plus a flipped third triangle sharing an edge
    faces = torch.tensor([[0, 1, 2], [0, 2, 3], [2, 1, 4]])
    e = mesh_edges(faces)
    assert e.ends.shape[0] == 7
    pairs = {
        tuple(sorted(map(int, ab))): (tuple(map(int, f)), bool(c))
        for ab, f, c in zip(e.ends, e.faces, e.consistent, strict=True)
    }
    assert pairs[(0, 2)][0] == (0, 1) and pairs[(0, 2)][1]
    assert pairs[(1, 2)][0] == (0, 2) and pairs[(1, 2)][1]  # face 2 runs 2 -> 1, face 0 runs 1 -> 2
    assert sum(f[1] == -1 for f, _ in pairs.values()) == 5
    for ab, f, apex in zip(e.ends.tolist(), e.faces.tolist(), e.apex.tolist(), strict=True):
        assert set(ab) | {apex} == set(faces[f[0]].tolist())
    big = mesh_edges(torch.tensor(trimesh.creation.icosphere(3).faces))
    assert bool((big.faces[:, 1] >= 0).all()) and bool(big.consistent.all())
    assert big.ends.shape[0] == 1280 * 3 // 2


# ------------------------------------------------------------ shading


def test_shading_grid_and_png(tmp_path, device):
    verts, faces = _sphere(3, 0.8, device, dtype=torch.float32)
    cams = fibonacci_cameras(3, device=device)
    maps = render_maps(verts, faces, cams, 32)
    for mode in ("lambert", "normals"):
        img = shade(maps, cams, mode=mode)
        assert img.shape == (3, 32, 32, 3) and img.dtype == torch.uint8
        bg = maps.mask.cpu() == 0
        assert bool((img[bg] == 255).all())
        assert img[maps.mask.cpu() == 1].float().std() > 5  # shaded, not flat
    lit = shade(maps, cams)[0].float()
    assert lit[6:12, 6:16].mean() > lit[20:26, 16:26].mean()  # headlight from the upper left
    grid = image_grid(shade(maps, cams), pad=2)
    assert grid.shape == (2 * 32 + 3 * 2, 2 * 32 + 3 * 2, 3)
    path = tmp_path / "grid.png"
    save_png(path, grid)
    from PIL import Image

    assert np.array_equal(np.asarray(Image.open(path)), grid)
    assert [p.name for p in tmp_path.iterdir()] == ["grid.png"]
