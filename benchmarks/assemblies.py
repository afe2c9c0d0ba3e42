"""Real assemblies (issue 59): `tetweave encode` of each asset of benchmarks/assets in two export forms, judged
against its truth by code that shares nothing with the encoder (benchmarks/assets/judge.py, raycast.py).

Assets (tests/data/assemblies/, made by `python -m tetweave_codec.benchmarks.assets`): gearbox, bolted, booleans,
enclosure (build123d/OCCT parts; truth: the kernel's fuse of all solids, outer shells) and character (sculpted
body with open clothing, eyes, teeth, hat; truth: ray-cast samples of what a viewer sees). Forms:

    welded     one mesh, vertices merged at equal positions across parts (edges with four faces where parts touch)
    separate   the parts concatenated, unwelded
    clean      the truth's closed surface given as a clean input (the character: assets.character.clean()): the
               reference the messy forms compare with (ratio = error / clean's error at the same --size)

Per encode (Python API, one at a time, torch on --threads): bytes; seconds of fit.visible.choose_surface("auto")
on the normalized input, timed on its own (the encode runs it again), and of the whole encode; the surface auto
chose; the encoder summary's Chamfer; the judge's symmetric Chamfer against the truth (normalized frame of the
input); the share of the decoded area no outside ray reaches (judge.hidden_share: 64 directions); closed (trimesh
watertight + winding-consistent). `floor`: the clean input itself against the truth (tessellation / sheet
thickness; ~0 for the CAD assets).

    python -m tetweave_codec.benchmarks.assemblies --sizes 5k --threads 1 --csv out.csv
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

FORMS = ("clean", "welded", "separate")
COLUMNS = ("asset", "size", "form", "bytes", "surface", "choose_s", "encode_s", "summary_chamfer", "chamfer",
           "clean_chamfer", "ratio", "hidden_pct", "closed", "floor", "faces_in", "reason")  # fmt: skip


def parse_size(text: str) -> int | None:
    """Bytes of a --size value (k = 1024); None for "default" (no rate option: the fit sized from the input)."""
    if text == "default":
        return None
    return int(float(text[:-1]) * 1024) if text.endswith("k") else int(text)


def form_mesh(asset, form: str):
    """(vertices, faces) of an asset in an export form (FORMS)."""
    if form == "clean":
        return asset.clean
    if form == "welded":
        return asset.parts.welded()
    if form == "separate":
        return asset.parts.separate()
    raise ValueError(f"unknown form {form!r}")


def run_one(asset, truth, form: str, size: int | None, threads: int) -> dict:
    """One encode of one form at one size, judged (module docstring)."""
    from tetweave_codec.benchmarks.assets import judge
    from tetweave_codec.encoder import encode
    from tetweave_codec.fit.visible import choose_surface
    from tetweave_codec.meshio import normalize
    from tetweave_codec.options import EncodeOptions

    v, f = form_mesh(asset, form)
    label = "default" if size is None else f"{size // 1024}k"
    row = {"asset": asset.name, "size": label, "form": form, "faces_in": len(f)}
    t0 = time.perf_counter()
    choice = choose_surface(normalize(v)[0], f, "auto")
    row["choose_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        res = encode(v, f, options=EncodeOptions(size=size, threads=threads))
    except Exception as exc:  # an InputError (or worse) is a row of the table, not the end of the run
        row.update(encode_s=time.perf_counter() - t0, surface="failed", reason=f"{type(exc).__name__}: {exc}")
        return row
    row["encode_s"] = time.perf_counter() - t0
    row.update(bytes=len(res.data), surface=res.stats.get("surface") or choice.mode,
               reason=res.stats.get("surface_reason") or choice.reason,
               summary_chamfer=float(res.stats["chamfer"]))  # fmt: skip
    row["chamfer"] = judge.chamfer(truth, res.vertices, res.faces)["chamfer"]
    row["hidden_pct"] = 100.0 * judge.hidden_share(res.vertices, res.faces)
    row["closed"] = judge.closed(res.vertices, res.faces)
    return row


def fmt(value) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.3g}"
    return "" if value is None else str(value)


def markdown(rows: list[dict]) -> str:
    cols = [c for c in COLUMNS if c != "reason"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(fmt(r.get(c)) for c in cols) + " |")
    return "\n".join(lines)


def main() -> None:
    from tetweave_codec.benchmarks.assets import NAMES, judge, load

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--assets", default=",".join(NAMES))
    ap.add_argument("--forms", default=",".join(FORMS), help="comma-separated of clean, welded, separate")
    ap.add_argument("--sizes", default="5k", help="comma-separated --size values (k = 1024) or default")
    ap.add_argument("--threads", type=int, default=1, help="torch threads of the encodes")
    ap.add_argument("--csv", type=Path, default=None, help="write the rows here (each row as it is done)")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    rows: list[dict] = []
    writer = None
    handle = None
    if args.csv:
        handle = args.csv.open("w", newline="")
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        writer.writeheader()
    forms = args.forms.split(",")
    for name in args.assets.split(","):
        asset = load(name)
        truth = judge.truth_of(asset)
        floor = judge.chamfer(truth, *asset.clean)["chamfer"]
        for size in (parse_size(s) for s in args.sizes.split(",")):
            clean_err = None
            for form in sorted(forms, key=FORMS.index):  # clean first: the others' reference
                row = run_one(asset, truth, form, size, args.threads)
                row["floor"] = floor
                if form == "clean":
                    clean_err = row.get("chamfer")
                row["clean_chamfer"] = clean_err
                if clean_err and row.get("chamfer") is not None:
                    row["ratio"] = row["chamfer"] / clean_err
                rows.append(row)
                print(" ".join(f"{c}={fmt(row.get(c))}" for c in COLUMNS), flush=True)
                if writer:
                    writer.writerow({c: row.get(c) for c in COLUMNS})
                    handle.flush()
    if handle:
        handle.close()
    print(markdown(rows))


if __name__ == "__main__":
    main()
