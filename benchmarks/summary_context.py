"""The encoder summary's classical context (tetweave_codec/classical.py) on the committed bench files: how close its
quick search for fast-simplification + Draco comes to a dense sweep and to `tetweave bench`, and what it costs.

For each committed file (benchmarks/results/files/MESH/*.tw) the file is decoded and its Chamfer distance to the
input measured as the summary measures it; then `classical_context` runs (timed), and a dense sweep of the same
family (DENSE_FRACTIONS fractions around the search's fractions, at its depths and one bit either side of them)
gives the size a practitioner choosing the fraction and the depth would reach. The bench's own number is read
from the committed results.csv (its decimate+draco rows, 4 fractions x 2 depths, at the tetweave row's Chamfer
distance): a sparse sweep, so it can lie above both or have no bracket ("-").

    python -m tetweave_codec.benchmarks.summary_context [--only igea,spot]
"""

from __future__ import annotations

import csv
import statistics
import time
from pathlib import Path

import numpy as np

from tetweave_codec.benchmarks.common import script_meshes, script_parser
from tetweave_codec.classical import classical_context, decimate, draco_decode, draco_encode
from tetweave_codec.decoder import decode
from tetweave_codec.fit.prepared import prepare_input
from tetweave_codec.meshio import load_mesh
from tetweave_codec.metrics.rate_distortion import bytes_at, pareto_front
from tetweave_codec.packing import SUMMARY_CHAMFER_SAMPLES

RESULTS = Path(__file__).resolve().parent / "results"
DENSE_FRACTIONS = 14


def bench_bytes(rows: list[dict], mesh: str, target_bytes: int) -> tuple[float | None, float | None]:
    """(the bench's decimate+draco bytes at the tetweave file's Chamfer distance, the file's encode seconds)."""
    tw = [r for r in rows if r["mesh"] == mesh and r["family"] == "tetweave" and r["target_bytes"] == str(target_bytes)]
    if not tw:
        return None, None
    front = pareto_front(
        [
            (float(r["chamfer"]), float(r["bytes"]))
            for r in rows
            if r["mesh"] == mesh and r["family"] == "decimate+draco"
        ]
    )
    return bytes_at(front, float(tw[0]["chamfer"])), float(tw[0]["encode_s"])


def dense_bytes(prepared, chamfer: float, settings: dict) -> float | None:
    """fast-simplification + Draco at `chamfer` from DENSE_FRACTIONS fractions spanning the search's fractions
    (/2 .. x2) at its depths and one bit either side of them, measured with the summary's metric."""
    keeps = [k for k, _ in settings]
    depths = range(min(b for _, b in settings) - 1, max(b for _, b in settings) + 2)
    points = []
    for keep in np.geomspace(max(min(keeps) / 2, 1e-4), min(max(keeps) * 2, 1.0), DENSE_FRACTIONS):
        v, f = decimate(prepared.vertices, prepared.faces, float(keep))  # in the input's frame, as the summary
        for b in depths:
            data = draco_encode(v, f, b, 7)
            points.append((prepared.chamfer(*draco_decode(data), SUMMARY_CHAMFER_SAMPLES), len(data)))
    return bytes_at(pareto_front(points), chamfer)


def main() -> None:
    ap = script_parser(__doc__.split("\n\n")[0])
    args = ap.parse_args()
    rows = list(csv.DictReader(open(RESULTS / "results.csv", encoding="utf-8")))
    print(
        "| mesh | file bytes | Chamfer | bits | summary's bytes | dense sweep | bench (4 fractions) | summary / dense "
        "| summary / bench | context CPU s | bench encode s | share |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    ratios, shares = [], []
    for path in script_meshes(args):
        v, f = load_mesh(path)
        prepared = prepare_input(v, f, seed=0)
        for tw in sorted((RESULTS / "files" / path.stem).glob("size-*.tw"), key=lambda p: int(p.stem.split("-")[1])):
            data = tw.read_bytes()
            dv, df = decode(data)
            chamfer = prepared.chamfer(dv, df, SUMMARY_CHAMFER_SAMPLES)
            t0 = time.process_time()
            context = classical_context(prepared, len(data), chamfer, len(df), SUMMARY_CHAMFER_SAMPLES)
            seconds = time.process_time() - t0
            match = context["decimate"]
            dense = dense_bytes(prepared, chamfer, match.settings) if match.settings else None
            bench, encode_s = bench_bytes(rows, path.stem, int(tw.stem.split("-")[1]))
            ours = match.bytes

            def fmt(x):
                return "-" if x is None else f"{x:,.0f}"

            def ratio(a, b):
                return "-" if a is None or b is None else f"{a / b:.3f}"

            if ours is not None and dense is not None:
                ratios.append(ours / dense)
            if encode_s:
                shares.append(seconds / encode_s)
            print(
                f"| {path.stem} | {len(data):,} | {chamfer:.3g} | {match.bits} | {fmt(ours)} | {fmt(dense)} | "
                f"{fmt(bench)} | {ratio(ours, dense)} | {ratio(ours, bench)} | {seconds:.2f} | "
                f"{fmt(encode_s)} | {'-' if not encode_s else f'{100 * seconds / encode_s:.1f} %'} |",
                flush=True,
            )
    if ratios:
        print(
            f"\nsummary / dense sweep: median {statistics.median(ratios):.3f}, range {min(ratios):.3f}-"
            f"{max(ratios):.3f}; context / encode (wall): median {100 * statistics.median(shares):.1f} %"
        )


if __name__ == "__main__":
    main()
