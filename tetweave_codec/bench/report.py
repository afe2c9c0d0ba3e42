"""Reports of `tetweave bench`: results.csv, summary.md and the matched-error verdict (pictures: pictures.py).

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

from tetweave_codec.bench.methods import CLASSICAL, DECIMATE_DRACO, DRACO, MLAB_DRACO, TETWEAVE
from tetweave_codec.bench.rows import COLUMNS, INPUT_FAMILY
from tetweave_codec.meshio import write_bytes_atomic
from tetweave_codec.metrics.rate_distortion import bytes_at, pareto_front

FOCUS_ORDER = (TETWEAVE, MLAB_DRACO, DECIMATE_DRACO, DRACO)  # the family the verdict is about, first present wins


# ----------------------------------------------------------------------------------------------------------
# Rows
# ----------------------------------------------------------------------------------------------------------


def as_number(value) -> float | None:
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
        and as_number(r.get("chamfer")) is not None
        and as_number(r.get("bytes")) is not None
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
    """One line per row, columns `rows.COLUMNS`; booleans as yes/no, floats to 6 significant digits."""
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
        pts = [(as_number(r["chamfer"]), as_number(r["bytes"])) for r in ok_rows(rows, family)]
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
        if r["family"] in CLASSICAL
        and as_number(r["bytes"]) <= budget
        and as_number(r.get("normal_consistency")) is not None
    ]
    if not candidates:
        return None, ""
    best = max(candidates, key=lambda r: as_number(r["normal_consistency"]))
    return as_number(best["normal_consistency"]), f"{best['family']} {best['setting']}"


def matched_points(rows: Sequence[dict]) -> tuple[str | None, list[MatchedPoint]]:
    """(focus family, one MatchedPoint per successful focus setting, smallest first) for one mesh's rows."""
    fronts = family_fronts(rows)
    focus = next((f for f in FOCUS_ORDER if f in fronts), None)
    if focus is None:
        return None, []
    others = [f for f in FOCUS_ORDER if f in fronts and f != focus]
    points = []
    for row in sorted(ok_rows(rows, focus), key=lambda r: as_number(r["bytes"])):
        error, size = as_number(row["chamfer"]), as_number(row["bytes"])
        sizes = {f: bytes_at(fronts[f], error) for f in others}
        nc_classical, classical_setting = _best_classical_nc(rows, size)
        points.append(
            MatchedPoint(
                focus=focus,
                setting=row["setting"],
                error=error,
                size=size,
                sizes={f: b for f, b in sizes.items() if b is not None},
                nc=as_number(row.get("normal_consistency")),
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

# What a mesh's rows were measured against, from their ``target`` column (batch.bench_target).
TARGET_TEXT = {
    "all": "the input",
    "visible": "the input's visible surface (fit/visible.py); the classical methods compress every input face",
}


def _target_mode(mesh_rows: Sequence[dict]) -> str | None:
    modes = {r.get("target") for r in mesh_rows} - {"", None}
    return modes.pop() if len(modes) == 1 else None


def target_line(mesh_rows: Sequence[dict], described: str | None = None) -> str:
    """One bullet naming what this mesh's Chamfer distances were measured against: `described`
    (rows.MeshResult.target) when given, else from the rows' ``target`` column."""
    text = described or TARGET_TEXT.get(_target_mode(mesh_rows) or "", "")
    return f"- measured against {text}" if text else "- measured against: not recorded"


def target_summary(by_mesh: dict[str, list[dict]]) -> str:
    """One bullet over every mesh: how many were measured against the input, how many against its visible
    surface (tetweave's `--surface`: the same target as the fit, every method alike)."""
    modes = [_target_mode(r) for r in by_mesh.values()]
    visible = [m for m, mode in zip(by_mesh, modes, strict=True) if mode == "visible"]
    whole = modes.count("all")
    if not visible:
        return f"- every method measured against the input ({whole} of {len(modes)} meshes)"
    return (
        f"- every method measured against the surface tetweave fits: the input on {whole} mesh(es), its visible "
        f"surface on {len(visible)} ({', '.join(visible)}), where the classical methods still compress every "
        "input face, hidden ones included"
    )


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
    ("unseen %", "unseen_area_pct"),
    ("enc s", "encode_s"),
    ("dec s", "decode_s"),
]


def _md_cell(key: str, value) -> str:
    if value in ("", None):
        return ""
    if key in ("watertight", "two_manifold"):
        return "yes" if value in (True, "yes", "True", "1") else "no"
    x = as_number(value)
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
self-intersecting faces. unseen % (tetweave rows): % of the decoded area no outside view sees (the encode
summary's self-check; above 1 % membranes or hidden parts were kept inside the solid). Exact definitions:
`tetweave_codec/metrics/`. The input row gives the raw size (float32 xyz + uint32 indices) and the input's own
triangle quality. bits/vertex: 8 × bytes / input vertices.
Times are wall-clock seconds on the machine that ran the benchmark."""


def write_summary(
    rows: Sequence[dict],
    path: str | Path,
    *,
    command: str | None = None,
    images: dict[str, list[str]] | None = None,
    notes: Sequence[str] = (),
    targets: dict[str, str] | None = None,
) -> None:
    """summary.md: a verdict per mesh, then per mesh its pictures and a table of every setting. targets: mesh ->
    what its rows were measured against (`rows.MeshResult.target`); without it, the rows' ``target`` column."""
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
        target_summary(by_mesh),
        "",
    ]
    for mesh, mesh_rows in by_mesh.items():
        out += [f"### {mesh}", "", target_line(mesh_rows, (targets or {}).get(mesh)), *verdict(mesh_rows), ""]
    out += ["## Per mesh", ""]
    for mesh, mesh_rows in by_mesh.items():
        inp = next((r for r in mesh_rows if r["family"] == INPUT_FAMILY), None)
        size = ""
        if inp is not None and as_number(inp.get("n_faces")) is not None:
            size = f" ({as_number(inp['n_vertices']):,.0f} vertices, {as_number(inp['n_faces']):,.0f} faces)"
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
