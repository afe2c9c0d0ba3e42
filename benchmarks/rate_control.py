"""Rate control on real meshes: does `--size S` land in [0.85 S, S] and `--max-error E` meet E, and at what cost?

    python -m tetweave_codec.benchmarks.rate_control [--meshes DIR] [--only spot,fandisk] [--sizes 5k,10k,20k,40k]
                                                     [--errors 2e-3,1e-3,5e-4] [--quality default] [--threads N]

For each mesh and target: the file's bytes, the decoded mesh's Chamfer distance (the summary's metric: input's
normalized frame, 100K samples, seed 0), the grid points rate control chose, whether the target was met, and the
CPU time (time.process_time: the machine is shared; run with --threads 1 so CPU time is the fit's time) against
one fit at the chosen point count (timed on the same run) -- the issue's budget is 1.5x.
"""

from __future__ import annotations

import time

import torch

from tetweave_codec.benchmarks.common import script_meshes, script_parser
from tetweave_codec.cli.common import parse_count
from tetweave_codec.encoder import encode
from tetweave_codec.errors import InputError
from tetweave_codec.meshio import load_mesh


def main() -> None:
    ap = script_parser(__doc__)
    ap.add_argument("--sizes", default="5k,10k,20k,40k")
    ap.add_argument("--errors", default="2e-3,1e-3,5e-4")
    ap.add_argument("--no-reference", action="store_true", help="skip the one-fit reference timing")
    args = ap.parse_args()
    sizes = [parse_count(s) for s in args.sizes.split(",") if s]
    errors = [float(e) for e in args.errors.split(",") if e]
    paths = script_meshes(args)
    print(f"torch threads {torch.get_num_threads()}, quality {args.quality}")
    print("| mesh | target | bytes | Chamfer | points | met | time s | one fit s | ratio |")
    print("|---|---|---:|---:|---:|---|---:|---:|---:|")
    for path in paths:
        v, f = load_mesh(path)
        targets = [("size", s) for s in sizes] + [("max_error", e) for e in errors]
        for kind, value in targets:
            label = f"--size {value:,}" if kind == "size" else f"--max-error {value:g}"
            t0 = time.process_time()
            try:
                r = encode(v, f, quality=args.quality, device="cpu", seed=0, **{kind: value})
            except InputError as exc:
                print(f"| {path.stem} | {label} | - | - | - | refused: {exc} | {time.process_time() - t0:.0f} | | |")
                continue
            wall = time.process_time() - t0
            st = r.stats
            met = 0.85 * value <= st["bytes"] <= value if kind == "size" else st["chamfer"] <= value
            ref = ""
            ratio = ""
            if not args.no_reference:
                t1 = time.process_time()
                encode(v, f, points=st["points_target"], quality=args.quality, device="cpu", seed=0, measure=False)
                ref_s = time.process_time() - t1
                ref, ratio = f"{ref_s:.0f}", f"{wall / ref_s:.2f}"
            print(
                f"| {path.stem} | {label} | {st['bytes']:,} | {st['chamfer']:.3g} | {st['points_target']:,} | "
                f"{'yes' if met else 'NO'} | {wall:.0f} | {ref} | {ratio} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
