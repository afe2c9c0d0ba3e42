"""`tetweave info`: describe a `.tw` file (header, sizes, bounding box) without writing anything."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import click
import numpy as np

from tetweave_codec.cli.decode import echo_warnings, read_tw_bytes


def _box(lo: np.ndarray, hi: np.ndarray) -> str:
    fmt = lambda a: "(" + ", ".join(f"{x:.6g}" for x in a) + ")"  # noqa: E731
    return f"{fmt(lo)} .. {fmt(hi)}, size {fmt(hi - lo)}"


def _v2_lines(file: Path, f, total: int, degree: str) -> list[tuple[str, str]]:
    from tetweave_codec.formats import quantize
    from tetweave_codec.formats.common import FLAG_OCTREE_CONTEXTS, FLAG_S_PREDICTED

    n = f.num_points
    bpp = (lambda b: f"{8 * b / n:.2f} bits/point") if n else (lambda b: "-")
    steps = ", ".join(f"l={band}: {x:.6g}" for band, x in enumerate(f.c_band_steps)) or "none"
    predicted = "; s coded as prediction residuals" if f.flags & FLAG_S_PREDICTED else ""
    predicted += "; octree context-coded" if f.flags & FLAG_OCTREE_CONTEXTS else ""
    predicted += f"; {f.smoothing} Taubin smoothing step{'s' if f.smoothing > 1 else ''}" if f.smoothing else ""
    predicted += " keeping creases" if f.smoothing and f.creases else ""
    predicted += f"; {f.subdivision} Loop subdivision level{'s' if f.subdivision > 1 else ''}" if f.subdivision else ""
    predicted += f"; {len(f.holes):,} faces removed to keep the input's holes open" if f.holes is not None else ""
    lines = [
        ("file", str(file)),
        ("format", ".tw version 2 (quantized; octree + range-coded streams)"),
        ("points", f"{n:,}"),
        ("SH degree", degree),
        ("flags", f"0x{f.flags:x} (Delaunay backend: {f.backend}{predicted})"),
        (
            "quantization",
            f"positions {f.position_bits} bits/axis (cell {quantize.cell_size(f.position_bits):.6g}, "
            f"{quantize.cell_size(f.position_bits) * f.scale:.6g} in the input's units), "
            f"s step {f.s_step:.6g}, c steps {steps}",
        ),
        ("bytes", f"{total:,} total ({bpp(total)})"),
    ]
    for part in ("header", "positions", "s", "c", "holes", "checksum"):
        if part not in f.sizes:  # the holes section is optional
            continue
        size = f.sizes[part]
        lines.append((f"  {part}", f"{size:,} ({bpp(size)})"))
    return lines


def _level_faces_line(data: bytes, f) -> str:
    """Faces of `tetweave decode --level control / smoothed / full` (Delaunay and marching tets only)."""
    from tetweave_codec.decoder import level_faces

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a missing backend: `decode` and --mesh say so
        counts = level_faces(data)
    smoothing, levels = getattr(f, "smoothing", 0), getattr(f, "subdivision", 0)
    full = "refused (too many subdivided faces)" if counts["full"] is None else f"{counts['full']:,}"
    parts = [f"control {counts['control']:,}"]
    if smoothing:
        parts.append(f"smoothed {counts['smoothed']:,}")
    parts.append(f"full {full}" + (f" (4^{levels} per control face)" if levels else " (no subdivision)"))
    return ", ".join(parts) + " (tetweave decode --level)"


@click.command(context_settings={"show_default": True})
@click.argument("file", type=click.Path(path_type=Path))
@click.option("--mesh", is_flag=True, help="Also decode FILE and report the mesh: counts and exact bounding box.")
def info(file: Path, mesh: bool) -> None:
    """Describe FILE (a .tw file): version, points, SH degree, byte sizes, bounding box.

    The bounding box is that of the stored points in the original mesh's coordinates; the decoded surface lies
    inside it (use --mesh for the surface's own box).
    """
    from tetweave_codec.formats import tw
    from tetweave_codec.geometry.sh import num_coeffs

    data = read_tw_bytes(file)
    f = tw.unpack(data)
    n, q = f.num_points, num_coeffs(f.sh_degree)
    degree = "none (0 coefficients per point)" if f.sh_degree < 0 else f"{f.sh_degree} ({q} per point)"
    if f.version == 2:
        lines = _v2_lines(file, f, len(data), degree)
    else:
        payload = len(data) - tw.HEADER_SIZE - tw.CHECKSUM_SIZE
        lines = [
            ("file", str(file)),
            ("format", f".tw version 1, payload codec {f.codec} (raw float16)"),
            ("points", f"{n:,}"),
            ("SH degree", degree),
            ("flags", f"0x{f.flags:x} (Delaunay backend: {f.backend})"),
            (
                "bytes",
                f"{len(data):,} total = header {tw.HEADER_SIZE} + payload {payload:,} "
                f"(positions {6 * n:,}, s {2 * n:,}, c {2 * n * q:,}) + checksum {tw.CHECKSUM_SIZE}",
            ),
        ]
    lines.append(("transform", f"original = normalized * {f.scale:.9g} + ({', '.join(f'{x:.9g}' for x in f.offset)})"))
    if n:
        pts = f.points.astype(np.float64) * f.scale + f.offset
        lines.append(("points box", _box(pts.min(0), pts.max(0))))
    lines.append(("faces", _level_faces_line(data, f)))
    if mesh:
        from tetweave_codec.decoder import decode_detailed

        start = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = decode_detailed(data)
        echo_warnings(caught)
        v = result.vertices
        lines.append(("mesh", f"{len(v):,} vertices, {len(result.faces):,} faces "
                              f"(decoded in {time.perf_counter() - start:.2f}s)"))  # fmt: skip
        lines.append(("mesh box", _box(v.min(0), v.max(0)) if len(v) else "empty"))
    width = max(len(k) for k, _ in lines)
    for key, value in lines:
        click.echo(f"{key:<{width}}  {value}")
