"""Pictures of `tetweave bench`: rate-distortion plots (bytes against Chamfer distance) and side-by-side renders
of the input and each family's file at comparable sizes."""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from tetweave_codec.bench.methods import DECIMATE_DRACO, DRACO, FAMILIES, MLAB_DRACO, TETWEAVE
from tetweave_codec.bench.report import FOCUS_ORDER, as_number, ok_rows
from tetweave_codec.bench.rows import MeshResult
from tetweave_codec.meshio import write_bytes_atomic

PICTURE_FAMILIES = FAMILIES
CURVE_STYLE = {
    DRACO: ("tab:blue", "o"),
    DECIMATE_DRACO: ("tab:orange", "s"),
    MLAB_DRACO: ("tab:red", "D"),
    TETWEAVE: ("tab:green", "^"),
}


def _save_figure(fig, path: str | Path) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    write_bytes_atomic(path, buf.getvalue())


# Settings named on a curve of the rate-distortion plot, evenly spread along it (both ends included): the
# MeshLab sweep has 54 settings per bit depth, whose names would cover the plot.
LABELS_PER_CURVE = 8


def plot_rate_distortion(rows: Sequence[dict], path: str | Path, title: str = "") -> bool:
    """Bytes against Chamfer distance, log-log, one curve per method curve; False if nothing to plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    good = ok_rows(rows)
    good = [r for r in good if as_number(r["chamfer"]) > 0]
    if not good:
        return False
    curves: dict[str, list[dict]] = {}
    for r in good:
        curves.setdefault(r["curve"], []).append(r)
    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    dashes = {}
    for label, pts in curves.items():
        family = pts[0]["family"]
        colour, marker = CURVE_STYLE.get(family, ("tab:gray", "x"))
        dashes[family] = dashes.get(family, -1) + 1
        pts = sorted(pts, key=lambda r: as_number(r["chamfer"]))
        x = [as_number(r["chamfer"]) for r in pts]
        y = [as_number(r["bytes"]) for r in pts]
        style = ["-", "--", ":", "-."][dashes[family] % 4]
        ax.plot(x, y, style, color=colour, marker=marker, label=label, markersize=5 if len(pts) <= 20 else 3)
        for i in np.unique(np.linspace(0, len(pts) - 1, min(len(pts), LABELS_PER_CURVE)).round().astype(int)):
            r, xi, yi = pts[i], x[i], y[i]
            tag = r["setting"].replace(" pts", "").split(" sh")[0] if family == TETWEAVE else r["setting"]
            ax.annotate(tag, (xi, yi), textcoords="offset points", xytext=(4, 3), fontsize=6, color=colour)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("Chamfer distance (normalized frame, point-to-surface)")
    ax.set_ylabel("compressed size (bytes)")
    ax.set_title(title or "rate-distortion")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    _save_figure(fig, path)
    plt.close(fig)
    return True


def comparable_rows(rows: Sequence[dict]) -> list[dict]:
    """One row per family for the side-by-side picture, at comparable sizes.

    The reference is the middle-sized setting of the first family of FOCUS_ORDER present (tetweave when
    present); every other family contributes its setting closest to that size in log scale.
    """
    for family in FOCUS_ORDER:
        candidates = sorted(ok_rows(rows, family), key=lambda r: as_number(r["bytes"]))
        if candidates:
            reference = candidates[(len(candidates) - 1) // 2]
            break
    else:
        return []
    target = math.log(as_number(reference["bytes"]))
    chosen = []
    for family in PICTURE_FAMILIES:
        if family == reference["family"]:
            chosen.append(reference)
            continue
        candidates = ok_rows(rows, family)
        if candidates:
            chosen.append(min(candidates, key=lambda r: abs(math.log(as_number(r["bytes"])) - target)))
    return chosen


VIEW_CANDIDATES = 24  # Fibonacci directions tried for the overview
VIEW_RADIUS = 3.2  # camera distance from the centre of the normalized frame
CLOSE_UP_FOV = 14.0  # degrees; the overview uses 45


def _local_detail(normals, mask, window: int):
    """Normal change per pixel (to the right and below), box-filtered over `window` pixels: (H,W), 0 where the
    window is not entirely on the surface (a close-up of a silhouette would show mostly background)."""
    import torch

    h, w = mask.shape
    n = normals * mask[..., None]
    change = torch.zeros((h, w), dtype=normals.dtype)
    change[:, :-1] += (n[:, 1:] - n[:, :-1]).norm(dim=-1)
    change[:-1, :] += (n[1:, :] - n[:-1, :]).norm(dim=-1)
    pool = torch.nn.functional.avg_pool2d
    full = pool(mask[None, None], window, stride=1, padding=window // 2)[0, 0, :h, :w]
    detail = pool(change[None, None], window, stride=1, padding=window // 2)[0, 0, :h, :w]
    return torch.where(full > 0.999, detail, torch.zeros_like(detail))


def choose_cameras(vertices: np.ndarray, faces: np.ndarray, size: int = 96):
    """Cameras [overview, close-up] for pictures of a mesh in the normalized frame.

    The overview looks at the centre from the candidate direction (a Fibonacci sphere, not from below) whose
    normal map varies most over the covered area; the close-up looks, from the same eye, at the surface point
    where a window half the low-resolution image wide has the most normal change (the most detail).
    """
    import torch

    from tetweave_codec.render import fibonacci_cameras, look_at_cameras, render_maps

    v = torch.as_tensor(vertices, dtype=torch.float32)
    f = torch.as_tensor(np.asarray(faces, dtype=np.int64))
    cams = fibonacci_cameras(VIEW_CANDIDATES, radius=VIEW_RADIUS)
    cams = cams[cams.eye[:, 1] > -0.35 * VIEW_RADIUS]
    with torch.no_grad():
        maps = render_maps(v, f, cams, size, antialias=False)
        mask = maps.mask
        count = mask.sum(dim=(1, 2)).clamp_min(1.0)
        mean = (maps.normals * mask[..., None]).sum(dim=(1, 2)) / count[:, None]
        spread = (((maps.normals - mean[:, None, None]) ** 2).sum(-1) * mask).sum(dim=(1, 2)) / count
        best = int(torch.argmax(spread * mask.mean(dim=(1, 2))))
        eye = cams.eye[best : best + 1]
        overview = look_at_cameras(eye, fov_deg=45.0)
        big = render_maps(v, f, overview, 2 * size, antialias=False)
        detail = _local_detail(big.normals[0], big.mask[0], max(3, size // 2) | 1)
        target = torch.zeros(3)
        if float(detail.max()) > 0:
            iy, ix = divmod(int(torch.argmax(detail)), detail.shape[1])
            target = overview.backproject(big.depth)[0, iy, ix]
    return [overview, look_at_cameras(eye, target=target, fov_deg=CLOSE_UP_FOV)]


def _render_views(vertices: np.ndarray, faces: np.ndarray, cameras, size: int) -> np.ndarray:
    """(len(cameras),H,W,3) uint8 Lambert-shaded renders of a mesh given in the normalized frame."""
    import torch

    from tetweave_codec.render import render_maps, shade

    v = torch.as_tensor(np.asarray(vertices, dtype=np.float64), dtype=torch.float32)
    f = torch.as_tensor(np.asarray(faces, dtype=np.int64))
    images = []
    for cam in cameras:
        with torch.no_grad():
            images.append(shade(render_maps(v, f, cam, size), cam)[0].numpy())
    return np.stack(images)


def side_by_side(result: MeshResult, rows: Sequence[dict], path: str | Path, size: int = 360) -> bool:
    """Input / Draco / decimate+Draco / tetweave at comparable sizes, full view above and close-up below.

    Rendered with the project's renderer (flat normals, Lambert shading); False if no method succeeded.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tetweave_codec.metrics.fidelity import normalization

    chosen = [r for r in comparable_rows(rows) if f"{r['family']} {r['setting']}" in result.decoded]
    if not chosen:
        return False
    scale, offset = normalization(result.vertices)

    def frame(v: np.ndarray) -> np.ndarray:
        return (np.asarray(v, dtype=np.float64) - offset) / scale

    cameras = choose_cameras(frame(result.vertices), result.faces)
    panels = [
        (
            "input",
            f"{len(result.faces):,} faces",
            _render_views(frame(result.vertices), result.faces, cameras, size),
        )
    ]
    for r in chosen:
        v, f = result.decoded[f"{r['family']} {r['setting']}"]
        caption = f"{as_number(r['bytes']):,.0f} B, CD {as_number(r['chamfer']):.2g}\n{len(f):,} faces"
        panels.append((f"{r['family']} {r['setting']}", caption, _render_views(frame(v), f, cameras, size)))
    fig, axes = plt.subplots(2, len(panels), figsize=(2.6 * len(panels), 5.6), squeeze=False)
    for col, (title, caption, views) in enumerate(panels):
        for row in range(2):
            ax = axes[row, col]
            ax.imshow(views[row])
            ax.set_xticks([])
            ax.set_yticks([])
            for spine in ax.spines.values():
                spine.set_visible(False)
        axes[0, col].set_title(title, fontsize=9)
        axes[1, col].set_xlabel(caption, fontsize=8)
    fig.suptitle(f"{result.name}: comparable sizes (top: whole shape, bottom: close-up)", fontsize=10)
    fig.tight_layout()
    _save_figure(fig, path)
    plt.close(fig)
    return True
