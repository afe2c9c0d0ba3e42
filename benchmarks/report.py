"""Reports of `tetweave bench`: results.csv, summary.md, rate-distortion plots and side-by-side pictures.

Matched-error verdict. Each family's settings give points (Chamfer distance, bytes); its Pareto front and the
size on it at a given error come from `tetweave_codec.metrics.rate_distortion` (log-log interpolation, never
extrapolated). The verdict compares, at the Chamfer distance of each setting of the focus family (tetweave when
present, else the strongest classical family present), the sizes of all families, names the smallest, and sets the
focus setting's normal consistency beside that of the best classical file that fits in the same bytes.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tetweave_codec.benchmarks.batch import COLUMNS, INPUT_FAMILY, MeshResult
from tetweave_codec.benchmarks.methods import CLASSICAL, DECIMATE_DRACO, DRACO, FAMILIES, MLAB_DRACO, TETWEAVE
from tetweave_codec.meshio import write_bytes_atomic
from tetweave_codec.metrics.rate_distortion import bytes_at, pareto_front

FOCUS_ORDER = (TETWEAVE, MLAB_DRACO, DECIMATE_DRACO, DRACO)  # the family the verdict is about, first present wins
PICTURE_FAMILIES = FAMILIES
CURVE_STYLE = {
    DRACO: ("tab:blue", "o"),
    DECIMATE_DRACO: ("tab:orange", "s"),
    MLAB_DRACO: ("tab:red", "D"),
    TETWEAVE: ("tab:green", "^"),
}


# ----------------------------------------------------------------------------------------------------------
# Rows
# ----------------------------------------------------------------------------------------------------------


def _num(value) -> float | None:
    """A finite float from a row cell (number or CSV text), else None."""
    if value is None or value == "" or isinstance(value, bool):
        return None
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def ok_rows(rows: Sequence[dict], family: str | None = None) -> list[dict]:
    """Successful method rows (not the input row), optionally of one family."""
    return [
        r
        for r in rows
        if r["family"] != INPUT_FAMILY
        and not r.get("error")
        and _num(r.get("chamfer")) is not None
        and _num(r.get("bytes")) is not None
        and (family is None or r["family"] == family)
    ]


def _format_cell(value) -> str:
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return f"{float(value):.6g}"
    return "" if value is None else str(value)


def write_csv(rows: Sequence[dict], path: str | Path) -> None:
    """One line per row, columns `batch.COLUMNS`; booleans as yes/no, floats to 6 significant digits."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _format_cell(row.get(k, "")) for k in COLUMNS})
    write_bytes_atomic(path, buf.getvalue().encode("utf-8"))


