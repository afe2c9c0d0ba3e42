"""Point pruning before the late stage (tetweave_codec/fit/prune.py) against none, on the same main stage.

Each mesh and size is fitted once with rate control (`encode(size=...)`'s path, no pruning, no s RDO); the
finalized points of rate control's choice are then pruned by each fraction and the late stage rerun from the same
random state. Every variant is quantized at s/c step scales around rate control's final steps (bytes, Chamfer),
and the pruned curves are compared with the unpruned one at equal bytes (log-log interpolation).

Run (one thread, ~3-5 min per mesh and size):

    cd /tmp && OMP_NUM_THREADS=1 /work/venvs/rdo/bin/python -m tetweave_codec.benchmarks.prune --meshes spot igea \
        fandisk stanford-bunny --sizes 10000 --fractions 0.05 0.1 > /tmp/prune.md

Prints markdown tables.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import torch

from tetweave_codec.benchmarks.rdo import MESH_DIR, equal_bytes

SWEEP = (0.7, 0.85, 1.0, 1.2)
FRACTIONS = (0.05, 0.1)


def run(mesh: str, size: int, fractions, sweep, max_score: float = float("inf"), seed: int = 0) -> list[dict]:
    from tetweave_codec import rate_control
    from tetweave_codec.decoder import decode
    from tetweave_codec.encoder import Job
    from tetweave_codec.fit.config import schedule_for
    from tetweave_codec.fit.finish import requantize
    from tetweave_codec.meshio import load_mesh

    v, f = load_mesh(f"{MESH_DIR}/{mesh}.ply")

    class PlainJob(Job):
        def config(self, points, quantization):
            return dataclasses.replace(super().config(points, quantization), s_rdo=False)

    job = PlainJob(v, f, 1, schedule_for("default"), "default", torch.device("cpu"), seed, "sdf", None)
    captured = {}
    complete = rate_control.complete

    def capture(fin, ctx, quant):
        captured.update(fin=fin, ctx=ctx, quant=quant, state=ctx.generator.get_state())
        return complete(fin, ctx, quant)

    rate_control.complete = capture
    try:
        plain = rate_control.encode_to_size(job, size)
    finally:
        rate_control.complete = complete
    ctx, fin, quant = captured["ctx"], captured["fin"], captured["quant"]
    final_quant = plain.stats["quantization"]
    rows = []
    base_config = ctx.config
    for frac in (0.0, *fractions):
        ctx.generator.set_state(captured["state"])
        ctx.config = dataclasses.replace(base_config, prune_fraction=frac, prune_max_score=max_score)
        late = complete(fin, ctx, quant)
        for scale in sweep:
            q = rate_control._scaled(final_quant, scale)
            res = requantize(late.points, late.cells, late.latent_s, late.latent_c, q, 1)
            data = job.pack(res, ctx)
            out = decode(data)
            rows.append(dict(mesh=mesh, size=size, kind=f"sweep x{scale:g}", method=f"prune {frac:g}",
                             points=len(late.s), bytes=len(data), chamfer=job.chamfer(*out)))  # fmt: skip
    ctx.config = base_config
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", nargs="+", default=["spot", "igea", "fandisk", "stanford-bunny"])
    ap.add_argument("--sizes", nargs="+", type=int, default=[10000])
    ap.add_argument("--fractions", nargs="+", type=float, default=list(FRACTIONS))
    ap.add_argument("--sweep", nargs="+", type=float, default=list(SWEEP))
    ap.add_argument("--max-score", type=float, default=float("inf"), help="in position cells")
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| mesh | size | file | method | points | bytes | Chamfer | bytes x CD |")
    print("|---|---:|---|---|---:|---:|---:|---:|")
    summary = []
    for mesh in args.meshes:
        for size in args.sizes:
            rows = run(mesh, size, args.fractions, args.sweep, args.max_score)
            for r in rows:
                cells = (r["mesh"], r["size"], r["kind"], r["method"], r["points"], r["bytes"], f"{r['chamfer']:.4e}")
                print("| " + " | ".join(map(str, cells)) + f" | {r['bytes'] * r['chamfer']:.3f} |", flush=True)
            base = [dict(r, method="plain") for r in rows if r["method"] == "prune 0"]
            for frac in args.fractions:
                other = [dict(r, method="rdo") for r in rows if r["method"] == f"prune {frac:g}"]
                for b, cp, cr in equal_bytes(base + other, "rdo"):
                    summary.append((mesh, size, frac, b, cp, cr))
    print("\n| mesh | size | pruned | bytes | unpruned CD | pruned CD at equal bytes | change |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for mesh, size, frac, b, cp, cr in summary:
        print(f"| {mesh} | {size} | {frac:g} | {b} | {cp:.4e} | {cr:.4e} | {100 * (cr / cp - 1):+.1f} % |")
    print(f"\n(median change: {np.median([100 * (s[5] / s[4] - 1) for s in summary]):+.1f} %)" if summary else "")


if __name__ == "__main__":
    main()
