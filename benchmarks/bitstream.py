"""Container v1 against v2 on the same fit: bytes, bits per point per stream, Chamfer distance, encode and decode time.

    python -m tetweave_codec.benchmarks.bitstream [--meshes DIR] [--only spot,fandisk] [--points 4k,16k]
                                                  [--quality default] [--threads N] [--repeats 11]
                                                  [--sweep "b=10,s=1e-3,c=0.2;b=11,..."]

For each mesh and point count the main stage of the fit runs once; then the v1 finish (float16 positions, plain
late stage) and the v2 finish (grid-snapped positions, quantization-aware late stage) each start from the same
parameters and the same RNG state, so the two files differ only by the container and its finish. Encode time
of a version = targets + init + main + its finish + packing. Decode time: median of `--repeats` full decodes of
the file (unpack + entropy decoding + Delaunay + marching tets), the files of one mesh decoded in turn. Chamfer
distance: the summary's metric (input's normalized frame, 100K samples per mesh, seed 0).

`--sweep` adds v2 finishes with other quantization settings (b = position bits, s = s step, c = one step for all
SH bands, or c0/c1/... per band), to choose defaults from measurements.
Run it on a quiet machine: torch's threads slow down badly when other processes share the cores.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from tetweave_codec.benchmarks.common import script_meshes, script_parser
from tetweave_codec.cli.common import parse_count
from tetweave_codec.decoder import decode, decode_detailed
from tetweave_codec.encoder import pack_result
from tetweave_codec.fit.config import QUALITY, FitConfig
from tetweave_codec.fit.finish import finish
from tetweave_codec.fit.loop import FitResult, deterministic_torch, fit_main
from tetweave_codec.formats.quantize import Quantization, default_quantization
from tetweave_codec.meshio import load_mesh, normalize
from tetweave_codec.metrics import chamfer_distance

CHAMFER_SAMPLES = 100_000


def parse_sweep(text: str, sh_degree: int) -> list[Quantization]:
    """'b=10,s=1e-3,c=0.2;b=11' -> Quantizations (unset fields from the default)."""
    out = []
    for item in filter(None, (t.strip() for t in text.split(";"))):
        q = Quantization()
        bands = list(q.c_band_steps)
        for kv in item.split(","):
            key, value = kv.split("=")
            key = key.strip()
            if key == "b":
                q = replace(q, position_bits=int(value))
            elif key == "s":
                q = replace(q, s_step=float(value))
            elif key == "c":
                bands = [float(value)] * 4
            elif key.startswith("c") and key[1:].isdigit():
                bands[int(key[1:])] = float(value)
            else:
                raise SystemExit(f"unknown sweep key {key!r} (b, s, c, c0..c3)")
        out.append(replace(q, c_band_steps=tuple(bands)))
    return out


def _finish_and_measure(params, ctx, quant, base_seconds, vertices, faces, scale, offset) -> dict:
    state = ctx.generator.get_state()
    ctx.config = replace(ctx.config, quantization=quant)
    ctx.seconds = {}
    t0 = time.perf_counter()
    fin = finish(params, ctx)
    result = FitResult(fin, ctx.config.sh_degree, ctx.backend, dict(ctx.seconds), [])
    data = pack_result(result, scale, offset)
    encode_s = base_seconds + time.perf_counter() - t0
    ctx.generator.set_state(state)
    detail = decode_detailed(data)
    out_v, out_f = detail.vertices, detail.faces
    cd = chamfer_distance(vertices, faces, out_v, out_f, n_samples=CHAMFER_SAMPLES, seed=0) if len(out_f) else np.inf
    n = len(fin.s)
    return {
        "version": fin.version,
        "data": data,
        "bytes": len(data),
        "kept": n,
        "bpp": 8 * len(data) / n,
        "chamfer": cd,
        "encode_s": encode_s,
        "streams": getattr(detail.container, "sizes", None),
        "quant": quant,
    }


def _time_decodes(rows: list[dict], repeats: int) -> None:
    """Median decode time of each row's file, the files decoded in turn (round robin) so that a busy moment of
    the machine costs all of them alike."""
    times = [[] for _ in rows]
    for _ in range(repeats):
        for k, row in enumerate(rows):
            t0 = time.perf_counter()
            decode(row["data"])
            times[k].append(time.perf_counter() - t0)
    for row, ts in zip(rows, times, strict=True):
        row["decode_ms"] = 1000 * statistics.median(ts)


def _label(row: dict) -> str:
    q = row["quant"]
    if q is None:
        return "v1"
    steps = {f"{x:.3g}" for x in q.c_band_steps}
    return f"v2 b={q.position_bits} s={q.s_step:.3g} c={'/'.join(sorted(steps))}"


def run_mesh(path: Path, points: int, quality: str, sweep: list[Quantization], repeats: int) -> list[dict]:
    vertices, faces = load_mesh(path)
    normalized, scale, offset = normalize(vertices)
    config = FitConfig(points=points, schedule=QUALITY[quality], quantization=None)
    t0 = time.perf_counter()
    ctx, params = fit_main(normalized, faces, config, "cpu")
    base = time.perf_counter() - t0
    with deterministic_torch():
        variants = [None, default_quantization(points), *sweep]
        rows = []
        for quant in variants:
            row = _finish_and_measure(params, ctx, quant, base, vertices, faces, scale, offset)
            row.update(mesh=path.stem, points=points)
            rows.append(row)
    _time_decodes(rows, repeats)
    return rows


def main() -> None:
    ap = script_parser(__doc__)
    ap.add_argument("--points", default="4k,16k")
    ap.add_argument("--repeats", type=int, default=11)
    ap.add_argument("--sweep", default="", help="extra v2 settings, e.g. 'b=10,s=1e-3,c=0.2;b=11'")
    args = ap.parse_args()
    counts = [parse_count(p) for p in args.points.split(",")]
    paths = script_meshes(args)
    sweep = parse_sweep(args.sweep, 1)
    print(f"torch threads {torch.get_num_threads()}, quality {args.quality}, decode repeats {args.repeats}")
    print(
        f"| {'mesh':14} | {'points':>6} | {'container':36} | {'kept':>6} | {'bytes':>8} | {'bits/pt':>7} | "
        f"{'pos':>5} | {'s':>5} | {'c':>5} | {'chamfer':>8} | {'CD/v1':>5} | {'v1/bytes':>8} | "
        f"{'encode s':>8} | {'decode ms':>9} |"
    )
    print("|" + "|".join("-" * (w + 2) for w in (14, 6, 36, 6, 8, 7, 5, 5, 5, 8, 5, 8, 8, 9)) + "|")
    for path in paths:
        for n in counts:
            rows = run_mesh(path, n, args.quality, sweep, args.repeats)
            v1 = rows[0]
            for row in rows:
                st = row["streams"] or {}
                per = {k: 8 * st[k] / row["kept"] if k in st else float("nan") for k in ("positions", "s", "c")}
                print(
                    f"| {row['mesh']:14} | {n:>6} | {_label(row):36} | {row['kept']:>6} | {row['bytes']:>8,} | "
                    f"{row['bpp']:>7.1f} | {per['positions']:>5.1f} | {per['s']:>5.1f} | {per['c']:>5.1f} | "
                    f"{row['chamfer']:>8.2e} | {row['chamfer'] / v1['chamfer']:>5.2f} | "
                    f"{v1['bytes'] / row['bytes']:>8.2f} | {row['encode_s']:>8.1f} | {row['decode_ms']:>9.1f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
