"""Encode time per stage, file size and Chamfer distance for real meshes at several point counts.

    python -m tetweave_codec.benchmarks.encode_speed [--meshes DIR] [--points 8k,16k,32k] [--quality default]
                                                     [--baseline] [--threads N]

For each mesh and point count: seconds per stage (targets, init, main, finalize, late, extract), total, file bytes,
points kept and the point-to-surface Chamfer distance in the input's normalized frame. With --baseline it also runs
the paper-style fit in the same wall-clock budget as ours at that point count: random start in a ball, renders
only (no 3-D term), the paper's step sizes and weights (`Weights.paper()`, `LearningRates.paper()`),
the same container as ours — and prints the ratio of the Chamfer distances.
Run it on a quiet machine: torch's threads slow down badly when other processes share the cores.
"""

from __future__ import annotations

import time
from dataclasses import replace

import torch

from tetweave_codec.benchmarks.common import script_meshes, script_parser
from tetweave_codec.cli.common import parse_count
from tetweave_codec.fit.config import QUALITY, FitConfig, LearningRates, Weights
from tetweave_codec.fit.loop import fit
from tetweave_codec.meshio import load_mesh, normalize
from tetweave_codec.metrics.fidelity import chamfer_distance

STAGES = ("targets", "init", "main", "finalize", "late", "extract")


def _encode_once(vertices, faces, points: int, quality: str, seed: int = 0) -> dict:
    from tetweave_codec.encoder import encode

    t0 = time.perf_counter()
    result = encode(vertices, faces, points=points, quality=quality, device="cpu", seed=seed)
    row = dict(result.stats["seconds"])
    row["wall"] = time.perf_counter() - t0
    row.update(bytes=result.stats["bytes"], kept=result.stats["points_kept"], chamfer=result.stats["chamfer"])
    return row


def _paper_style(vertices, faces, points: int, budget_s: float, quality: str, seed: int = 0) -> tuple[float, int]:
    """The paper's recipe (random start, renders only, `Weights.paper()`, `LearningRates.paper()`), stopped at about
    `budget_s`.

    Iterations are sized from a short timing run so the whole fit takes about the budget. Returns (Chamfer, iters).
    """
    from tetweave_codec.decoder import mesh_from_points

    normalized, _, _ = normalize(vertices)
    paper = {"weights": Weights.paper(), "lr": LearningRates.paper(), "init": "random"}
    probe = replace(QUALITY[quality], main_iters=10, late_iters=5, resample_at=())
    t0 = time.perf_counter()
    fit(normalized, faces, FitConfig(points=points, schedule=probe, seed=seed, **paper))
    per_iter = (time.perf_counter() - t0) / 15.0
    iters = max(20, int(budget_s / per_iter))
    sch = replace(QUALITY[quality], main_iters=int(iters * 0.7), late_iters=iters - int(iters * 0.7))
    res = fit(normalized, faces, FitConfig(points=points, schedule=sch, seed=seed, **paper))
    fin = res.finish
    v, f = mesh_from_points(fin.points, fin.s, fin.c, res.sh_degree, backend=res.backend)
    if len(f) == 0:
        return float("inf"), iters
    return chamfer_distance(normalized, faces, v, f, n_samples=100_000, normalize=False), iters


def main() -> None:
    ap = script_parser(__doc__)
    ap.add_argument("--points", default="8k,16k,32k")
    ap.add_argument("--baseline", action="store_true", help="also run the paper-style fit in the same time")
    args = ap.parse_args()
    counts = [parse_count(p) for p in args.points.split(",")]
    paths = script_meshes(args)
    print(f"torch threads {torch.get_num_threads()}, quality {args.quality}")
    head = (
        f"{'mesh':16} {'points':>6} "
        + " ".join(f"{s:>8}" for s in STAGES)
        + f" {'total s':>8} {'bytes':>8} {'kept':>6} {'chamfer':>9}"
    )
    if args.baseline:
        head += f" {'paper-style CD':>14} {'ratio':>6}"
    print(head)
    for path in paths:
        vertices, faces = load_mesh(path)
        for n in counts:
            row = _encode_once(vertices, faces, n, args.quality)
            line = (
                f"{path.stem:16} {n:>6} "
                + " ".join(f"{row[s]:>8.1f}" for s in STAGES)
                + f" {row['wall']:>8.1f} {row['bytes']:>8} {row['kept']:>6} {row['chamfer']:>9.2e}"
            )
            if args.baseline:
                cd, _ = _paper_style(vertices, faces, n, row["wall"], args.quality)
                line += f" {cd:>14.2e} {cd / row['chamfer']:>6.1f}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
