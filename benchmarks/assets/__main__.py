"""python -m tetweave_codec.benchmarks.assets [--out DIR] [--only NAMES]: write the assets' PLYs (module __init__)."""

from __future__ import annotations

import argparse
from pathlib import Path

from tetweave_codec.benchmarks.assets import DATA, NAMES, save


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=DATA)
    ap.add_argument("--only", default=",".join(NAMES))
    args = ap.parse_args()
    for name in args.only.split(","):
        for path in save(name, args.out):
            print(f"{path}: {path.stat().st_size:,} bytes")


if __name__ == "__main__":
    main()