def read_csv(path: str | Path) -> list[dict]:
    """Rows of a results.csv (values as text; the report functions accept text or numbers)."""
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def rows_by_mesh(rows: Sequence[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for row in rows:
        out.setdefault(row["mesh"], []).append(row)
    return out


# ----------------------------------------------------------------------------------------------------------
# Rate-distortion fronts and the matched-error verdict
# ----------------------------------------------------------------------------------------------------------


def family_fronts(rows: Sequence[dict]) -> dict[str, list[tuple[float, float]]]:
    fronts = {}
    for family in FOCUS_ORDER:
        pts = [(_num(r["chamfer"]), _num(r["bytes"])) for r in ok_rows(rows, family)]
        if pts:
            fronts[family] = pareto_front(pts)
    return fronts


@dataclass(frozen=True)
class MatchedPoint:
    """One setting of the focus family compared with the other families at its Chamfer distance.

    sizes: family -> bytes interpolated on that family's front at `error` (families whose front does not reach
    `error` are absent). best: the smallest of them. nc: the setting's normal consistency; nc_classical /
    classical_setting: the highest normal consistency of a classical file no larger than `size` (None when no
    classical file is that small).
    """

    focus: str
    setting: str
    error: float
    size: float
    sizes: dict[str, float]
    nc: float | None
    nc_classical: float | None
    classical_setting: str

    @property
    def best(self) -> tuple[str, float] | None:
        return min(self.sizes.items(), key=lambda kv: kv[1]) if self.sizes else None

    @property
    def ratio(self) -> float | None:
        """Focus bytes / best other family's bytes at the same error (< 1: the focus family is smaller)."""
        best = self.best
        return None if best is None else self.size / best[1]


def _best_classical_nc(rows: Sequence[dict], budget: float) -> tuple[float | None, str]:
    """The highest normal consistency among classical files of at most `budget` bytes, and its setting."""
    candidates = [
        r
        for r in ok_rows(rows)
        if r["family"] in CLASSICAL and _num(r["bytes"]) <= budget and _num(r.get("normal_consistency")) is not None
    ]
    if not candidates:
        return None, ""
    best = max(candidates, key=lambda r: _num(r["normal_consistency"]))
    return _num(best["normal_consistency"]), f"{best['family']} {best['setting']}"


def matched_points(rows: Sequence[dict]) -> tuple[str | None, list[MatchedPoint]]:
    """(focus family, one MatchedPoint per successful focus setting, smallest first) for one mesh's rows."""
    fronts = family_fronts(rows)
    focus = next((f for f in FOCUS_ORDER if f in fronts), None)
    if focus is None:
        return None, []
    others = [f for f in FOCUS_ORDER if f in fronts and f != focus]
    points = []
    for row in sorted(ok_rows(rows, focus), key=lambda r: _num(r["bytes"])):
        error, size = _num(row["chamfer"]), _num(row["bytes"])
        sizes = {f: bytes_at(fronts[f], error) for f in others}
        nc_classical, classical_setting = _best_classical_nc(rows, size)
        points.append(
            MatchedPoint(
                focus=focus,
                setting=row["setting"],
                error=error,
                size=size,
                sizes={f: b for f, b in sizes.items() if b is not None},
                nc=_num(row.get("normal_consistency")),
                nc_classical=nc_classical,
                classical_setting=classical_setting,
            )
        )
    return focus, points


def _nc_text(point: MatchedPoint) -> str:
    if point.nc is None or point.nc_classical is None or point.focus in CLASSICAL:
        return ""
    return (
        f"; NC {point.nc:.4f} vs {point.nc_classical:.4f} (best classical file within {point.size:,.0f} B: "
        f"{point.classical_setting})"
    )


def verdict(rows: Sequence[dict]) -> list[str]:
    """Markdown bullets: at each focus setting's error, every family's interpolated size, the smallest, and
    normal consistency against the best classical file of at most the same bytes."""
    focus, points = matched_points(rows)
    if focus is None:
        return ["- no method succeeded on this mesh"]
    if all(f == focus for f in family_fronts(rows)):
        return [f"- only {focus} succeeded; nothing to compare with"]
    lines = []
    wins = compared = 0
    for p in points:
        head = f"- at CD {p.error:.3g} ({focus} {p.setting}, {p.size:,.0f} B):"
        best = p.best
        if best is None:
            fronts = family_fronts(rows)
            ranges = ", ".join(f"{f} {fr[0][0]:.2g}-{fr[-1][0]:.2g}" for f, fr in fronts.items() if f != focus)
            lines.append(f"{head} outside the other methods' Chamfer ranges ({ranges}){_nc_text(p)}")
            continue
        compared += 1
        parts = [f"{f} ≈ {b:,.0f} B" for f, b in p.sizes.items()]
        best_other, best_size = best
        if p.size <= best_size:
            wins += 1
            tail = f"smallest: **{focus}** ({best_size / p.size:.2f}× smaller than {best_other})"
        else:
            tail = f"smallest: **{best_other}** ({p.size / best_size:.2f}× smaller than {focus})"
        lines.append(f"{head} {', '.join(parts)} → {tail}{_nc_text(p)}")
    outside = len(lines) - compared
    note = f"; {outside} of its settings fall outside the others' error range" if outside else ""
    lines.insert(0, f"- **{focus} is smallest at {wins} of {compared} matched-error points**{note}")
    return lines


def overall(rows: Sequence[dict]) -> list[str]:
    """Markdown lines over every mesh: focus bytes ÷ the best other family's bytes at matched Chamfer distance
    (median, range, wins), and normal consistency against the best classical file of at most the same bytes."""
    ratios, nc_gaps, names = [], [], []
    focus = None
    for mesh_rows in rows_by_mesh(rows).values():
        mesh_focus, points = matched_points(mesh_rows)
        focus = focus or mesh_focus
        for p in points:
            if p.ratio is not None:
                ratios.append(p.ratio)
                names.append(p.best[0])
            if p.nc is not None and p.nc_classical is not None and p.focus not in CLASSICAL:
                nc_gaps.append(p.nc - p.nc_classical)
    if not ratios:
        return ["- no matched-error points"]
    smaller = sum(r <= 1.0 for r in ratios)
    best_counts = ", ".join(f"{f} {names.count(f)}" for f in dict.fromkeys(names))
    lines = [
        f"- {focus} bytes ÷ the best other family's bytes at matched Chamfer distance over {len(ratios)} points: "
        f"median **{float(np.median(ratios)):.2f}×** (range {min(ratios):.2f}–{max(ratios):.2f}); {focus} "
        f"smaller at {smaller} of {len(ratios)} (best other family: {best_counts})"
    ]
    if nc_gaps:
        lines.append(
            f"- normal consistency minus that of the best classical file of at most the same bytes: median "
            f"{float(np.median(nc_gaps)):+.4f} (range {min(nc_gaps):+.4f} to {max(nc_gaps):+.4f}, "
            f"{sum(g >= -0.005 for g in nc_gaps)} of {len(nc_gaps)} within 0.005 or better)"
        )
    return lines


# ----------------------------------------------------------------------------------------------------------
# Markdown summary
# ----------------------------------------------------------------------------------------------------------

SUMMARY_COLUMNS = [
    ("method", "family"),
    ("setting", "setting"),
    ("bytes", "bytes"),
    ("bits/vertex", "bits_per_vertex"),
    ("CD", "chamfer"),
    ("HD", "hausdorff"),
    ("NC", "normal_consistency"),
    ("F1@.001", "f1@0.001"),
    ("F1@.005", "f1@0.005"),
    ("ECD", "edge_chamfer"),
    ("EF1", "edge_f1"),
    ("IN>5° %", "inaccurate_normals_pct"),
    ("AR>4 %", "aspect_ratio_gt4_pct"),
    ("RR>4 %", "radius_ratio_gt4_pct"),
    ("SA<10° %", "small_angle_lt10_pct"),
    ("SI %", "self_intersect_pct"),
    ("watertight", "watertight"),
    ("2-manifold", "two_manifold"),
    ("V", "n_vertices"),
    ("F", "n_faces"),
    ("enc s", "encode_s"),
    ("dec s", "decode_s"),
]


def _md_cell(key: str, value) -> str:
    if value in ("", None):
        return ""
    if key in ("watertight", "two_manifold"):
        return "yes" if value in (True, "yes", "True", "1") else "no"
    x = _num(value)
    if x is None:  # inf (e.g. edge Chamfer when the creases are lost) or text
        return str(value)
    if key in ("bytes", "n_vertices", "n_faces"):
        return f"{x:,.0f}"
    if key in ("chamfer", "hausdorff", "edge_chamfer"):
        return f"{x:.3g}"
    if key in ("normal_consistency", "f1@0.001", "f1@0.005", "edge_f1"):
        return f"{x:.4f}"
    if key in ("encode_s", "decode_s"):
        return f"{x:.2f}"
    return f"{x:.2f}"


def mesh_table(rows: Sequence[dict]) -> list[str]:
    lines = [
        "| " + " | ".join(h for h, _ in SUMMARY_COLUMNS) + " |",
        "|" + "|".join("---" for _ in SUMMARY_COLUMNS) + "|",
    ]
    for row in rows:
        cells = [_md_cell(k, row.get(k, "")) for _, k in SUMMARY_COLUMNS]
        if row.get("error"):
            cells[4] = "failed: " + str(row["error"]).replace("|", "/")[:120]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


METRICS_LEGEND = """\
Distances are in each input's normalized frame (bounding box scaled into [-0.9, 0.9]³; the decoded mesh is
moved by the input's transform). CD: symmetric point-to-surface Chamfer distance (mean of the two directions,
area-weighted samples). HD: Hausdorff distance (samples and vertices). NC: normal consistency. F1@τ: F1 score
at distance τ. ECD / EF1: edge Chamfer distance / edge F1 (crease samples, paper Appendix C). IN>5°: % samples
whose normal is off by more than 5°. AR>4 / RR>4: % triangles with aspect ratio (longest edge / shortest
altitude) / radius ratio (circumradius / inradius) above 4. SA<10°: % triangles with an angle below 10°. SI: %
self-intersecting faces. Exact definitions: `tetweave_codec/metrics/`. The input row gives the raw size
(float32 xyz + uint32 indices) and the input's own triangle quality. bits/vertex: 8 × bytes / input vertices.
Times are wall-clock seconds on the machine that ran the benchmark."""


def write_summary(
    rows: Sequence[dict],
    path: str | Path,
    *,
    command: str | None = None,
    images: dict[str, list[str]] | None = None,
    notes: Sequence[str] = (),
) -> None:
    """summary.md: a verdict per mesh, then per mesh its pictures and a table of every setting."""
    by_mesh = rows_by_mesh(rows)
    out = ["# tetweave bench: compression against Draco", ""]
    if command:
        out += ["Regenerate with:", "", "```", command, "```", ""]
    out += [*notes, "", METRICS_LEGEND, "", "## Verdict at matched Chamfer distance", ""]
    out += [
        "Each family's sizes are interpolated along its Pareto front in log-log (bytes against Chamfer",
        "distance) at the error of each setting of the focus family (tetweave when present); sizes outside a",
        "front's range are not extrapolated. NC: normal consistency of the focus setting against the highest NC",
        "of a classical file (Draco, decimate+Draco, MeshLab+Draco) no larger than it.",
        "",
        "### All meshes",
        "",
        *overall(rows),
        "",
    ]
    for mesh, mesh_rows in by_mesh.items():
        out += [f"### {mesh}", "", *verdict(mesh_rows), ""]
    out += ["## Per mesh", ""]
    for mesh, mesh_rows in by_mesh.items():
        inp = next((r for r in mesh_rows if r["family"] == INPUT_FAMILY), None)
        size = ""
        if inp is not None and _num(inp.get("n_faces")) is not None:
            size = f" ({_num(inp['n_vertices']):,.0f} vertices, {_num(inp['n_faces']):,.0f} faces)"
        out += [f"### {mesh}{size}", ""]
        for image in (images or {}).get(mesh, []):
            out += [f"![{image}]({image})", ""]
        out += [*mesh_table(mesh_rows), ""]
    failures = [r for r in rows if r.get("error")]
    if failures:
        out += ["## Failures", ""]
        out += [f"- {r['mesh']}, {r['family']} {r['setting']}: {r['error']}" for r in failures]
        out.append("")
    write_bytes_atomic(path, "\n".join(out).encode("utf-8"))


# ----------------------------------------------------------------------------------------------------------
# Pictures
# ----------------------------------------------------------------------------------------------------------


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
    good = [r for r in good if _num(r["chamfer"]) > 0]
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
        pts = sorted(pts, key=lambda r: _num(r["chamfer"]))
        x = [_num(r["chamfer"]) for r in pts]
        y = [_num(r["bytes"]) for r in pts]
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
        candidates = sorted(ok_rows(rows, family), key=lambda r: _num(r["bytes"]))
        if candidates:
            reference = candidates[(len(candidates) - 1) // 2]
            break
    else:
        return []
    target = math.log(_num(reference["bytes"]))
    chosen = []
    for family in PICTURE_FAMILIES:
        if family == reference["family"]:
            chosen.append(reference)
            continue
        candidates = ok_rows(rows, family)
        if candidates:
            chosen.append(min(candidates, key=lambda r: abs(math.log(_num(r["bytes"])) - target)))
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
        caption = f"{_num(r['bytes']):,.0f} B, CD {_num(r['chamfer']):.2g}\n{len(f):,} faces"
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
