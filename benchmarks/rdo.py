"""RD-optimized s symbols (tetweave_codec/fit/rdo.py) against plain rounding, on the same fit.

Each mesh and size is fitted once with rate control (`encode(size=...)`'s path, RDO off); then the late stage's
latent s and c are quantized both ways:

* "rate control": the file each pipeline writes (plain: the fit's own result; RDO: the same late stage, RDO
  symbols, then rate control's step nudging `_fit_band`), bytes and Chamfer;
* "sweep": both quantizations at s/c step scales around rate control's choice, bytes and Chamfer, so that the
  two rate-distortion curves can be compared at equal bytes (log-log interpolation of the RDO curve at the plain
  files' sizes).

Run (one thread, ~2-4 min per mesh and size):

    cd /tmp && OMP_NUM_THREADS=1 /work/venvs/rdo/bin/python -m tetweave_codec.benchmarks.rdo --meshes spot igea \
        fandisk stanford-bunny --sizes 10000 20000 > rdo.md

Prints markdown tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
import torch

MESH_DIR = "/work/shared/meshes"
SWEEP = (0.8, 1.0, 1.25)
LAMBDAS = (3.0, 10.0)


def run(mesh: str, size: int, lambdas, sweep, seed: int = 0) -> list[dict]:
    from tetweave_codec import rate_control
    from tetweave_codec.decoder import decode
    from tetweave_codec.encoder import Job
    from tetweave_codec.fit.config import schedule_for
    from tetweave_codec.fit.finish import requantize
    from tetweave_codec.fit.rdo import prepare
    from tetweave_codec.meshio import load_mesh

    v, f = load_mesh(f"{MESH_DIR}/{mesh}.ply")

    class PlainJob(Job):
        def config(self, points, quantization):
            return dataclasses.replace(super().config(points, quantization), s_rdo=False)

    job = PlainJob(v, f, 1, schedule_for("default"), "default", torch.device("cpu"), seed, "sdf", None)
    captured = {}
    complete = rate_control.complete

    def capture(fin, ctx, quant):
        out = complete(fin, ctx, quant)
        captured.update(ctx=ctx, result=out)
        return out

    rate_control.complete = capture
    try:
        plain = rate_control.encode_to_size(job, size)
    finally:
        rate_control.complete = complete
    ctx, late = captured["ctx"], captured["result"]
    final_quant = plain.stats["quantization"]
    t0 = time.process_time()
    rdo = prepare(late.points, late.cells, ctx.backend)
    prep_s = time.process_time() - t0
    rows = [dict(mesh=mesh, size=size, kind="rate control", method="plain", bytes=plain.stats["bytes"],
                 chamfer=plain.stats["chamfer"], seconds=0.0)]  # fmt: skip

    def measure(res):
        data = job.pack(res, ctx)
        out = decode(data)
        return len(data), job.chamfer(*out)

    for lam in lambdas:
        rdo.lambda_scale = lam
        t0 = time.process_time()
        res = requantize(late.points, late.cells, late.latent_s, late.latent_c, late.quantization, 1, rdo)
        res, data = rate_control._fit_band(job, ctx, res, job.pack(res, ctx), size)
        secs = time.process_time() - t0
        out = decode(data)
        rows.append(dict(mesh=mesh, size=size, kind="rate control", method=f"rdo x{lam:g}", bytes=len(data),
                         chamfer=job.chamfer(*out), seconds=secs + prep_s))  # fmt: skip
    for scale in sweep:
        quant = rate_control._scaled(final_quant, scale)
        b, cd = measure(requantize(late.points, late.cells, late.latent_s, late.latent_c, quant, 1))
        rows.append(dict(mesh=mesh, size=size, kind=f"sweep x{scale:g}", method="plain", bytes=b, chamfer=cd,
                         seconds=0.0))  # fmt: skip
        for lam in lambdas:
            rdo.lambda_scale = lam
            t0 = time.process_time()
            res = requantize(late.points, late.cells, late.latent_s, late.latent_c, quant, 1, rdo)
            secs = time.process_time() - t0
            b, cd = measure(res)
            rows.append(dict(mesh=mesh, size=size, kind=f"sweep x{scale:g}", method=f"rdo x{lam:g}", bytes=b,
                             chamfer=cd, seconds=secs))  # fmt: skip
    return rows


def equal_bytes(rows: list[dict], method: str) -> list[tuple[int, float, float]]:
    """For each plain sweep file: (bytes, plain Chamfer, `method`'s Chamfer interpolated at those bytes, log-log)."""
    plain = sorted((r["bytes"], r["chamfer"]) for r in rows if r["kind"].startswith("sweep") and r["method"] == "plain")
    other = sorted((r["bytes"], r["chamfer"]) for r in rows if r["kind"].startswith("sweep") and r["method"] == method)
    xb, yc = np.log([b for b, _ in other]), np.log([c for _, c in other])
    out = []
    for b, c in plain:
        if xb[0] <= np.log(b) <= xb[-1]:
            out.append((b, c, float(np.exp(np.interp(np.log(b), xb, yc)))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", nargs="+", default=["spot", "igea", "fandisk", "stanford-bunny"])
    ap.add_argument("--sizes", nargs="+", type=int, default=[10000, 20000])
    ap.add_argument("--lambdas", nargs="+", type=float, default=list(LAMBDAS))
    ap.add_argument("--sweep", nargs="+", type=float, default=list(SWEEP))
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| mesh | size | file | method | bytes | Chamfer | bytes x CD | RDO CPU s |")
    print("|---|---:|---|---|---:|---:|---:|---:|")
    summary = []
    for mesh in args.meshes:
        for size in args.sizes:
            rows = run(mesh, size, args.lambdas, args.sweep)
            for r in rows:
                cells = (r["mesh"], r["size"], r["kind"], r["method"], r["bytes"], f"{r['chamfer']:.4e}")
                print("| " + " | ".join(map(str, cells)), end=" | ")
                print(f"{r['bytes'] * r['chamfer']:.3f} | {r['seconds']:.1f} |", flush=True)
            for lam in args.lambdas:
                for b, c_plain, c_rdo in equal_bytes(rows, f"rdo x{lam:g}"):
                    summary.append((mesh, size, lam, b, c_plain, c_rdo))
    print("\n| mesh | size | lambda | bytes | plain CD | RDO CD at equal bytes | change |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for mesh, size, lam, b, cp, cr in summary:
        print(f"| {mesh} | {size} | {lam:g} | {b} | {cp:.4e} | {cr:.4e} | {100 * (cr / cp - 1):+.1f} % |")


if __name__ == "__main__":
    main()
