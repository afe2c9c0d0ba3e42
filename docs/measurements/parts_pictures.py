"""Before / after pictures of issue 55 (parts.md): `tetweave render` of the files `benchmarks/parts.py --save DIR`
wrote for --runs before,auto (DIR/parts_KIND_5k_before.tw, DIR/parts_KIND_5k_auto.tw), from outside and cut open.

Writes docs/measurements/parts_KIND.png: top row before (the default encode at 0a60d8a), bottom row after (this
tree's --surface auto); left two views from outside (`tetweave render --views 2`), right two of the decoded mesh cut
open by the plane x = CUT (the faces with centroid x < CUT kept, `tetweave render` of that half as a PLY, normals
as colours): membranes left inside the solid show through the cut. 32-colour PNGs.

    python docs/measurements/parts_pictures.py DIR [KIND ...]
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent
SIZE = 256
CUT = {"cyl48": 0.3, "cyl12": 0.3, "boxes": 0.3, "housing": 0.2, "spot_cyl": 0.0, "sheet": 0.0, "touching": -0.3}


def render(mesh: Path, png: Path, views: int, shading: str = "lambert") -> None:
    command = [sys.executable, "-m", "tetweave_codec.cli.main", "render", str(mesh), "-o", str(png)]
    command += ["--views", str(views), "--size", str(SIZE), "--shading", shading, "--threads", "1"]
    subprocess.run(command, check=True, capture_output=True)


def main() -> None:
    from PIL import Image

    from tetweave_codec.decoder import decode
    from tetweave_codec.meshio import save_mesh

    folder = Path(sys.argv[1])
    kinds = sys.argv[2:] or ["cyl48", "boxes", "housing", "sheet"]
    for kind in kinds:
        rows = []
        with tempfile.TemporaryDirectory() as tmp:
            for run in ("before", "auto"):
                tw = folder / f"parts_{kind}_5k_{run}.tw"
                v, f = decode(tw.read_bytes())
                # cut in the decoded mesh's own bounding-box frame (x from -1 to 1)
                lo, hi = v.min(axis=0), v.max(axis=0)
                x = (v[f].mean(axis=1)[:, 0] - 0.5 * (lo[0] + hi[0])) / (0.5 * (hi[0] - lo[0]))
                half = Path(tmp) / f"{run}_cut.ply"
                save_mesh(half, v, f[x < CUT[kind]])
                render(tw, Path(tmp) / f"{run}_out.png", 2)
                render(half, Path(tmp) / f"{run}_cut.png", 2, "normals")
                row = [Image.open(Path(tmp) / f"{run}_{part}.png").convert("RGB") for part in ("out", "cut")]
                rows.append(np.concatenate([np.asarray(im) for im in row], axis=1))
        picture = Image.fromarray(np.concatenate(rows, axis=0))
        picture.quantize(colors=32).save(OUT / f"parts_{kind}.png", optimize=True)
        print(OUT / f"parts_{kind}.png", picture.size)


if __name__ == "__main__":
    main()
