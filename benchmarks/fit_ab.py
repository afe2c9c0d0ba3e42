"""A/B of fit settings at equal file size: bytes x Chamfer of rate-controlled files, variant against base.

    python -m tetweave_codec.benchmarks.fit_ab run TAG [--cases spot:10k,igea:20k,...] [--set FIELD=VALUE ...]
                                                   [--meshes DIR] [--seed 0] [--out rows.jsonl]
    python -m tetweave_codec.benchmarks.fit_ab compare rows.jsonl [--base TAG]

`run` encodes each case (mesh name in --meshes, target size) with `encoder.encode(size=...)`, one torch thread,
after overriding fields of the default `Schedule` (`--set relocate=0.2`, `--set resample_at=0.1,0.2,0.3`), and
appends one JSON row per case: bytes, the encoder's Chamfer distance, bytes x Chamfer, CPU seconds. Two variants
can run side by side in two processes (one thread each) on a 2-core machine; CPU seconds then stay comparable.

`compare` prints, per case, bytes x Chamfer of every tag and its ratio to the base tag (default: the first tag
in the file), and the median ratio per tag. bytes x Chamfer is the comparison at equal size: a fit's error falls
about as 1 / bytes around a target (exponent 0.9-1 on the shared meshes), so a lower product is a smaller file
at equal error. One fit's product varies by about +-3 % with the seed alone (trajectories diverge at the first
re-triangulation), so judge a change by its median over several cases, not by one case.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import fields, replace
from pathlib import Path

from tetweave_codec.benchmarks.batch import DEFAULT_MESHES

DEFAULT_CASES = "spot:10k,igea:10k,fandisk:10k,stanford-bunny:10k,spot:40k,igea:20k"


def _parse_value(field_type: str, text: str):
    if "tuple" in field_type:
        return tuple(float(x) for x in text.split(",") if x)
    if "int" in field_type:
        return int(text)
    if "float" in field_type:
        return float(text)
    return text


def _schedule_with(settings: list[str]):
    from tetweave_codec.fit import config

    types = {f.name: str(f.type) for f in fields(config.Schedule)}
    changes = {}
    for item in settings:
        name, _, text = item.partition("=")
        if name not in types:
            raise SystemExit(f"unknown Schedule field {name!r}; choose from {', '.join(types)}")
        changes[name] = _parse_value(types[name], text)
    return replace(config.QUALITY["default"], **changes), changes


def run(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(1)
    from tetweave_codec.cli.common import parse_count
    from tetweave_codec.encoder import encode
    from tetweave_codec.fit import config
    from tetweave_codec.meshio import load_mesh

    config.QUALITY["default"], changes = _schedule_with(args.set)
    with open(args.out, "a") as out:
        for case in args.cases.split(","):
            name, size = case.split(":")
            vertices, faces = load_mesh(Path(args.meshes) / f"{name}.ply")
            t0 = time.process_time()
            result = encode(
                vertices,
                faces,
                size=parse_count(size),
                device="cpu",
                seed=args.seed,
                smoothing=args.smoothing,
                subdivision=args.subdivision,
                sh_degree=args.sh_degree,
                layout=args.layout,
                holes=args.holes,
            )
            stats = result.stats
            row = dict(
                tag=args.tag, settings=changes, smoothing=args.smoothing, subdivision=args.subdivision,
                sh_degree=args.sh_degree, layout=args.layout, holes=args.holes, mesh=name,
                size=parse_count(size),
                seed=args.seed,
                bytes=stats["bytes"], chamfer=stats["chamfer"], bxc=stats["bytes"] * stats["chamfer"],
                cpu=round(time.process_time() - t0, 1), points=stats["points_kept"],
            )  # fmt: skip
            print(json.dumps(row), flush=True)
            out.write(json.dumps(row) + "\n")
            out.flush()


def compare(args: argparse.Namespace) -> None:
    rows = [json.loads(line) for line in open(args.rows) if line.strip()]
    tags = list(dict.fromkeys(r["tag"] for r in rows))
    base = args.base or tags[0]
    cases = list(dict.fromkeys((r["mesh"], r["size"]) for r in rows))
    value = {(r["tag"], r["mesh"], r["size"]): r["bxc"] for r in rows}
    print("| mesh | size | " + " | ".join(tags) + " |")
    print("|---|---:|" + "---:|" * len(tags))
    ratios = {t: [] for t in tags}
    for mesh, size in cases:
        ref = value.get((base, mesh, size))
        cells = []
        for t in tags:
            v = value.get((t, mesh, size))
            if v is None:
                cells.append("-")
            elif ref is None or t == base:
                cells.append(f"{v:.3f}")
            else:
                ratios[t].append(v / ref)
                cells.append(f"{v:.3f} ({v / ref:.3f})")
        print(f"| {mesh} | {size} | " + " | ".join(cells) + " |")
    for t in tags:
        if ratios[t]:
            print(f"{t}: median ratio to {base} {statistics.median(ratios[t]):.3f} over {len(ratios[t])} cases")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="encode the cases with one variant")
    p_run.add_argument("tag")
    p_run.add_argument("--cases", default=DEFAULT_CASES)
    p_run.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    p_run.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    p_run.add_argument("--seed", type=int, default=0)
    p_run.add_argument("--smoothing", type=int, default=None, help="Taubin steps (default: the encoder's)")
    p_run.add_argument("--subdivision", type=int, default=None, help="Loop levels (default: the encoder's)")
    p_run.add_argument(
        "--sh-degree", type=int, default=None, help="SH degree of the fit (default: the encoder's choice)"
    )
    p_run.add_argument("--layout", default="fit", help="where the points come from: fit or grid (encode's layout)")
    p_run.add_argument("--holes", default="close", help="an open input's holes: close or keep (encode's --holes)")
    p_run.add_argument("--out", default="fit_ab.jsonl")
    p_cmp = sub.add_parser("compare", help="tabulate the rows of several variants")
    p_cmp.add_argument("rows")
    p_cmp.add_argument("--base")
    args = parser.parse_args(argv)
    run(args) if args.command == "run" else compare(args)


if __name__ == "__main__":
    main(sys.argv[1:])
